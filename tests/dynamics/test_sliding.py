"""The sliding-wheel model (snake_env.dynamics.sliding): the no-slip model of eq. 27 is its limit as
the friction grows, its work-energy balance closes with friction's work, and wheels past their
grip slide at the Coulomb force."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from snake_env.dynamics import lagrange
from snake_env.dynamics.model import SnakeModel
from snake_env.dynamics.sliding import GRAVITY, SlidingWheels

N = 5
# the v3 default's servo (1 N m stall, pi rad/s no load, 1 N m limit) and joint-limit barrier
SERVO = dict(stall_torque=1.0, no_load_speed=math.pi, torque_limit=1.0, joint_limit=math.pi / 2,
             limit_stiffness=20.0, limit_damping=0.2)
COMMAND = np.array([0.8, -0.5, 0.6, -0.9])  # N m


@pytest.fixture(scope="module")
def start():
    model = SnakeModel(N, mass=1.0, length=0.2, inertia=0.005, joint_damping=0.01, wheel_damping=0.1)
    rng = np.random.default_rng(0)
    q = np.concatenate([rng.uniform(-0.3, 0.3, N), [0.0, 0.0]])
    qdot = lagrange.consistent_qdot(model, q, np.array([0.3, 0.5]))
    return model, q, qdot


def run(wheels, q, qdot, steps, dt=0.04):
    y = wheels.initial(q, qdot)
    for _ in range(steps):
        y = wheels.advance(y, COMMAND, dt)
    return y


def no_slip(model, q, qdot, duration):
    """The no-slip model (eq. 27, Lagrange's multipliers) under the same motor and barrier."""
    motor = SlidingWheels(model, 1.0, **SERVO)

    def f(t, y):
        qq, qd = y[:N + 2], y[N + 2:]
        return np.concatenate([qd, lagrange.qddot(model, qq, qd, motor.joint_torques(COMMAND, qq, qd))])

    return solve_ivp(f, (0.0, duration), np.concatenate([q, qdot]), method="DOP853", rtol=1e-11, atol=1e-12).y[:, -1]


def test_converges_to_the_no_slip_model_as_friction_grows(start):
    model, q, qdot = start
    reference = no_slip(model, q, qdot, 6 * 0.04)
    errors = []
    for mu in (10.0, 100.0, 1000.0):
        y = run(SlidingWheels(model, mu, slip_speed=1e-2, **SERVO), q, qdot, 6)
        errors.append(np.max(np.abs(y[:N + 2] - reference[:N + 2])))
    # the lateral slip, and so the distance to the constrained motion, falls as 1 / mu
    assert errors[0] > 5 * errors[1] > 25 * errors[2]
    assert errors[2] < 1e-4  # rad, m


def test_work_energy_balance_with_friction(start):
    model, q, qdot = start
    wheels = SlidingWheels(model, 0.2, slip_speed=1e-3, **SERVO)  # low grip: the wheels slide
    y = run(wheels, q, qdot, 10)
    qq, qd = y[:N + 2], y[N + 2:2 * N + 4]
    change = wheels.kinetic_energy(qq, qd) - wheels.kinetic_energy(q, qdot)
    work, friction_work = y[-2], y[-1]
    assert friction_work < -0.01  # J: friction takes energy, and here a real share
    assert abs(change - work - friction_work) < 1e-6 * (abs(work) + abs(friction_work))
    v, f = wheels.lateral(qq, qd)
    grip = 0.2 * GRAVITY * model.mass
    assert np.all(np.abs(f) < grip)
    assert np.any(np.abs(v) > 10 * wheels.slip_speed)  # some wheel slides
    sliding = np.abs(v) > 10 * wheels.slip_speed
    assert np.all(np.abs(f[sliding]) > 0.99 * grip[sliding])  # at the Coulomb force


@pytest.mark.parametrize("name, kwargs", [("friction", {"friction": 0.0}), ("friction", {"friction": -1.0}),
                                          ("slip_speed", {"friction": 1.0, "slip_speed": 0.0}),
                                          ("friction", {"friction": math.inf})])
def test_bad_input_names_the_argument(start, name, kwargs):
    with pytest.raises(ValueError, match=name):
        SlidingWheels(start[0], **kwargs)
