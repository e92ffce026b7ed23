"""The motor's response in time on wheels that slide (the default, v4): ActuatorResponse steps the sliding
physics one sim_dt substep at a time under the lag's held torque. Against the sliding physics stepped by hand
substep by substep, the one-call step, the work-energy balance with the friction's work, an undone step, and the
vector env's rows."""

import dataclasses
import math

import numpy as np
import pytest

from snake_env.envs import SnakeEnv, SnakeVectorEnv
from snake_env.physics import AUX_FAILED, AUX_KINETIC, AUX_WORK, PhysicsConfig
from snake_env.physics.actuator_response import ActuatorResponse
from snake_env.physics.sliding_wheels import SlidingWheelPhysics
from tests.rows import assert_rows_step_like_singles


def started_env(seed, **kwargs):
    env = SnakeEnv(n_links=5, **kwargs)
    env.reset(seed=seed)
    return env


def test_without_lag_the_split_step_equals_the_one_call_step():
    """No lag, no latency: the sim_dt pieces take the one-call step's 1 ms substeps, so the same states, wheel
    state and slip, bit for bit; the work is the sum of the pieces' (equal to rounding). With an energy tolerance
    no step nears: the split path holds each piece to 1/frame_skip of it, so it refines where the one-call path
    does not (as on the no-slip wheels, tests/physics/test_actuator_response.py)."""
    env = started_env(3, energy_tolerance=1.0)
    batch = env.unwrapped._batch
    config, params = batch.config, batch.params
    q, u = batch.q.copy(), batch.u.copy()
    split = ActuatorResponse(config, params, num_envs=1)
    one = SlidingWheelPhysics(config, params, num_envs=1)
    for physics in (split, one):
        physics.set_state(q, u)
    q1, u1 = q.copy(), u.copy()
    obs_s, aux_s = batch.physics_obs.copy(), batch.aux.copy()
    obs_o, aux_o = batch.physics_obs.copy(), batch.aux.copy()
    rng = np.random.default_rng(0)
    slid = 0
    for _ in range(50):
        torques = rng.uniform(-1, 1, (1, 4))
        split.step(q, u, torques, obs_s, aux_s)
        one.step(q1, u1, torques, obs_o, aux_o)
        assert aux_s[0, AUX_FAILED] == 0.0 and aux_o[0, AUX_FAILED] == 0.0
        np.testing.assert_array_equal(q, q1)
        np.testing.assert_array_equal(u, u1)
        np.testing.assert_array_equal(obs_s, obs_o)
        np.testing.assert_array_equal(split.wheels.qdot, one.qdot)
        np.testing.assert_array_equal(split.slip, one.slip)
        assert aux_s[0, AUX_WORK] == pytest.approx(aux_o[0, AUX_WORK], rel=1e-12, abs=1e-15)
        assert aux_s[0, AUX_KINETIC] == aux_o[0, AUX_KINETIC]
        slid += int(one.slip.sum())
    assert slid > 0  # random torques slide wheels: the comparison covers sliding substeps


def test_env_step_equals_the_sliding_physics_stepped_substep_by_substep():
    """The env with a lag and a latency against the sliding physics of one sim_dt stepped here under the lag's
    means: the same states and wheel state bit for bit, the summed work, and the wheels that slid."""
    lag, latency = 0.025, 0.02
    env = started_env(4, torque_lag=lag, control_latency=latency)
    batch = env.unwrapped._batch
    params = batch.params
    instant = dataclasses.replace(batch.config, torque_lag=0.0, control_latency=0.0)
    one = dataclasses.replace(params, frame_skip=1, energy_tolerance=params.energy_tolerance / params.frame_skip)
    wheels = SlidingWheelPhysics(instant, one, num_envs=1)
    q, u = batch.q.copy(), batch.u.copy()
    wheels.set_state(q, u)
    obs, aux = batch.physics_obs.copy(), batch.aux.copy()
    h = params.sim_dt
    decay, weight = math.exp(-h / lag), -math.expm1(-h / lag) / (h / lag)
    state, previous = np.zeros((1, 4)), np.zeros((1, 4))
    rng = np.random.default_rng(1)
    slid = 0
    for _ in range(40):
        action = rng.uniform(-1, 1, 4)
        command = action[None] * env.unwrapped.max_torque
        work = 0.0
        for j in range(params.frame_skip):
            arrived = previous if j < round(latency / h) else command
            held = arrived + (state - arrived) * weight
            state = arrived + (state - arrived) * decay
            wheels.step(q, u, held, obs, aux)
            assert aux[0, AUX_FAILED] == 0.0
            work += aux[0, AUX_WORK]
        previous = command
        _, _, _, _, info = env.step(action)
        np.testing.assert_array_equal(batch.q, q)
        np.testing.assert_array_equal(batch.physics.wheels.qdot, wheels.qdot)
        np.testing.assert_array_equal(info["wheel_slip"], wheels.slip[0])
        np.testing.assert_array_equal(batch.physics.held, held)
        assert info["power"] * env.unwrapped.dt == pytest.approx(work, rel=1e-12, abs=1e-15)
        slid += int(wheels.slip.sum())
    assert slid > 0


