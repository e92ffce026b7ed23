"""A task of one's own is one Task subclass, defined here and nowhere else: registered, checked,
stepped (single and vector env), trained by snake-train, evaluated by snake-eval with its own
metric, and its own baseline run by ``snake-eval --baseline``."""

from __future__ import annotations

import json
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import pytest
import yaml
from gymnasium.utils.env_checker import check_env

import snake_env
from snake_env.controllers import SerpenoidController, SerpenoidParams
from snake_env.physics.settings import setting
from snake_env.tasks import TASKS, Task
from snake_env.tasks.base import controller_geometry, mean_heading


@dataclass(frozen=True)
class SpinTask(Task):
    """Turn on the spot: reward = `spin_weight` x the rate of the mean link angle theta_bar (rad/s)."""

    spin_weight: float = setting(1.0, "per rad/s", doc="weight of the heading rate")

    name = "spin"
    id_prefix, version = "SnakeSpinTest", 0
    max_episode_steps = 200
    step_info_keys = ("reward_spin", "heading_rate")
    episode_metrics = {"mean_heading_rate": ("heading_rate", "mean")}
    baseline_name = "turn"

    def evaluate(self, config, ctx, state):
        n = config.n_links
        rate = (mean_heading(ctx.q, n) - mean_heading(ctx.q_prev, n)) / ctx.dt
        reward = self.spin_weight * rate
        return reward, np.zeros(rate.shape[0], bool), {"reward_spin": reward, "heading_rate": rate}

    @classmethod
    def make_baseline(cls, config, num_envs=1, gait=None, gaits=None, settings=None):
        """A travelling torque wave with an offset: the snake runs in a circle (with ideal torque sources
        and unlimited grip: on the default servos and finite grip its turn is weak and changes sign)."""
        turn = SerpenoidParams("torque", amplitude=0.6, frequency=10.0, phase_lag=1.0, offset=0.2)
        return SerpenoidController(turn, num_envs=num_envs, **controller_geometry(config))


ENV_ID = "snake_env/SnakeSpinTest4-v0"


@pytest.fixture(scope="module")
def registered():
    ids = snake_env.register_task(SpinTask, n_links=(4,))
    assert ids == ["snake_env/SnakeSpinTest-v0", ENV_ID]
    assert "spin" not in TASKS  # the shipped table is untouched
    yield
    for env_id in ids:
        gym.registry.pop(env_id)


def test_register_step_and_check(registered):
    spec = gym.spec(ENV_ID)
    assert spec.kwargs == {"task": SpinTask, "n_links": 4} and spec.max_episode_steps == 200
    env = gym.make(ENV_ID, spin_weight=2.0)
    check_env(env.unwrapped, skip_render_check=True)
    obs, info = env.reset(seed=0)
    assert obs.shape == (10,) and env.action_space.shape == (3,)
    obs, reward, terminated, truncated, info = env.step(np.full(3, 0.5, np.float32))
    assert reward == pytest.approx(2.0 * info["heading_rate"]) and info["reward_spin"] == reward
    with pytest.raises(ValueError, match="spin_weight must be a finite number"):
        gym.make(ENV_ID, spin_weight=float("nan"))
    # the vector env steps the same task: its row 0 equals the single env from the same seed
    envs = gym.make_vec(ENV_ID, num_envs=3, vectorization_mode="vector_entry_point")
    single = gym.make(ENV_ID)
    vec_obs, _ = envs.reset(seed=5)
    one_obs, _ = single.reset(seed=5)
    np.testing.assert_array_equal(vec_obs[0], one_obs)
    for _ in range(5):
        action = np.full((3, 3), -0.4, np.float32)
        vec_obs, vec_reward, *_ = envs.step(action)
        one_obs, one_reward, *_ = single.step(action[0])
        assert vec_reward[0] == one_reward
    envs.close()
    single.close()


def test_train_evaluate_and_run_its_baseline(registered, tmp_path, capsys):
    from snake_env.train.evaluate import main as eval_main
    from snake_env.train.train import main as train_main

    config = tmp_path / "ppo.yaml"  # the task's own hyperparameters, RL Zoo style
    config.write_text(yaml.safe_dump({ENV_ID: {"n_envs": 2, "n_timesteps": 256, "n_steps": 64, "batch_size": 32,
                                               "n_epochs": 1, "normalize": True, "eval_freq": 128,
                                               "n_eval_episodes": 1, "policy_kwargs": "dict(net_arch=[8])"}}))
    run_dir = tmp_path / "spin"
    assert train_main(["--algo", "ppo", "--env", ENV_ID, "--config", str(config), "--run-dir", str(run_dir),
                       "--set", "env_kwargs.max_episode_steps=50", "--no-progress-bar"]) == 0
    assert (run_dir / "model.zip").is_file()
    out = tmp_path / "eval.json"
    assert eval_main([str(run_dir), "--episodes", "2", "--max-steps", "30", "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["task"] == "spin" and np.isfinite(report["mean_heading_rate"])
    assert report["mean_cost_of_transport"] is None or report["mean_cost_of_transport"] > 0
    baseline = tmp_path / "turn.json"
    assert eval_main(["--baseline", "turn", "--env", ENV_ID, "--episodes", "1", "--max-steps", "100",
                      "--env-kwarg", "actuator=ideal", "--env-kwarg", "wheel_friction=null",
                      "--json", str(baseline)]) == 0
    turn = json.loads(baseline.read_text())
    assert turn["algo"] == "turn" and turn["mean_heading_rate"] > 0.1  # it does turn (5.3 rad/s measured)
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_info:
        eval_main(["--baseline", "serpenoid", "--env", ENV_ID, "--episodes", "1"])
    assert exit_info.value.code == 2
    assert "use --baseline turn" in capsys.readouterr().err


def test_metrics_must_name_a_known_reduction_and_an_info_key():
    with pytest.raises(TypeError, match="reduction must be one of"):
        type("Bad", (Task,), {"step_info_keys": ("x",), "episode_metrics": {"m": ("x", "median")}})
    with pytest.raises(TypeError, match="reads info key 'y'"):
        type("Bad", (Task,), {"step_info_keys": ("x",), "episode_metrics": {"m": ("y", "mean")}})
