"""SlipCostSchedule: a curriculum on the slip cost's weight. The env's weight can change after
construction (``set_slip_cost_weight``), the training envs follow the schedule step by step, the reward's
slip term scales with it, the evaluation env keeps the configured weight, and bad settings are one-line
errors."""

from __future__ import annotations

import csv

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.callbacks import BaseCallback

import snake_env  # noqa: F401  (registers the ids)
from snake_env.train import config as cfg
from snake_env.train.callbacks import SlipCostSchedule

from .conftest import TINY, assert_callback_config_error

ENV = "snake_env/Snake3-v3"  # wheels with finite grip
NAME = "snake_env.train.callbacks.SlipCostSchedule"


def _rollout(weight_after_reset=None, steps=100, seed=1):
    """(reward, reward_slip) of every step of a 2-env Snake12-v3 vector env at weight 2 (changed to
    ``weight_after_reset`` after the reset when given), under the same seeded random torques (with
    these, a few steps push wheels beyond their grip; shorter snakes hardly ever slip at random)."""
    env = gym.make_vec("snake_env/Snake12-v3", num_envs=2, vectorization_mode="vector_entry_point",
                       slip_cost_weight=2.0)
    env.reset(seed=seed)
    if weight_after_reset is not None:
        env.unwrapped.set_slip_cost_weight(weight_after_reset)
    rng = np.random.default_rng(seed)
    rewards, slips = [], []
    for _ in range(steps):
        _, reward, _, _, info = env.step(rng.uniform(-1.0, 1.0, size=env.action_space.shape))
        rewards.append(reward)
        slips.append(info["reward_slip"])
    env.close()
    return np.array(rewards), np.array(slips)


def test_set_weight_scales_the_slip_term_of_the_reward():
    rewards, slips = _rollout()
    assert slips.sum() < -1.0  # some wheels went beyond their grip
    for weight in (0.5, 0.0, 6.0):
        rewards_w, slips_w = _rollout(weight)
        np.testing.assert_allclose(slips_w, slips * weight / 2.0, rtol=1e-12, atol=1e-15)
        # the rest of the reward (the forward speed) is unchanged: the cost does not act on the motion
        np.testing.assert_allclose(rewards_w - slips_w, rewards - slips, rtol=1e-12, atol=1e-12)


def test_set_weight_updates_the_attributes_and_keeps_the_info_key():
    env = gym.make(ENV, slip_cost_weight=1.0, max_episode_steps=5)
    env.reset(seed=0)
    env.unwrapped.set_slip_cost_weight(0.0)
    assert env.unwrapped.slip_cost_weight == 0.0 and env.unwrapped.task.slip_cost_weight == 0.0
    _, _, _, _, info = env.step(env.action_space.sample())
    assert info["reward_slip"] == 0.0  # still reported (0) at weight 0
    env.unwrapped.set_slip_cost_weight(3)
    assert env.unwrapped.task.slip_cost_weight == 3.0


@pytest.mark.parametrize("kwargs, weight, pattern", [
    ({"slip_cost_weight": 1.0}, -1.0, "slip_cost_weight must be a finite number >= 0"),
    ({"slip_cost_weight": 1.0}, float("nan"), "slip_cost_weight must be a finite number >= 0"),
    ({"slip_cost_weight": 1.0}, "1", "slip_cost_weight must be a finite number >= 0"),
    ({}, 1.0, "needs an env made with slip_cost_weight > 0"),
])
def test_set_weight_refuses_bad_values_in_one_line(kwargs, weight, pattern):
    env = gym.make(ENV, **kwargs)
    with pytest.raises(ValueError, match=pattern) as info:
        env.unwrapped.set_slip_cost_weight(weight)
    assert "\n" not in str(info.value)


def test_weight_at_follows_the_ramp():
    schedule = SlipCostSchedule(start_fraction=0.25, end_fraction=0.75, floor=0.1)
    schedule.final_weight = 2.0
    expected = {0.0: 0.2, 0.25: 0.2, 0.5: 0.2 + 1.8 * 0.5, 0.75: 2.0, 1.0: 2.0}
    for progress, weight in expected.items():
        assert schedule.weight_at(progress) == pytest.approx(weight, rel=1e-12)


class _Record(BaseCallback):
    """After SlipCostSchedule in a CallbackList: (num_timesteps, training envs' weight, eval-env weight)."""

    def __init__(self, eval_env):
        super().__init__()
        self.eval_env = eval_env
        self.rows = []

    def _on_step(self) -> bool:
        self.rows.append((self.model.num_timesteps, self.training_env.get_attr("slip_cost_weight")[0],
                          self.eval_env.get_attr("slip_cost_weight")[0]))
        return True


