"""The motors' energy of a step (aux column AUX_MOTOR_ENERGY, the env's ``actuator_power`` times dt):
the integral of sum_k |s A_k phidot_k|, A_k the torque the motor delivers after its torque-speed band
and current limit, s the traction scale.

Cross-checked against a quadrature of the same integrand computed apart (numpy's motor envelope, the
joint rates of the observation, the traction scale of ``wheel_lateral_forces``) on a fine time grid,
and against the work-energy identity of ideal sources without damping, where the motors' signed power
is all the power: the absolute energy bounds the work from above and equals it while every motor drives.
"""

import math

import numpy as np
import pytest

from snake_env import physics
from snake_env.dynamics.motor import motor_torque_reference
from snake_env.physics import AUX_FAILED, AUX_MOTOR_ENERGY, AUX_WORK, PhysicsConfig


def _bent_state(rng, n, speed):
    q = np.concatenate([np.cumsum(rng.uniform(-0.5, 0.5, n)), [0.0, 0.0]])
    return q, rng.normal(0.0, speed, 2)


def _integrand(params, config, q, u, torques, obs):
    """sum_k |s A_k phidot_k| (W) at one state, from parts the kernel's sum does not share."""
    n = config.n_links
    phidot = obs[-(n - 1):]  # the observation's last block: the joint rates (rad/s)
    scale = np.ones(1)
    physics.wheel_lateral_forces(params, q[None], u[None], torques[None], np.empty((1, n)), scale)
    motor = params.kernel_model[8:11]  # stall torque (N m), 1 / no-load speed (s/rad), current limit (N m)
    if math.isinf(motor[2]):
        delivered = torques
    else:
        no_load = math.inf if motor[1] == 0.0 else 1.0 / motor[1]
        delivered = motor_torque_reference(torques, phidot, motor[0], no_load, motor[2])
    return scale[0] * np.sum(np.abs(delivered * phidot))


@pytest.mark.parametrize("settings", [{}, {"actuator": "ideal", "wheel_friction": None}],
                         ids=["servo_and_grip", "ideal_unlimited_grip"])
def test_motor_energy_is_the_integral_of_the_delivered_power(rng, settings):
    """Over 0.3 s in 0.5 ms steps under held commands that drive the joints into the motor's band
    (servo) and the wheels past their grip, the summed AUX_MOTOR_ENERGY equals the trapezoid rule of
    the integrand to its O(h^2) error; the commanded torque's |T dphi| is far above it on the servo."""
    n = 5
    config = PhysicsConfig(n_links=n, sim_dt=0.0005, frame_skip=1, **settings)
    _, params = config.build()
    q, u = _bent_state(rng, n, speed=0.3)
    torques = np.array([1.0, -1.0, 0.8, -0.6])
    obs, _ = physics.observe(params, q, u)
    f0 = _integrand(params, config, q, u, torques, obs)
    energy = reference = commanded = 0.0
    for _ in range(600):
        q1, u1, obs, aux = physics.step(params, q, u, torques)
        assert aux[AUX_FAILED] == 0.0
        energy += aux[AUX_MOTOR_ENERGY]
        f1 = _integrand(params, config, q1, u1, torques, obs)
        reference += 0.5 * config.sim_dt * (f0 + f1)
        commanded += np.sum(np.abs(torques * (np.diff(q1[:n]) - np.diff(q[:n]))))
        q, u, f0 = q1, u1, f1
    assert reference > 0.1  # J: the motors did work worth checking
    assert energy == pytest.approx(reference, rel=2e-3)
    if settings:  # ideal sources: the commanded torque is delivered
        assert commanded == pytest.approx(energy, rel=2e-3)
    else:
        assert commanded > 1.2 * energy


def test_motor_energy_bounds_the_work_of_ideal_undamped_sources(rng):
    """Ideal sources, no damping, no limits, unlimited grip: the power of all loads is sum_k T_k phidot_k,
    so |work| <= the motors' absolute energy on every step, with equality from rest (every joint turns
    the way its torque pushes)."""
    n = 6
    config = PhysicsConfig(n_links=n, paper_model=True, actuator="ideal", wheel_friction=None)
    _, params = config.build()
    gaps = []
    for _ in range(30):
        q, u = _bent_state(rng, n, speed=0.5)
        torques = rng.uniform(-1.0, 1.0, n - 1)
        _, _, _, aux = physics.step(params, q, u, torques)
        assert aux[AUX_FAILED] == 0.0
        assert abs(aux[AUX_WORK]) <= aux[AUX_MOTOR_ENERGY] * (1.0 + 1e-12)
        gaps.append(aux[AUX_MOTOR_ENERGY] - abs(aux[AUX_WORK]))
    assert max(gaps) > 1e-3  # some joints were pushed against their motion: the bound is strict there
    # from rest, straight, one joint: it turns the way its torque pushes over the whole step
    q = np.zeros(4)
    _, _, _, aux = physics.step(PhysicsConfig(n_links=2, paper_model=True, actuator="ideal",
                                              wheel_friction=None).build()[1], q, np.zeros(2), np.array([0.7]))
    assert aux[AUX_WORK] > 0.0
    assert aux[AUX_MOTOR_ENERGY] == pytest.approx(aux[AUX_WORK], rel=1e-12)


def test_env_actuator_power_is_the_motor_energy_over_dt(rng):
    """The env's info["actuator_power"] (W) is the physics step's motor energy over dt, and the optional
    energy cost charges exactly that."""
    import gymnasium as gym

    env = gym.make("snake_env/Snake5-v3", energy_cost_weight=0.1)
    env.reset(seed=0)
    base = env.unwrapped
    for _ in range(20):
        q, u = base.state
        action = rng.uniform(-1.0, 1.0, 4)
        *_, info = env.step(action)
        _, _, _, aux = physics.step(base.params, q, u, action * base.max_torque)
        assert info["actuator_power"] == aux[AUX_MOTOR_ENERGY] / base.dt
        assert info["reward_energy"] == -0.1 * info["actuator_power"]
    env.close()
