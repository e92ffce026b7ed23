"""The motor's response in time (physics.actuator_response): the step response of the torque lag and the
control latency against the continuous first-order lag, the split step against the one-call step and
against the pure API stepped substep by substep, the work-energy balance, undone failures, resets, rows
of the vector env, and one-line errors."""

import dataclasses
import math

import numpy as np
import pytest

from snake_env.envs import SnakeEnv, SnakeVectorEnv
from snake_env.physics import (AUX_FAILED, AUX_KINETIC, AUX_MOTOR_ENERGY, AUX_VX, AUX_WORK, AUX_X, PhysicsConfig, step,
                               step_inplace)
from snake_env.physics.actuator_response import ActuatorResponse
from tests.rows import assert_rows_step_like_singles


def continuous_mean(command, start, lag, t0, t1, points=20001):
    """The mean over [t0, t1] (s) of a first-order lag's torque that gets ``command`` at time ``start``
    from rest: c (1 - exp(-(t - start) / lag)) after it, 0 before; by the trapezoid rule."""
    t = np.linspace(t0, t1, points)
    tau = np.where(t < start, 0.0, command * -np.expm1(-np.clip(t - start, 0.0, None) / lag))
    return float(np.sum((tau[1:] + tau[:-1]) / 2.0) / (points - 1))


@pytest.mark.parametrize("lag, latency", [(0.03, 0.0), (0.015, 0.02), (0.0, 0.03), (0.05, 0.04)])
def test_step_response_shows_the_lag_and_the_latency(lag, latency):
    """From rest, a command step of 0.8 N m at t = 0: the torque held over each 10 ms substep is the
    continuous lag's mean over it, 0 until the latency has passed."""
    config = PhysicsConfig(wheel_model="no_slip", n_links=4, torque_lag=lag, control_latency=latency)
    _, params = config.build()
    response = ActuatorResponse(config, params, num_envs=1)
    command = np.full((1, 3), 0.8)
    h = params.sim_dt
    held = []
    for step_index in range(3):
        for j in range(params.frame_skip):
            held.append(response.substep_torques(command, j)[0, 0])
        response.previous_command[:] = command  # what ActuatorResponse.step does after a step
    for j, value in enumerate(held):
        t0 = j * h
        if lag == 0.0:
            expected = 0.8 if t0 >= latency - 1e-12 else 0.0
        else:
            expected = continuous_mean(0.8, latency, lag, t0, t0 + h)
        assert value == pytest.approx(expected, abs=1e-7), (j, value, expected)
    delay = round(latency / h)
    assert all(value == 0.0 for value in held[:delay]) and held[delay] > 0.0
    if lag > 0.0:  # one time constant after the command arrives the torque is 1 - 1/e of it
        assert response.torque[0, 0] == pytest.approx(0.8 * -math.expm1(-(len(held) * h - latency) / lag))


@pytest.mark.parametrize("grip", [0.8, None])
def test_split_step_without_lag_equals_the_one_call_step(rng, grip):
    """The substep-by-substep path with no lag and no latency reproduces the one-call step: the same
    RK4 substeps, so the same states; the work is the sum of the substeps' (equal to rounding). Fixed-step
    RK4: with refinement the paths differ where a step is refined (the split path halves only the
    substep that fails, the one-call path the whole env step), and an energy tolerance no step nears (the
    split path holds each substep to a quarter of it)."""
    env = SnakeEnv(wheel_model="no_slip", n_links=6, wheel_friction=grip, integrator="rk4", energy_tolerance=1.0)
    env.reset(seed=3)
    batch = env.unwrapped._batch
    q, u = batch.q.copy(), batch.u.copy()
    response = ActuatorResponse(batch.config, batch.params, num_envs=1)
    obs_split, aux_split = batch.physics_obs.copy(), batch.aux.copy()
    obs_one, aux_one = batch.physics_obs.copy(), batch.aux.copy()
    q1, u1 = q.copy(), u.copy()
    for _ in range(30):
        torques = rng.uniform(-1, 1, (1, 5))
        response.step(q, u, torques, obs_split, aux_split)
        step_inplace(batch.params, q1, u1, torques, obs_one, aux_one)
        np.testing.assert_array_equal(q, q1)
        np.testing.assert_array_equal(u, u1)
        np.testing.assert_array_equal(obs_split, obs_one)
        assert aux_split[0, AUX_WORK] == pytest.approx(aux_one[0, AUX_WORK], rel=1e-12, abs=1e-15)
        assert aux_split[0, AUX_VX] == pytest.approx(aux_one[0, AUX_VX], rel=1e-9, abs=1e-12)
        assert aux_split[0, AUX_KINETIC] == aux_one[0, AUX_KINETIC]


