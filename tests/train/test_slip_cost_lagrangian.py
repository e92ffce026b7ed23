"""SlipCostLagrangian: the slip cost's weight as a Lagrange multiplier on the share of wheel-steps that
slide. The dual step follows its formula, the training envs' weight follows the measured share (up while
wheels slide more than the target, down to 0 while they slide less), the evaluation env keeps the
configured weight, the multiplier is saved with the model, and bad settings are one-line errors."""

from __future__ import annotations

import numpy as np
import pytest
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback, CallbackList

import snake_env  # noqa: F401  (registers the ids)
from snake_env.train import config as cfg
from snake_env.train.callbacks import SlipCostLagrangian

from .conftest import TINY, assert_callback_config_error

ENV = "snake_env/Snake5-v4"  # the default sliding wheels
NAME = "snake_env.train.callbacks.SlipCostLagrangian"


def test_dual_step_follows_the_formula_and_its_bounds():
    lagrangian = SlipCostLagrangian(target_share=0.05, gain=2.0, proportional=3.0, max_weight=1.0)
    lagrangian.multiplier = 0.2
    assert lagrangian.update(0.15) == pytest.approx(min(0.2 + 0.2 + 0.3, 1.0))  # 0.4 + 3 * 0.1 = 0.7
    assert lagrangian.multiplier == pytest.approx(0.4)
    assert lagrangian.update(0.55) == 1.0 and lagrangian.multiplier == 1.0  # both capped at max_weight
    assert lagrangian.update(0.0) == pytest.approx(0.9 - 0.15)  # 1 - 2 * 0.05, then - 3 * 0.05
    for _ in range(20):
        weight = lagrangian.update(0.0)
    assert lagrangian.multiplier == 0.0 and weight == 0.0  # never below 0


class _Record(BaseCallback):
    """After the Lagrangian in a CallbackList: every step's training-env and eval-env weight, and the
    wheels' slip flags of the step."""

    def __init__(self, eval_env):
        super().__init__()
        self.eval_env = eval_env
        self.weights, self.eval_weights, self.shares, self.speeds = [], [], [], []

    def _on_step(self) -> bool:
        self.weights.append(self.training_env.get_attr("slip_cost_weight")[0])
        self.eval_weights.append(self.eval_env.get_attr("slip_cost_weight")[0])
        self.shares.append(np.mean([info["wheel_slip"] for info in self.locals["infos"]]))
        self.speeds.append(np.mean([info["x_velocity"] for info in self.locals["infos"]]))
        return True


def _train(target_share, initial_weight, start_fraction=0.0, steps=512, start_speed=0.0):
    from snake_env.train.envs import make_vec_env, wrap_normalize
    from snake_env.train.train import build_model

    config = cfg.build_config("ppo", ENV, overrides=[
        "env_kwargs.slip_cost_weight=4.0", "env_kwargs.max_episode_steps=50", "n_steps=64", "batch_size=64",
        "n_epochs=1", "policy_kwargs.net_arch=[8]", "policy_kwargs.log_std_init=1.0"], n_envs=2)
    config["callback"] = [{NAME: {"target_share": target_share, "gain": 2.0, "initial_weight": initial_weight,
                                  "start_fraction": start_fraction, "start_speed": start_speed}}]
    config = cfg.validate(config)
    venv = wrap_normalize(make_vec_env(config, 2, 0), config, training=True)
    eval_env = make_vec_env(config, 1, 10_000)
    model = build_model(config, venv, 0)
    lagrangian, = cfg.make_callbacks(config)
    record = _Record(eval_env)
    model.learn(total_timesteps=steps, callback=CallbackList([lagrangian, record]))
    return model, lagrangian, record, venv