SMALL = {"ppo": ["n_steps=32", "batch_size=32", "n_epochs=1", "policy_kwargs.net_arch=[8]"],
         "sac": ["learning_starts=32", "buffer_size=1000", "batch_size=16", "policy_kwargs.net_arch=[8]"]}


@pytest.mark.parametrize("algo", ["ppo", "sac"])  # on-policy: a rollout's steps; off-policy: every step
def test_training_envs_follow_the_schedule_and_the_eval_env_keeps_the_final_weight(algo):
    from stable_baselines3.common.callbacks import CallbackList

    from snake_env.train.envs import make_vec_env, wrap_normalize
    from snake_env.train.train import build_model

    config = cfg.build_config(algo, ENV, overrides=[
        "env_kwargs.slip_cost_weight=4.0", "env_kwargs.max_episode_steps=50", *SMALL[algo]], n_envs=2)
    config["callback"] = [{NAME: {"start_fraction": 0.25, "end_fraction": 0.75}}]
    config = cfg.validate(config)
    venv = wrap_normalize(make_vec_env(config, 2, 0), config, training=True)
    eval_env = make_vec_env(config, 1, 10_000)
    model = build_model(config, venv, 0)
    schedule, = cfg.make_callbacks(config)
    record = _Record(eval_env)
    model.learn(total_timesteps=256, callback=CallbackList([schedule, record]))
    steps = np.array([row[0] for row in record.rows])
    weights = np.array([row[1] for row in record.rows])
    expected = 4.0 * np.clip((steps / 256 - 0.25) / 0.5, 0.0, 1.0)
    np.testing.assert_allclose(weights, expected, rtol=1e-12, atol=1e-12)
    assert weights[0] == 0.0 and 0.0 < weights[len(weights) // 2] < 4.0 and weights[-1] == 4.0
    assert all(row[2] == 4.0 for row in record.rows)  # evaluation: the configured weight throughout
    assert venv.get_attr("slip_cost_weight")[0] == 4.0  # restored at the end of training
    # a second learn() continuing the run: past end_fraction, the configured weight
    model.learn(total_timesteps=64, callback=CallbackList([schedule, record]), reset_num_timesteps=False)
    assert record.rows[-1][1] == 4.0


@pytest.mark.parametrize("kwargs, pattern", [
    ({"start_fraction": -0.1}, r"start_fraction must be a number in \[0, 1\]"),
    ({"end_fraction": 1.5}, r"end_fraction must be a number in \[0, 1\]"),
    ({"floor": True}, r"floor must be a number in \[0, 1\]"),
    ({"start_fraction": 0.8, "end_fraction": 0.5}, r"start_fraction must be below end_fraction"),
    ({"ramp": 0.5}, "unexpected keyword"),
])
def test_bad_schedule_arguments_are_one_line_config_errors(kwargs, pattern):
    assert_callback_config_error(ENV, [{NAME: kwargs}], pattern, ["env_kwargs.slip_cost_weight=1.0"])


@pytest.mark.parametrize("override", [[], ["env_kwargs.slip_cost_weight=0"]])
def test_schedule_needs_a_configured_weight(override, tmp_path):
    entry = tmp_path / "ppo.yaml"  # an entry without the cost, whatever the shipped entries hold
    entry.write_text(f"{ENV}:\n  n_envs: 2\n")
    assert_callback_config_error(ENV, [NAME], "SlipCostSchedule needs env_kwargs slip_cost_weight > 0", override,
                                 config_path=entry)


def test_snake_train_end_to_end_logs_the_ramp(tmp_path):
    from snake_env.train.train import main

    run_dir = tmp_path / "run"
    callback = "callback=[{" + NAME + ": {start_fraction: 0.25, end_fraction: 0.75}}]"
    assert main(["--algo", "ppo", "--env", ENV, "--total-timesteps", "512", "--run-dir", str(run_dir),
                 *TINY["ppo"], "--set", "env_kwargs.slip_cost_weight=2.0", "--set", callback]) == 0
    assert (run_dir / "model.zip").is_file()
    assert cfg.load_run_config(run_dir / "config.yaml")["callback"] == [
        {NAME: {"start_fraction": 0.25, "end_fraction": 0.75}}]
    rows = []
    for path in sorted((run_dir / "logs").glob("segment_*/progress.csv")):
        with path.open() as f:
            rows += [row for row in csv.DictReader(f) if row.get("train/slip_cost_weight")]
    logged = {int(row["time/total_timesteps"]): float(row["train/slip_cost_weight"]) for row in rows}
    # PPO logs once per rollout (2 envs x 32 steps): the weight at each rollout's last step
    for steps, weight in logged.items():
        assert weight == pytest.approx(2.0 * min(max((steps / 512 - 0.25) / 0.5, 0.0), 1.0))
    assert min(logged.values()) == 0.0 and max(logged.values()) == 2.0
