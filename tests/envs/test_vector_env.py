"""SnakeVectorEnv: make_vec, equality with the single env, Gymnasium's
autoreset modes, info masks, input checks, pickling."""

import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

from snake_env.envs import SnakeEnv, SnakeVectorEnv
from snake_env.envs.snake import STEP_INFO_KEYS
from tests.rows import assert_rows_step_like_singles


def test_make_vec_builds_the_batched_env():
    envs = gym.make_vec("snake_env/Snake8-v2", num_envs=3, vectorization_mode="vector_entry_point", ctrl_cost_weight=0.01)
    assert isinstance(envs, SnakeVectorEnv)
    assert envs.num_envs == 3 and envs.n_links == 8 and envs.max_episode_steps == 1000
    assert envs.ctrl_cost_weight == 0.01
    assert envs.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert envs.action_space.shape == (3, 7) and envs.observation_space.shape == (3, 18)
    obs, info = envs.reset(seed=0)
    assert envs.observation_space.contains(obs)
    obs, rewards, terminated, truncated, info = envs.step(envs.action_space.sample())
    assert rewards.shape == terminated.shape == truncated.shape == (3,)
    assert set(STEP_INFO_KEYS) <= set(info) and all(info["_" + k].all() for k in STEP_INFO_KEYS)


def test_default_vectorization_mode_is_the_vector_entry_point():
    assert isinstance(gym.make_vec("snake_env/Snake3-v2", num_envs=2), SnakeVectorEnv)


@pytest.mark.parametrize("n", [3, 12])
def test_num_envs_1_reproduces_the_single_env_through_autoresets(n):
    """Same seed, same actions: identical observations, rewards, flags and infos, bit for bit,
    across two time-limit ends (the single env is reset by hand, the vector env autoresets)."""
    env_id = f"snake_env/Snake{n}-v2"
    single = gym.make(env_id, max_episode_steps=40)
    vec = gym.make_vec(env_id, num_envs=1, vectorization_mode="vector_entry_point", max_episode_steps=40)
    obs1, info1 = single.reset(seed=5)
    obs2, info2 = vec.reset(seed=5)
    np.testing.assert_array_equal(obs1, obs2[0])
    actions = np.random.default_rng(0).uniform(-1.2, 1.2, (100, 1, n - 1)).astype(np.float32)
    done = False
    for a in actions:
        if done:
            obs1, info1 = single.reset()
            reward1, term1, trunc1 = 0.0, False, False
        else:
            obs1, reward1, term1, trunc1, info1 = single.step(a[0])
        obs2, reward2, term2, trunc2, info2 = vec.step(a)
        np.testing.assert_array_equal(obs1, obs2[0])
        assert (reward1, term1, trunc1) == (reward2[0], term2[0], trunc2[0])
        for key, value in info1.items():
            assert info2["_" + key][0] and np.array_equal(info2[key][0], value), key
        done = term1 or trunc1


def test_batch_rows_equal_independent_single_envs(rng):
    """B = 4 with different states: each row evolves as a single env started from it."""
    vec = SnakeVectorEnv(num_envs=4, n_links=5)
    vec.reset(seed=1)
    q, u = vec.state
    singles = []
    for b in range(4):
        env = SnakeEnv(n_links=5)
        env.set_state(q[b], u[b])
        singles.append(env)
    assert_rows_step_like_singles(vec, singles, rng, 25, ["power"])


def test_next_step_autoreset_semantics():
    vec = SnakeVectorEnv(num_envs=2, n_links=3, max_episode_steps=3)
    vec.reset(seed=0)
    zeros = np.zeros((2, 2), np.float32)
    for _ in range(2):
        assert not vec.step(zeros)[3].any()
    obs_end, _, _, truncated, _ = vec.step(zeros)
    assert truncated.all()
    obs, rewards, terminated, truncated, info = vec.step(np.ones((2, 2), np.float32))  # actions ignored
    assert not terminated.any() and not truncated.any() and np.all(rewards == 0.0)
    assert not info["_x_velocity"].any() and info["_x_position"].all()
    np.testing.assert_allclose(info["x_position"], 0.0, atol=1e-15)  # reset: CM at the origin
    assert not np.allclose(obs, obs_end)
    assert not vec.step(zeros)[3].any()  # a fresh episode


def test_same_step_autoreset_gives_final_obs_and_info():
    vec = SnakeVectorEnv(num_envs=3, n_links=4, max_episode_steps=4, autoreset_mode="SameStep",
                         wheel_model="no_slip")  # set_state restarts sliding wheels gripping: (q, u) is no-slip's
    assert vec.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    vec.reset(seed=0)
    a = np.full((3, 3), 0.5, np.float32)
    for _ in range(3):
        obs, _, _, truncated, info = vec.step(a)
        assert "final_obs" not in info and not truncated.any()
    last_state = vec.state
    obs, rewards, terminated, truncated, info = vec.step(a)
    assert truncated.all() and info["_final_obs"].all()
    # the final observation is that of stepping the last state, the returned one a reset
    ref = SnakeEnv(n_links=4, wheel_model="no_slip")
    for b in range(3):
        ref.set_state(last_state[0][b], last_state[1][b])
        final_obs, final_reward, _, _, final_info = ref.step(a[b])
        np.testing.assert_array_equal(info["final_obs"][b], final_obs)
        assert info["final_info"]["x_velocity"][b] == final_info["x_velocity"] and rewards[b] == final_reward
    np.testing.assert_allclose(info["x_position"], 0.0, atol=1e-15)
    assert not info["_x_velocity"].any()
    assert not vec.step(a)[3].any()


