"""Tiny training budgets shared by the CLI tests (seconds, not minutes)."""

from __future__ import annotations

import pytest

ENV = "snake_env/Snake3-v2"
# 50-step episodes, 2 envs, frequent checkpoints/evaluations, 8-unit networks
COMMON = ["--n-envs", "2", "--set", "env_kwargs.max_episode_steps=50", "--set", "eval_freq=128",
          "--set", "checkpoint_freq=128", "--set", "n_eval_episodes=1", "--set", "policy_kwargs.net_arch=[8]",
          "--no-progress-bar"]
TINY = {
    "ppo": COMMON + ["--set", "n_steps=32", "--set", "batch_size=32", "--set", "n_epochs=1"],
    "sac": COMMON + ["--set", "learning_starts=64", "--set", "buffer_size=2000", "--set", "batch_size=32"],
}


def train_args(algo: str, run_dir, steps: int, *extra) -> list[str]:
    return ["--algo", algo, "--env", ENV, "--total-timesteps", str(steps), "--run-dir", str(run_dir),
            *TINY[algo], *extra]


@pytest.fixture(scope="session")
def ppo_run(tmp_path_factory):
    """A finished tiny PPO run directory (normalized observations and rewards)."""
    from snake_env.train.train import main

    run_dir = tmp_path_factory.mktemp("runs") / "ppo_run"
    assert main(train_args("ppo", run_dir, 256)) == 0
    return run_dir


def assert_callback_config_error(env_id: str, callback, pattern: str, overrides=(), config_path=None) -> None:
    """``callback`` (the config's ``callback`` entry) on a PPO config of ``env_id`` is refused by
    ``validate`` with a one-line ConfigError matching ``pattern``."""
    from snake_env.train import config as cfg

    config = cfg.build_config("ppo", env_id, config_path=config_path, overrides=list(overrides))
    config["callback"] = callback
    with pytest.raises(cfg.ConfigError, match=pattern) as info:
        cfg.validate(config)
    assert "\n" not in str(info.value)

