"""SnakeSB3VecEnv against SB3's own DummyVecEnv on the single env, SB3's
wrappers (VecCheckNan, VecMonitor, VecNormalize) and a short PPO run."""

import os

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import DummyVecEnv, VecCheckNan, VecEnv, VecMonitor, VecNormalize

from snake_env.agents.sb3_vec_env import SnakeSB3VecEnv
from snake_env.envs import SnakeVectorEnv

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")


def _compare(a, b):
    if isinstance(a, np.ndarray):
        np.testing.assert_array_equal(a, b)
    else:
        assert a == b


def test_matches_dummy_vec_env_on_the_single_env_across_episode_ends():
    """Same seed, same actions: obs, rewards, dones, every info entry (including
    terminal_observation and TimeLimit.truncated) and reset_infos agree exactly."""
    ours = SnakeSB3VecEnv("snake_env/Snake3-v2", num_envs=1, max_episode_steps=30)
    ref = DummyVecEnv([lambda: gym.make("snake_env/Snake3-v2", max_episode_steps=30)])
    ours.seed(5)
    ref.seed(5)
    np.testing.assert_array_equal(ours.reset(), ref.reset())
    assert ours.reset_infos == ref.reset_infos
    actions = np.random.default_rng(1).uniform(-1, 1, (70, 1, 2)).astype(np.float32)
    ends = 0
    for a in actions:
        obs1, rew1, done1, infos1 = ours.step(a)
        obs2, rew2, done2, infos2 = ref.step(a)
        np.testing.assert_array_equal(obs1, obs2)
        np.testing.assert_array_equal(rew1, rew2)
        np.testing.assert_array_equal(done1, done2)
        assert rew1.dtype == rew2.dtype and done1.dtype == done2.dtype
        assert infos1[0].keys() == infos2[0].keys()
        for key in infos1[0]:
            _compare(infos1[0][key], infos2[0][key])
        assert ours.reset_infos == ref.reset_infos
        ends += int(done1[0])
    assert ends == 2
    assert infos1[0]["TimeLimit.truncated"] is False


def test_many_envs_terminal_observation_convention():
    venv = SnakeSB3VecEnv("snake_env/Snake5-v2", num_envs=4, max_episode_steps=5)
    assert isinstance(venv, VecEnv) and venv.num_envs == 4
    venv.seed(0)
    venv.reset()
    a = np.zeros((4, 4), np.float32)
    for _ in range(4):
        _, _, dones, infos = venv.step(a)
        assert not dones.any() and all("terminal_observation" not in i for i in infos)
    obs, rewards, dones, infos = venv.step(a)
    assert dones.all()
    for i in range(4):
        assert infos[i]["TimeLimit.truncated"] is True
        assert infos[i]["terminal_observation"].shape == (12,)
        assert not np.array_equal(infos[i]["terminal_observation"], obs[i])  # obs is the new episode's
        assert abs(venv.reset_infos[i]["x_position"]) < 1e-15
    assert venv.observation_space.contains(obs[0])


def test_attribute_access_and_seeding():
    venv = SnakeSB3VecEnv("snake_env/Snake3-v2", num_envs=3, ctrl_cost_weight=0.5)
    assert venv.get_attr("ctrl_cost_weight") == [0.5] * 3
    assert venv.get_attr("n_links", indices=[0, 2]) == [3, 3]
    venv.set_attr("ctrl_cost_weight", 0.25)
    assert venv.get_attr("ctrl_cost_weight", 1) == [0.25]
    with pytest.raises(ValueError, match="indices"):
        venv.set_attr("ctrl_cost_weight", 0.1, indices=[0])
    assert venv.env_is_wrapped(gym.Wrapper) == [False] * 3
    assert venv.env_method("__repr__", indices=[1])[0].startswith("SnakeVectorEnv")
    venv.seed(3)
    first = venv.reset()
    venv.seed(3)
    np.testing.assert_array_equal(venv.reset(), first)
    assert not np.array_equal(venv.reset(), first)


def test_construction_errors():
    with pytest.raises(ValueError, match="SameStep"):
        SnakeSB3VecEnv(SnakeVectorEnv(num_envs=2))
    with pytest.raises(ValueError, match="num_envs"):
        SnakeSB3VecEnv(SnakeVectorEnv(num_envs=2, autoreset_mode="SameStep"), num_envs=2)
    with pytest.raises(ValueError, match="snake_env id"):
        SnakeSB3VecEnv(42)
    with pytest.raises(ValueError, match="action"):
        venv = SnakeSB3VecEnv("snake_env/Snake3-v2", num_envs=2)
        venv.reset()
        venv.step(np.full((2, 2), np.nan, np.float32))


def test_rgb_array_images_tile():
    venv = SnakeSB3VecEnv("snake_env/Snake3-v2", num_envs=2, render_mode="rgb_array", width=40, height=30)
    venv.reset()
    venv.step(np.zeros((2, 2), np.float32))
    images = venv.get_images()
    assert [im.shape for im in images] == [(30, 40, 3)] * 2
    np.testing.assert_array_equal(venv.render(), np.concatenate(images, axis=0))  # SB3 tiles 2 frames in a column


def test_ppo_trains_through_sb3_wrappers(tmp_path):
    venv = SnakeSB3VecEnv("snake_env/Snake5-v2", num_envs=4, max_episode_steps=50)
    venv = VecNormalize(VecMonitor(VecCheckNan(venv, raise_exception=True)), gamma=0.99)
    model = PPO("MlpPolicy", venv, n_steps=64, batch_size=64, n_epochs=1, seed=0, device="cpu",
                policy_kwargs=dict(net_arch=[16]))
    model.learn(total_timesteps=512)
    assert model.num_timesteps == 512
    episodes = list(model.ep_info_buffer)  # VecMonitor's infos["episode"] as PPO collected them
    assert len(episodes) >= 8 and all(ep["l"] == 50 for ep in episodes)
    assert np.all(np.isfinite(venv.obs_rms.mean)) and venv.obs_rms.count > 512
    model.save(tmp_path / "ppo")
    venv.save(tmp_path / "vecnormalize.pkl")
    eval_env = VecNormalize.load(tmp_path / "vecnormalize.pkl", SnakeSB3VecEnv("snake_env/Snake5-v2", num_envs=1))
    np.testing.assert_array_equal(eval_env.obs_rms.mean, venv.obs_rms.mean)
    obs = eval_env.reset()
    action, _ = PPO.load(tmp_path / "ppo", device="cpu").predict(obs, deterministic=True)
    assert action.shape == (1, 4)