def test_weight_rises_while_wheels_slide_beyond_the_target():
    model, lagrangian, record, venv = _train(target_share=0.0, initial_weight=0.0)
    shares = np.array(record.shares).reshape(-1, 64).mean(axis=1)  # per rollout of 64 steps
    assert shares.max() > 0.0  # wide random torques make some wheels slide
    # the weight during rollout k+1 is the sum of the dual steps on the shares of rollouts 0..k
    weights = np.array(record.weights).reshape(-1, 64)
    assert np.all(weights == weights[:, :1])  # constant within a rollout
    np.testing.assert_allclose(weights[1:, 0], np.minimum(np.cumsum(2.0 * shares[:-1]), 20.0), rtol=1e-12)
    assert weights[0, 0] == 0.0 and weights[-1, 0] > 0.0
    assert lagrangian.multiplier == model.slip_cost_multiplier > 0.0
    assert all(w == 4.0 for w in record.eval_weights)  # the evaluation scores at the configured weight
    assert venv.get_attr("slip_cost_weight")[0] == 4.0  # and the training envs get it back at the end


def test_weight_falls_to_zero_while_wheels_slide_less_than_the_target(tmp_path):
    model, lagrangian, record, _ = _train(target_share=0.99, initial_weight=3.0)
    weights = np.array(record.weights).reshape(-1, 64)[:, 0]
    shares = np.array(record.shares).reshape(-1, 64).mean(axis=1)
    expected = [3.0]
    for share in shares[:-1]:
        expected.append(max(expected[-1] + 2.0 * (share - 0.99), 0.0))
    np.testing.assert_allclose(weights, expected, rtol=1e-12, atol=1e-15)
    assert np.all(np.diff(weights[weights > 0.0]) < 0.0) and weights[-1] < 3.0  # down after every rollout
    assert lagrangian.update(0.0) == 0.0  # and held at 0
    # the multiplier is saved with the model: a resumed run goes on from it
    model.save(tmp_path / "model.zip")
    assert PPO.load(tmp_path / "model.zip").slip_cost_multiplier == lagrangian.multiplier


@pytest.mark.parametrize("kwargs, pattern", [
    ({"target_share": 1.0}, r"target_share must be a number in \[0, 1\)"),
    ({"gain": 0}, "gain must be a number > 0"),
    ({"start_fraction": 1.0}, r"start_fraction must be a number in \[0, 1\)"),
    ({"proportional": -1.0}, "proportional must be a number >= 0"),
    ({"max_weight": float("inf")}, "max_weight must be a number > 0"),
    ({"start_speed": -0.1}, "start_speed must be a number >= 0"),
    ({"initial_weight": 30.0}, r"initial_weight must be <= max_weight \(20.0\)"),
    ({"update_every": 0}, "update_every must be an integer >= 1"),
    ({"price": 1.0}, "unexpected keyword"),
])
def test_bad_arguments_are_one_line_config_errors(kwargs, pattern):
    assert_callback_config_error(ENV, [{NAME: kwargs}], pattern, ["env_kwargs.slip_cost_weight=1.0"])


def test_needs_a_configured_weight_and_excludes_the_schedule(tmp_path):
    entry = tmp_path / "ppo.yaml"
    entry.write_text(f"{ENV}:\n  n_envs: 2\n")
    assert_callback_config_error(ENV, [NAME], "SlipCostLagrangian needs env_kwargs slip_cost_weight > 0",
                                 config_path=entry)
    assert_callback_config_error(ENV, [NAME, "snake_env.train.callbacks.SlipCostSchedule"], "give one of them",
                                 ["env_kwargs.slip_cost_weight=1.0"], config_path=entry)


def test_snake_train_end_to_end_logs_the_share_and_the_weight(tmp_path):
    import csv

    from snake_env.train.train import main

    run_dir = tmp_path / "run"
    assert main(["--algo", "ppo", "--env", ENV, "--total-timesteps", "256", "--run-dir", str(run_dir),
                 *TINY["ppo"], "--set", "env_kwargs.slip_cost_weight=2.0",
                 "--set", "callback=[{" + NAME + ": {target_share: 0.0}}]"]) == 0
    rows = []
    for path in sorted((run_dir / "logs").glob("segment_*/progress.csv")):
        with path.open() as f:
            rows += [row for row in csv.DictReader(f) if row.get("train/slip_share")]
    assert rows and all(0.0 <= float(row["train/slip_share"]) <= 1.0 for row in rows)
    assert all(float(row["train/slip_cost_weight"]) >= 0.0 for row in rows)


