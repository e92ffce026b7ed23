"""SnakeEnv: the Gymnasium API contract, input checks, determinism, pickling,
and the reported quantities cross-checked against the numpy dynamics."""

import copy
import math
import pickle
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from snake_env.envs import SnakeEnv

from .conftest import ALL_IDS


@pytest.mark.parametrize("env_id", ALL_IDS)
def test_gymnasium_and_sb3_checkers_pass(env_id):
    env = gym.make(env_id, render_mode="rgb_array")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # the only expected warnings: unbounded Box observations (physical speeds have no bound)
        warnings.filterwarnings("ignore", message=".*observation space (minimum|maximum) value is")
        check_env(env.unwrapped, skip_render_check=False)
        sb3_check_env(env.unwrapped, warn=True)
    assert env.spec.max_episode_steps == 1000
    env.close()


def test_make_without_prior_import():
    code = ("import gymnasium as gym, sys; env = gym.make('snake_env:snake_env/Snake5-v2'); "
            "obs, _ = env.reset(seed=0); print(obs.shape, type(env.unwrapped).__name__)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    assert out.stdout.split() == ["(12,)", "SnakeEnv"]


def test_snake_v1_takes_n_links():
    env = gym.make("snake_env/Snake-v2", n_links=7)
    assert env.action_space.shape == (6,)
    assert env.observation_space.shape == (16,)


def _rollout(env, seed, steps, action_seed=0):
    obs, _ = env.reset(seed=seed)
    actions = np.random.default_rng(action_seed).uniform(-1, 1, (steps,) + env.action_space.shape).astype(np.float32)
    out = [obs]
    for a in actions:
        obs, reward, terminated, truncated, info = env.step(a)
        out.append(np.concatenate([obs, [reward, info["x_position"], info["power"]]]))
    return np.concatenate(out)


def test_same_seed_same_rollout_different_seed_differs():
    env = gym.make("snake_env/Snake5-v2")
    a = _rollout(env, 7, 200)
    b = _rollout(gym.make("snake_env/Snake5-v2"), 7, 200)
    c = _rollout(env, 8, 200)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_reset_is_near_straight_and_centred():
    env = SnakeEnv(n_links=8, reset_noise_scale=0.1)
    model = env.model
    for seed in range(5):
        obs, info = env.reset(seed=seed)
        q, u = env.state
        assert np.all(np.abs(q[:8]) <= 0.1) and np.all(np.abs(u) <= 0.1)
        np.testing.assert_allclose(model.center_of_mass(q), 0.0, atol=1e-15)
        assert info["distance_from_origin"] < 1e-15
        np.testing.assert_allclose(info["kinetic_energy"], model.kinetic_energy(q, u), rtol=1e-13)


def test_observation_layout_matches_the_dynamics(rng):
    """Each block of the observation against SnakeModel's numpy kinematics (the no-slip wheels, whose state is
    (q, u); on sliding wheels the rates come from the chain's own velocities, tests/physics/test_sliding_wheels.py)."""
    n = 6
    env = SnakeEnv(n_links=n, exclude_current_positions_from_observation=False, wheel_model="no_slip")
    env.reset(seed=1)
    for _ in range(30):
        obs, _, _, _, info = env.step(rng.uniform(-1, 1, n - 1))
    q, u = env.state
    model = env.model
    sizes = env.observation_structure
    assert sizes["skipped_position"] == 0 and sum(v for k, v in sizes.items() if not k.startswith("skipped")) == obs.size
    blocks = np.split(obs, np.cumsum([sizes[k] for k in ("position", "joint_angles", "heading", "generalized_speeds")]))
    xy, phi, heading, speeds, rates = blocks
    np.testing.assert_allclose(xy, model.center_of_mass(q), atol=1e-14)
    np.testing.assert_allclose(xy, [info["x_position"], info["y_position"]], atol=0)
    dphi = np.diff(q[:n])
    np.testing.assert_allclose(np.cos(phi), np.cos(dphi), atol=1e-12)
    np.testing.assert_allclose(np.sin(phi), np.sin(dphi), atol=1e-12)
    assert np.all(np.abs(phi) <= np.pi)
    np.testing.assert_allclose(heading, [np.cos(q[0]), np.sin(q[0])], atol=1e-15)
    np.testing.assert_array_equal(speeds, u)
    _, omega = model.link_velocities(q, u)
    np.testing.assert_allclose(rates, np.diff(omega), atol=1e-12)
    np.testing.assert_allclose(info["kinetic_energy"], model.kinetic_energy(q, u), rtol=1e-12)
    assert env.observation_space.contains(obs)


def test_reward_is_cm_velocity_minus_control_cost(rng):
    env = SnakeEnv(n_links=5, forward_reward_weight=2.0, ctrl_cost_weight=0.1)
    env.reset(seed=3)
    x_prev, y_prev = env.model.center_of_mass(env.state[0])
    for _ in range(20):
        action = rng.uniform(-1.5, 1.5, 4)  # partly out of range: clipped
        _, reward, terminated, truncated, info = env.step(action)
        x, y = env.model.center_of_mass(env.state[0])
        clipped = np.clip(action, -1, 1)
        np.testing.assert_allclose(info["x_velocity"], (x - x_prev) / env.dt, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(info["y_velocity"], (y - y_prev) / env.dt, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(info["reward_ctrl"], -0.1 * np.sum(clipped ** 2), rtol=1e-12)
        np.testing.assert_allclose(reward, 2.0 * info["x_velocity"] + info["reward_ctrl"], rtol=1e-12, atol=1e-15)
        assert info["reward_forward"] == 2.0 * info["x_velocity"]
        assert math.isclose(info["distance_from_origin"], math.hypot(x, y), rel_tol=1e-12)
        assert not terminated and not truncated and info["sim_failure"] is False
        x_prev, y_prev = x, y


def test_actions_are_clipped_and_bad_actions_rejected():
    env = SnakeEnv(n_links=4)
    env.reset(seed=0)
    state = env.state
    big = env.step(np.array([5.0, -7.0, 1.0]))[0]
    env.set_state(*state)
    unit = env.step(np.array([1.0, -1.0, 1.0]))[0]
    np.testing.assert_array_equal(big, unit)
    for bad in ([np.nan, 0, 0], [0, np.inf, 0], [0.0, 0.0], np.zeros((1, 3)), "abc", [[0, 0, 0]]):
        with pytest.raises(ValueError, match="action"):
            env.step(bad)
    # a rejected action changes nothing: the next step is the one it would have been
    env.set_state(*state)
    for bad in ([1.0, 1.0, np.nan], [np.inf, 0.5, 0.5]):
        with pytest.raises(ValueError, match="finite"):
            env.step(bad)
    np.testing.assert_array_equal(env.step(np.array([1.0, -1.0, 1.0]))[0], unit)


def test_step_before_reset_is_an_error():
    with pytest.raises(gym.error.ResetNeeded):
        SnakeEnv().step(np.zeros(4))


@pytest.mark.parametrize("kwargs, name", [
    (dict(n_links=1), "n_links"),
    (dict(n_links=2.5), "n_links"),
    (dict(sim_dt=0.0), "sim_dt"),
    (dict(sim_dt=float("nan")), "sim_dt"),
    (dict(frame_skip=0), "frame_skip"),
    (dict(frame_skip=2.0), "frame_skip"),
    (dict(max_torque=-1.0), "max_torque"),
    (dict(ctrl_cost_weight=-1e-3), "ctrl_cost_weight"),
    (dict(reset_noise_scale=float("inf")), "reset_noise_scale"),
    (dict(joint_damping=-0.1), "joint_damping"),
    (dict(wheel_damping="x"), "wheel_damping"),
    (dict(joint_limit=4.0), "joint_limit"),
    (dict(joint_limit=0.0), "joint_limit"),
    (dict(joint_limit_stiffness=-1.0), "joint_limit_stiffness"),
    (dict(paper_model="yes"), "paper_model"),
    (dict(paper_model=True, joint_damping=0.5), "paper_model"),
    (dict(paper_model=True, joint_limit=1.0), "paper_model"),
    (dict(exclude_current_positions_from_observation=1), "exclude_current_positions_from_observation"),
    (dict(render_mode="rgb"), "render_mode"),
    (dict(width=0), "width"),
    (dict(mass=-1.0), "mass"),
])
def test_bad_kwargs_raise_value_error_naming_the_argument(kwargs, name):
    with pytest.raises(ValueError, match=name):
        SnakeEnv(**kwargs)


def test_paper_model_switches_off_damping_and_limits():
    env = SnakeEnv(paper_model=True)
    assert env.joint_damping == 0.0 and env.wheel_damping == 0.0 and env.joint_limit is None
    assert env.params.joint_limit == 0.0
    assert np.all(env.params.joint_damping == 0.0) and np.all(env.params.wheel_damping == 0.0)
    explicit = SnakeEnv(joint_damping=0.0, wheel_damping=0.0, joint_limit=None, actuator="ideal", wheel_friction=None)
    a = _rollout(env, 4, 100)
    b = _rollout(explicit, 4, 100)
    np.testing.assert_array_equal(a, b)


def test_pickle_mid_episode_continues_identically(rng):
    env = gym.make("snake_env/Snake5-v2", render_mode="rgb_array")
    env.reset(seed=11)
    for _ in range(10):
        env.step(rng.uniform(-1, 1, 4))
    env.render()
    clone = pickle.loads(pickle.dumps(env))
    actions = rng.uniform(-1, 1, (20, 4))
    for a in actions:
        r1 = env.step(a)
        r2 = clone.step(a)
        np.testing.assert_array_equal(r1[0], r2[0])
        assert r1[1:4] == r2[1:4]
    np.testing.assert_array_equal(env.render(), clone.render())
    env.reset()
    clone.reset()
    np.testing.assert_array_equal(env.unwrapped.state[0], clone.unwrapped.state[0])  # same generator state


@pytest.mark.parametrize("copier", [copy.deepcopy, lambda env: pickle.loads(pickle.dumps(env))],
                         ids=["deepcopy", "pickle"])
def test_copies_step_their_own_buffers(copier, rng):
    # the single env's physics step and common values are bound to its buffers (BoundKernel): a copy binds
    # to its own, so stepping it never moves the original, and each continues as an untouched twin does
    env, twin = gym.make("snake_env/Snake5-v3"), gym.make("snake_env/Snake5-v3")
    env.reset(seed=3)
    twin.reset(seed=3)
    for a in rng.uniform(-1, 1, (10, 4)):
        env.step(a)
        twin.step(a)
    clone, other = copier(env), copier(env)
    for a in rng.uniform(-1, 1, (10, 4)):
        other.step(a)  # moves only ``other``
    for a in rng.uniform(-1, 1, (10, 4)):
        results = [e.step(a) for e in (env, twin, clone)]
        for r in results[1:]:
            np.testing.assert_array_equal(results[0][0], r[0])
            assert results[0][1:4] == r[1:4]
            assert results[0][4]["x_velocity"] == r[4]["x_velocity"]
            np.testing.assert_array_equal(results[0][4]["wheel_lateral_force"], r[4]["wheel_lateral_force"])


def test_non_finite_state_ends_the_episode_without_nan():
    env = SnakeEnv(n_links=5)
    env.reset(seed=0)
    q, u = env.state
    obs_before = env.set_state(q, np.array([1e150, 1e150]))  # finite, but udot ~ u^2 overflows in RK4
    with pytest.warns(RuntimeWarning, match="non-finite"):
        obs, reward, terminated, truncated, info = env.step(np.ones(4))
    assert info["sim_failure"] is True and truncated is True and terminated is False
    assert np.all(np.isfinite(obs)) and np.isfinite(reward)
    np.testing.assert_array_equal(obs, obs_before)  # the step was undone
    assert all(np.all(np.isfinite(v)) for v in info.values())


def test_time_limit_comes_from_the_registration():
    env = gym.make("snake_env/Snake3-v2", max_episode_steps=5)
    env.reset(seed=0)
    flags = [env.step(env.action_space.sample())[3] for _ in range(5)]
    assert flags == [False] * 4 + [True]


def test_info_keys():
    env = gym.make("snake_env/Snake5-v2")
    _, reset_info = env.reset(seed=0)
    assert set(reset_info) == {"x_position", "y_position", "distance_from_origin", "kinetic_energy"}
    info = env.step(env.action_space.sample())[4]
    assert set(info) == {"x_position", "y_position", "distance_from_origin", "x_velocity", "y_velocity",
                         "reward_forward", "reward_ctrl", "kinetic_energy", "power", "actuator_power", "sim_failure"}
    gripped = gym.make("snake_env/Snake5-v2", wheel_friction=1.0)  # the grip modelled: the wheels' forces too
    # the step reads the forces from the lane kernel's last traction pass, wheel_lateral_forces() from a sweep
    # of its own: the same forces to rounding (a few 1e-16 N on forces of ~1-10 N on some actions), not bit for
    # bit; seeded actions, among them traction-limited steps (scale < 1)
    gripped.action_space.seed(0)
    scales = []
    for _ in range(40):
        gripped.reset(seed=0)
        info = gripped.step(gripped.action_space.sample())[4]
        assert info["wheel_lateral_force"].shape == info["wheel_slip"].shape == (5,)
        np.testing.assert_allclose(info["wheel_lateral_force"], gripped.unwrapped.wheel_lateral_forces(),
                                   rtol=0.0, atol=1e-12)
        scales.append(info["traction_scale"])
    assert min(scales) < 1.0 and max(scales) == 1.0