def test_disabled_autoreset_and_reset_mask():
    vec = SnakeVectorEnv(num_envs=3, n_links=3, max_episode_steps=2, autoreset_mode=AutoresetMode.DISABLED)
    vec.reset(seed=0)
    a = np.zeros((3, 2), np.float32)
    vec.step(a)
    assert vec.step(a)[3].all()
    with pytest.raises(ValueError, match="reset_mask"):
        vec.step(a)
    q_before = vec.state[0]
    mask = np.array([True, False, True])
    obs, info = vec.reset(options={"reset_mask": mask})
    assert list(info["_x_position"]) == [True, False, True]
    np.testing.assert_array_equal(vec.state[0][1], q_before[1])
    assert not np.array_equal(vec.state[0][0], q_before[0])
    with pytest.raises(ValueError, match="reset_mask"):  # sub-env 1 is still finished
        vec.step(a)
    vec.reset(options={"reset_mask": np.array([False, True, False])})
    assert not vec.step(a)[3].any()


def test_sim_failure_in_one_sub_env_only():
    vec = SnakeVectorEnv(num_envs=3, n_links=5)
    vec.reset(seed=0)
    q, u = vec.state
    u[1] = 1e150
    vec.set_state(q, u)
    with pytest.warns(RuntimeWarning, match="1 sub-env"):
        obs, rewards, terminated, truncated, info = vec.step(np.ones((3, 4), np.float32))
    assert list(truncated) == [False, True, False] and list(info["sim_failure"]) == [False, True, False]
    assert np.all(np.isfinite(obs)) and np.all(np.isfinite(rewards))
    obs, *_ = vec.step(np.ones((3, 4), np.float32))  # next step: sub-env 1 autoresets
    assert np.all(np.isfinite(obs)) and np.all(np.abs(vec.state[1][1]) <= 0.1)


@pytest.mark.parametrize("kwargs, name", [
    (dict(num_envs=0), "num_envs"),
    (dict(max_episode_steps=0), "max_episode_steps"),
    (dict(autoreset_mode="Later"), "autoreset_mode"),
    (dict(render_mode="human"), "render_mode"),
    (dict(sim_dt=-0.01), "sim_dt"),
    (dict(n_links=1), "n_links"),
])
def test_bad_kwargs(kwargs, name):
    with pytest.raises(ValueError, match=name):
        SnakeVectorEnv(**kwargs)


def test_bad_actions_and_seeds():
    vec = SnakeVectorEnv(num_envs=2, n_links=3)
    with pytest.raises(gym.error.ResetNeeded):
        vec.step(np.zeros((2, 2)))
    vec.reset(seed=0)
    for bad in (np.zeros(2), np.zeros((3, 2)), np.array([[0, np.nan], [0, 0]]), "x"):
        with pytest.raises(ValueError, match="action"):
            vec.step(bad)
    with pytest.raises(ValueError, match="seed"):
        vec.reset(seed=[1, 2])
    with pytest.raises(ValueError, match="reset_mask"):
        vec.reset(options={"reset_mask": np.array([1, 0])})


def test_pickle_continues_identically(rng):
    vec = SnakeVectorEnv(num_envs=3, n_links=5, max_episode_steps=10)
    vec.reset(seed=2)
    for _ in range(7):
        vec.step(rng.uniform(-1, 1, (3, 4)))
    clone = pickle.loads(pickle.dumps(vec))
    for a in rng.uniform(-1, 1, (8, 3, 4)):  # crosses the autoreset, so the generators are compared too
        r1, r2 = vec.step(a), clone.step(a)
        for x, y in zip(r1[:4], r2[:4]):
            np.testing.assert_array_equal(x, y)


def test_sync_vectorization_of_the_single_env_agrees():
    """Gymnasium's own SyncVectorEnv over SnakeEnv (num_envs=1, same seed) gives the same rollout."""
    ours = gym.make_vec("snake_env/Snake5-v2", num_envs=1, vectorization_mode="vector_entry_point", max_episode_steps=20)
    sync = gym.make_vec("snake_env/Snake5-v2", num_envs=1, vectorization_mode="sync", max_episode_steps=20)
    np.testing.assert_array_equal(ours.reset(seed=9)[0], sync.reset(seed=9)[0])
    for a in np.random.default_rng(3).uniform(-1, 1, (45, 1, 4)).astype(np.float32):
        r1, r2 = ours.step(a), sync.step(a)
        for x, y in zip(r1[:4], r2[:4]):
            np.testing.assert_array_equal(x, y)
        info1, info2 = r1[4], r2[4]
        present = {k for k in info1 if not k.startswith("_") and info1["_" + k][0]}
        assert present == {k for k in info2 if not k.startswith("_")}  # reset steps carry only the reset info
        for key in present:
            assert np.array_equal(info1[key][0], info2[key][0]), key