def test_dual_steps_wait_for_start_fraction():
    _, _, record, _ = _train(target_share=0.0, initial_weight=0.0, start_fraction=0.5, steps=1024)
    weights = np.array(record.weights).reshape(-1, 64)[:, 0]  # 8 rollouts of 128 steps
    shares = np.array(record.shares).reshape(-1, 64).mean(axis=1)
    # the updates after rollouts 0-2 (progress 1/8..3/8) are skipped; from rollout 3's end (4/8) on they count
    assert np.all(weights[:4] == 0.0)
    np.testing.assert_allclose(weights[4:], np.cumsum(2.0 * shares[3:-1]), rtol=1e-12)
    assert weights[-1] > 0.0


def test_dual_steps_wait_for_the_policy_to_move():
    # never fast enough: the weight stays at its initial value past start_fraction; the rollout speeds recorded
    model, lagrangian, record, _ = _train(target_share=0.0, initial_weight=0.0, start_fraction=0.5,
                                          start_speed=50.0, steps=1024)
    assert np.all(np.array(record.weights) == 0.0) and not lagrangian.started and not model.slip_cost_started
    speeds = np.array(record.speeds).reshape(-1, 64).mean(axis=1)  # per rollout of 64 steps (both envs)
    # the updates after rollouts 3.. are past start_fraction; a threshold at the fastest of rollouts 3-6
    # opens the gate at that rollout's update and not before (rollouts 0-2 may be faster: too early)
    first = 3 + int(np.argmax(speeds[3:-1]))
    threshold = speeds[first] - 1e-9  # below it by more than the rounding of a sum taken in another order
    assert threshold > 0.0 and np.all(speeds[3:first] < threshold)
    # the same run (the weight is 0 until the gate opens) with the threshold at that rollout's speed
    model, lagrangian, record, _ = _train(target_share=0.0, initial_weight=0.0, start_fraction=0.5,
                                          start_speed=float(threshold), steps=1024)
    weights = np.array(record.weights).reshape(-1, 64)[:, 0]
    # identical until the first dual step (the weight prices only the reward, and the policy changes after it)
    np.testing.assert_array_equal(np.array(record.speeds).reshape(-1, 64).mean(axis=1)[:first + 2],
                                  speeds[:first + 2])
    shares = np.array(record.shares).reshape(-1, 64).mean(axis=1)
    assert np.all(weights[:first + 1] == 0.0)
    np.testing.assert_allclose(weights[first + 1:], np.cumsum(2.0 * shares[first:-1]), rtol=1e-12)
    assert weights[-1] > 0.0 and lagrangian.started and model.slip_cost_started


def test_off_policy_updates_every_update_every_env_steps():
    from snake_env.train.envs import make_vec_env
    from snake_env.train.train import build_model

    config = cfg.build_config("sac", ENV, overrides=[
        "env_kwargs.slip_cost_weight=4.0", "env_kwargs.max_episode_steps=50", "learning_starts=64",
        "buffer_size=2000", "batch_size=32", "policy_kwargs.net_arch=[8]"], n_envs=2)
    config["callback"] = [{NAME: {"target_share": 0.0, "gain": 2.0, "start_fraction": 0.0, "update_every": 40}}]
    config = cfg.validate(config)
    venv = make_vec_env(config, 2, 0)
    model = build_model(config, venv, 0)
    lagrangian, = cfg.make_callbacks(config)
    record = _Record(make_vec_env(config, 1, 10_000))
    model.learn(total_timesteps=200, callback=CallbackList([lagrangian, record]))
    weights = np.array(record.weights)  # 100 vector steps of 2 envs: an update after every 20th
    shares = np.array(record.shares)
    block_shares = shares.reshape(5, 20).mean(axis=1)
    for i, weight in enumerate(weights):  # the record sees the update made at its own step
        done = (i + 1) // 20
        assert weight == pytest.approx(min(2.0 * block_shares[:done].sum(), 20.0), rel=1e-12, abs=1e-15)
    assert weights[-1] > 0.0