def test_work_energy_balance_holds_with_the_friction_work():
    """K1 - K0 equals the work of all loads, the sliding wheels' friction included, over every env step."""
    env = SnakeEnv(n_links=8, torque_lag=0.02, control_latency=0.01)
    env.reset(seed=0)
    rng = np.random.default_rng(2)
    kinetic = env.unwrapped._batch.aux[0, AUX_KINETIC]
    for _ in range(100):
        _, _, _, _, info = env.step(rng.uniform(-1, 1, 7))
        assert not info["sim_failure"]
        work = info["power"] * env.unwrapped.dt
        assert abs(info["kinetic_energy"] - kinetic - work) <= 1e-2 * (max(kinetic, info["kinetic_energy"]) + 1e-3)
        kinetic = info["kinetic_energy"]


def test_a_failed_step_is_undone_with_its_lag_and_wheel_state():
    """A step the check refuses keeps the pre-step state, observation, the lag's state and the wheels' own."""
    env = started_env(1, torque_lag=0.02)
    rng = np.random.default_rng(3)
    for _ in range(5):  # wheels moving and sliding before the failing step
        *_, before = env.step(rng.uniform(-1, 1, 4))
    batch = env.unwrapped._batch
    q0, obs0 = batch.q.copy(), batch.physics_obs.copy()
    torque0, qdot0, impulse0 = (batch.physics.torque.copy(), batch.physics.wheels.qdot.copy(),
                                batch.physics.wheels.impulse.copy())
    # every sim_dt piece passes its own check; the env step's balance, checked over the whole step, fails: the
    # pieces have moved the wheels' state, which the undo must put back
    batch.physics.params = dataclasses.replace(batch.physics.params, energy_tolerance=1e-300)
    with pytest.warns(RuntimeWarning, match="simulation failure"):
        _, reward, _, _, info = env.step(np.ones(4))
    assert info["sim_failure"] and reward == 0.0 and info["x_velocity"] == 0.0
    np.testing.assert_array_equal(batch.q, q0)
    np.testing.assert_array_equal(batch.physics_obs, obs0)
    np.testing.assert_array_equal(batch.physics.torque, torque0)
    np.testing.assert_array_equal(batch.physics.wheels.qdot, qdot0)
    np.testing.assert_array_equal(batch.physics.wheels.impulse, impulse0)
    np.testing.assert_array_equal(info["wheel_lateral_force"], before["wheel_lateral_force"])  # the restored ones


def test_vector_rows_equal_single_envs_and_autoreset_clears_the_lag():
    kwargs = dict(n_links=5, torque_lag=0.03, control_latency=0.02)
    vec = SnakeVectorEnv(num_envs=3, max_episode_steps=6, **kwargs)
    vec.reset(seed=2)
    q, u = vec.state
    singles = []
    for b in range(3):
        env = SnakeEnv(**kwargs)
        env.set_state(q[b], u[b])
        singles.append(env)
    assert_rows_step_like_singles(vec, singles, np.random.default_rng(4), 5,
                                  ["actuator_power", "wheel_lateral_force", "wheel_slip"])
    response = vec._batch.physics
    assert isinstance(response, ActuatorResponse) and response.wheels is not None
    assert np.all(response.torque != 0.0)
    vec.step(np.ones((3, 4), np.float32))  # the 6th step truncates; the next one resets
    vec.step(np.ones((3, 4), np.float32))
    np.testing.assert_array_equal(response.torque, 0.0)
    np.testing.assert_array_equal(response.previous_command, 0.0)


def test_sliding_wheels_take_a_lag_and_randomized_robots():
    """The default wheels take every motor-response and randomization setting (the no-slip wheels' set)."""
    config = PhysicsConfig(torque_lag=0.01, control_latency=0.01, randomize=True)
    assert config.wheel_model == "sliding" and "control_latency" in config.randomized
    with pytest.raises(ValueError, match="control_latency must be a whole number") as error:
        PhysicsConfig(control_latency=0.015)
    assert "\n" not in str(error.value)
