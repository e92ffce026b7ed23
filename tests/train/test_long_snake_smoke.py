"""CI smoke test: PPO and SAC train a few thousand steps on a long snake (Snake12)
with the shipped configs, opt-in wrappers included, and the result evaluates; the
shared-policy PPO entry of Snake20 and 30 trains and runs on both lengths
(no timing or learning asserts: learning is measured in docs/results.md)."""

from __future__ import annotations

import math

import pytest
import yaml

from tests.test_configs import newest_locomotion_ids
from snake_env.train.config import build_config
from snake_env.train.evaluate import main as evaluate_main
from snake_env.train.train import main as train_main


def long_snake_id() -> str:
    return next(env_id for env_id in newest_locomotion_ids() if env_id.startswith("snake_env/Snake12-"))


@pytest.mark.parametrize("algo, steps", [("ppo", None), ("sac", 3000)])
def test_shipped_config_trains_and_evaluates_on_snake12(algo, steps, tmp_path):
    env_id = long_snake_id()
    shipped = build_config(algo, env_id)
    if steps is None:  # one PPO rollout of the shipped size (n_envs x n_steps)
        steps = shipped["n_envs"] * shipped["n_steps"]
    run_dir = tmp_path / algo
    assert train_main(["--algo", algo, "--env", env_id, "--total-timesteps", str(steps), "--run-dir", str(run_dir),
                       "--no-progress-bar"]) == 0
    saved = yaml.safe_load((run_dir / "config.yaml").read_text())
    assert saved["env_wrapper"] == shipped["env_wrapper"]
    report_path = tmp_path / f"{algo}.json"
    assert evaluate_main([str(run_dir), "--episodes", "1", "--max-steps", "50", "--json", str(report_path)]) == 0
    report = yaml.safe_load(report_path.read_text())
    assert math.isfinite(report["mean_forward_velocity"]) and report["episodes"][0]["length"] == 50


def test_shipped_snake30_ppo_entry_is_the_shared_policy_and_runs_another_length(tmp_path):
    """Snake30's PPO entry is JointPolicy and Snake20's is the same entry: it trains from the shipped config
    (one small rollout) and the same run evaluates on Snake30 and on Snake20, which it never saw."""
    env_id = next(env_id for env_id in newest_locomotion_ids() if env_id.startswith("snake_env/Snake30-"))
    shipped = build_config("ppo", env_id)
    assert shipped["policy"] == "JointPolicy"
    snake20_id = env_id.replace("Snake30", "Snake20")
    assert {**build_config("ppo", snake20_id), "env_id": env_id} == shipped
    run_dir = tmp_path / "run"
    assert train_main(["--algo", "ppo", "--env", env_id, "--total-timesteps", "256", "--run-dir", str(run_dir),
                       "--set", "n_envs=4", "--set", "n_steps=64", "--set", "batch_size=64",
                       "--no-progress-bar"]) == 0
    for other in (env_id, snake20_id):
        report_path = tmp_path / f"{other.split('/')[1]}.json"
        assert evaluate_main([str(run_dir), "--env", other, "--episodes", "1", "--max-steps", "20",
                              "--json", str(report_path)]) == 0
        report = yaml.safe_load(report_path.read_text())
        assert math.isfinite(report["mean_forward_velocity"]) and report["episodes"][0]["length"] == 20