def test_env_step_equals_the_pure_api_stepped_substep_by_substep(rng):
    """The env with a lag and a latency against physics.step called once per 10 ms substep with the
    lag's means computed here: the same states, the summed work, the CM velocity over dt, and the
    actuator power from the torques held substep by substep."""
    lag, latency = 0.025, 0.02
    env = SnakeEnv(wheel_model="no_slip", n_links=5, torque_lag=lag, control_latency=latency)
    env.reset(seed=4)
    params = env.unwrapped.params
    one = dataclasses.replace(params, frame_skip=1, energy_tolerance=params.energy_tolerance / params.frame_skip)
    h = params.sim_dt
    decay, weight = math.exp(-h / lag), -math.expm1(-h / lag) / (h / lag)  # exp(-h/T), (T/h)(1 - exp(-h/T))
    q, u = env.unwrapped.state
    state = np.zeros(4)  # the lag's torque
    previous = np.zeros(4)
    for _ in range(40):
        action = rng.uniform(-1, 1, 4)
        command = action * env.unwrapped.max_torque
        x0 = env.unwrapped._batch.aux[0, AUX_X]
        work, power = 0.0, 0.0
        for j in range(params.frame_skip):
            arrived = previous if j < round(latency / h) else command
            held = arrived + (state - arrived) * weight
            state = arrived + (state - arrived) * decay
            q_next, u, _, aux = step(one, q, u, held)
            power += aux[AUX_MOTOR_ENERGY]
            q = q_next
            work += aux[AUX_WORK]
            assert aux[AUX_FAILED] == 0.0
        previous = command
        _, _, _, _, info = env.step(action)
        q_env, u_env = env.unwrapped.state
        np.testing.assert_array_equal(q_env, q)
        np.testing.assert_array_equal(u_env, u)
        assert info["power"] * env.unwrapped.dt == pytest.approx(work, rel=1e-12, abs=1e-15)
        assert info["x_velocity"] == pytest.approx((aux[AUX_X] - x0) / env.unwrapped.dt, rel=1e-12, abs=1e-15)
        assert info["actuator_power"] == pytest.approx(power / env.unwrapped.dt, rel=1e-12, abs=1e-15)


def test_work_energy_balance_holds_over_the_split_step(rng):
    """K1 - K0 equals the work of all loads over each env step to the integration's accuracy."""
    env = SnakeEnv(wheel_model="no_slip", n_links=8, torque_lag=0.02, control_latency=0.01)
    env.reset(seed=0)
    kinetic = env.unwrapped._batch.aux[0, AUX_KINETIC]
    for _ in range(100):
        _, _, _, _, info = env.step(rng.uniform(-1, 1, 7))
        work = info["power"] * env.unwrapped.dt
        assert abs(info["kinetic_energy"] - kinetic - work) <= 1e-2 * (max(kinetic, info["kinetic_energy"]) + 1e-3)
        kinetic = info["kinetic_energy"]


def test_a_failed_step_is_undone_with_its_lag_state():
    """A step the check refuses keeps the pre-step state and the lag's state before it."""
    env = SnakeEnv(wheel_model="no_slip", n_links=5, torque_lag=0.02, integrator="rk4", energy_tolerance=1e-14, paper_model=False)
    env.reset(seed=1)
    batch = env.unwrapped._batch
    q0 = batch.q.copy()
    torque0 = batch.physics.torque.copy()
    with pytest.warns(RuntimeWarning, match="simulation failure"):
        _, reward, _, _, info = env.step(np.ones(4))
    assert info["sim_failure"] and reward == 0.0 and info["x_velocity"] == 0.0
    np.testing.assert_array_equal(batch.q, q0)
    np.testing.assert_array_equal(batch.physics.torque, torque0)


def test_vector_rows_equal_single_envs_and_autoreset_clears_the_lag(rng):
    kwargs = dict(n_links=5, torque_lag=0.03, control_latency=0.02)
    vec = SnakeVectorEnv(wheel_model="no_slip", num_envs=3, max_episode_steps=6, **kwargs)
    vec.reset(seed=2)
    q, u = vec.state
    singles = []
    for b in range(3):
        env = SnakeEnv(wheel_model="no_slip", **kwargs)
        env.set_state(q[b], u[b])
        singles.append(env)
    assert_rows_step_like_singles(vec, singles, rng, 5, ["actuator_power"])
    response = vec._batch.physics
    assert np.all(response.torque != 0.0)
    vec.step(np.ones((3, 4), np.float32))  # the 6th step truncates; the next one resets
    vec.step(np.ones((3, 4), np.float32))
    np.testing.assert_array_equal(response.torque, 0.0)
    np.testing.assert_array_equal(response.previous_command, 0.0)


@pytest.mark.parametrize("kwargs, message", [
    (dict(torque_lag=-0.01), r"torque_lag must be a finite number >= 0.0 \(s\)"),
    (dict(control_latency=0.015), "control_latency must be a whole number of sim_dt"),
    (dict(control_latency=0.05), "a latency longer than a step"),
    (dict(control_latency=math.inf), "control_latency must be a finite number"),
    (dict(paper_model=True, torque_lag=0.01), "do not also pass torque_lag"),
])
def test_bad_lag_or_latency_is_a_one_line_error(kwargs, message):
    with pytest.raises(ValueError, match=message) as error:
        SnakeEnv(wheel_model="no_slip", n_links=5, **kwargs)
    assert "\n" not in str(error.value)
