"""info["wheel_lateral_force"]: the compiled backward sweep at the step's final state and held torques
equals eq. 27's multipliers (Lagrange and Newton–Euler) of the torques the traction limit lets through while
no joint limit acts; wheel_slip compares it
with mu m_k g (beyond rounding, physics.config.sliding); the single and the vector env report the same forces."""

import gymnasium as gym
import numpy as np
import pytest

from snake_env.dynamics import lagrange, newton_euler
from snake_env.envs import SnakeEnv
from snake_env.physics import AUX_REFINEMENTS, GRAVITY
from snake_env.physics.config import sliding


@pytest.mark.parametrize("n_links", [3, 5, 12])
def test_reported_forces_are_the_multipliers_of_eq_27(n_links):
    env = SnakeEnv(wheel_model="no_slip", n_links=n_links, wheel_friction=0.8, actuator="ideal")  # the torques: scale * commands
    model, limit = env.unwrapped.model, env.unwrapped.joint_limit
    env.reset(seed=1)
    rng = np.random.default_rng(1)
    checked = 0
    for _ in range(60):
        action = rng.uniform(-0.5, 0.5, n_links - 1)
        _, _, _, _, info = env.step(action)
        q, u = env.state
        if np.any(np.abs(np.diff(q[:n_links])) >= limit):
            continue  # the barrier acts: not in the dynamics package's formulations
        qdot = lagrange.consistent_qdot(model, q, u)
        # the traction limit lets through the share info["traction_scale"] of the torques (test_traction.py)
        torques = info["traction_scale"] * action * env.max_torque
        for formulation in (lagrange, newton_euler):
            _, reference = formulation.qddot(model, q, qdot, torques, with_multipliers=True)
            scale = np.max(np.abs(reference)) + 1.0
            assert np.max(np.abs(info["wheel_lateral_force"] - reference)) / scale < 1e-9
        load = np.broadcast_to(env.mass, (n_links,)) * GRAVITY
        np.testing.assert_array_equal(info["wheel_slip"], sliding(info["wheel_lateral_force"], 0.8 * load))
        checked += 1
    assert checked >= 30


def test_vector_env_reports_the_single_envs_forces_and_ample_grip_never_slips():
    """num_envs=1 reproduces the single env (same seed), per-wheel info included; without wheel_friction
    the info leaves the wheels out (their sweep is not paid for)."""
    vec = gym.make_vec("snake_env/Snake5-v2", num_envs=1, vectorization_mode="vector_entry_point",
                       wheel_friction=1e6)
    single = gym.make("snake_env/Snake5-v2", wheel_friction=1e6)
    vec.reset(seed=7)
    single.reset(seed=7)
    for action in np.random.default_rng(0).uniform(-1, 1, (40, 1, 4)):
        _, _, _, _, info = vec.step(action)
        assert info["wheel_lateral_force"].shape == (1, 5) and not info["wheel_slip"].any()
        assert np.array_equal(single.step(action[0])[4]["wheel_lateral_force"], info["wheel_lateral_force"][0])
    plain = gym.make("snake_env/Snake5-v2")
    plain.reset(seed=0)
    assert "wheel_lateral_force" not in plain.step(action[0])[4]


def test_step_reports_the_forces_of_their_own_sweep_on_every_path():
    """The step reads the wheel forces from the integrator's last traction pass (the final state's k5
    sweep) for snakes the lanes finished, and sweeps anew for refined or undone ones: both equal
    the separate sweep of the final state (SnakeEnv.wheel_lateral_forces)."""
    vec = gym.make_vec("snake_env/Snake5-v3", num_envs=64, vectorization_mode="vector_entry_point")
    core = vec.unwrapped._batch
    vec.reset(seed=3)
    refined = lane = 0
    for action in np.random.default_rng(3).uniform(-1, 1, (30, 64, 4)):
        _, _, _, _, info = vec.step(action)
        reported, scale = info["wheel_lateral_force"], info["traction_scale"]
        again = core.wheel_lateral_forces()
        bound = np.max(np.abs(again), axis=1, keepdims=True) + 1.0
        assert np.all(np.abs(reported - again) / bound < 1e-12)
        np.testing.assert_allclose(scale, core.traction_scale, rtol=0, atol=1e-12)
        redone = core.aux[:, AUX_REFINEMENTS] > 0
        refined += redone.sum()
        lane += (~redone).sum()
    assert refined > 0 and lane > 0  # both paths ran


def test_bad_friction_is_a_one_line_error():
    for value in (0.0, -1.0, float("inf")):
        with pytest.raises(ValueError, match="wheel_friction must be a finite number > 0"):
            SnakeEnv(wheel_model="no_slip", wheel_friction=value)
