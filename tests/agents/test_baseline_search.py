"""Per-n settings of the task baselines: configs/baselines.yaml, the turning-gain measurement, the reach search."""

import math

import gymnasium as gym
import pytest
import yaml

import snake_env  # noqa: F401
from snake_env.agents import baseline_search
from snake_env.agents.baseline_search import main, measure_turn_gain, success_rate
from snake_env.controllers.gaits import gait_for_links
from snake_env.controllers.steering import (GoalSeekingController, LineOfSightController, baseline_settings,
                                            make_baseline)
from snake_env.physics import PhysicsConfig
from snake_env.tasks import TASKS, Task
from snake_env.wrappers import SerpenoidResidualAction


def _write(tmp_path, data):
    path = tmp_path / "baselines.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_shipped_settings_exist_for_the_long_reach_snakes_and_snake5_keeps_the_defaults():
    for n in (8, 12):
        settings = baseline_settings("reach", GoalSeekingController, n)
        assert set(settings) == {"gain", "max_offset", "hysteresis", "turn_gain"}
        assert all(math.isfinite(v) and v > 0 for v in settings.values())
    assert baseline_settings("reach", GoalSeekingController, 5) == {}
    assert baseline_settings("path", LineOfSightController, 12) == {}


def test_make_baseline_applies_the_settings_of_its_n(tmp_path):
    path = _write(tmp_path, {"reach": {8: {"settings": {"gain": 0.2, "max_offset": 0.25, "turn_gain": 4.0}}},
                             "path": {8: {"settings": {"lookahead": 2.0}}}})
    params, speed = gait_for_links(8)
    reach = make_baseline(GoalSeekingController, "reach", params, speed, 8, 1.0, 0.04, settings_path=path)
    assert isinstance(reach, GoalSeekingController)
    assert (reach.gain, reach.max_offset, reach.turn_gain) == (0.2, 0.25, 4.0)
    assert reach.turn_radius == pytest.approx(speed / (4.0 * 0.25))
    los = make_baseline(LineOfSightController, "path", params, speed, 8, 1.0, 0.04, settings_path=path)
    assert isinstance(los, LineOfSightController) and los.lookahead == 2.0
    default = make_baseline(GoalSeekingController, "reach", params, speed, 12, 1.0, 0.04,
                            settings_path=path)  # no n = 12 entry
    assert (default.gain, default.max_offset, default.turn_gain) == (0.5, 0.3, 9.0)
    # the task class builds the same controller from its own facts (its class, name and the gait of its n)
    from_task = TASKS["reach"].make_baseline(PhysicsConfig(n_links=8), num_envs=3, settings=path)
    assert type(from_task) is GoalSeekingController and from_task.num_envs == 3
    assert (from_task.gain, from_task.max_offset, from_task.turn_gain) == (0.2, 0.25, 4.0)


@pytest.mark.parametrize("data, match", [
    ({"reach": {8: {"settings": {"gian": 0.2}}}}, "unknown setting 'gian'"),
    ({"reach": {8: {"settings": {"gain": "high"}}}}, "'gain' must be a number"),
    ({"reach": {8: {"gain": 0.2}}}, "needs a mapping 'settings'"),
    ({"reach": [1, 2]}, "must map a task name"),
])
def test_bad_settings_files_are_one_line_errors(tmp_path, data, match):
    with pytest.raises(ValueError, match=match):
        baseline_settings("reach", GoalSeekingController, 8, _write(tmp_path, data))


def test_a_setting_of_another_controller_is_rejected(tmp_path):
    with pytest.raises(ValueError, match="unknown setting 'hysteresis'"):
        baseline_settings("path", LineOfSightController, 8, _write(tmp_path, {"path": {8: {"settings": {"hysteresis": 2}}}}))


def test_a_task_without_a_baseline_says_so():
    with pytest.raises(ValueError, match="task has no baseline controller"):
        Task.make_baseline(PhysicsConfig(n_links=5))


def test_the_residual_wrapper_steers_with_the_settings_of_its_n():
    residual = SerpenoidResidualAction(gym.make("snake_env/SnakeReach12-v1"))
    settings = baseline_settings("reach", GoalSeekingController, 12)
    controller = residual.controller
    assert {name: getattr(controller, name) for name in settings} == settings


def test_turning_gain_is_positive_and_the_yaw_rate_proportional_to_the_offset():
    gain, rates = measure_turn_gain("snake_env/SnakeReach5-v1", offsets=(0.05, 0.1, 0.2), starts=2, steps=200,
                                    settle=50)
    assert gain > 0
    assert all(rate > 0 for rate in rates.values())  # a positive offset turns left
    for gamma, rate in rates.items():
        assert rate == pytest.approx(gain * gamma, rel=0.15)


def test_batched_success_rate_equals_the_single_env_episode():
    """One sub-env of the vector env reproduces gym.make(id) under the same seed, so success_rate with one
    episode equals goal seeking rolled out in the single env."""
    params, speed = gait_for_links(5, versions_back=2)  # SnakeReach5-v1: the ideal physics' gait (two versions back)
    for seed in (0, 1, 3):
        rate, steps = success_rate("snake_env/SnakeReach5-v1", {"gain": 0.3}, 1, seed)
        env = gym.make("snake_env/SnakeReach5-v1")
        obs, _ = env.reset(seed=seed)
        controller = GoalSeekingController(params, 5, 1.0, 0.04, gait_speed=float(speed), gain=0.3)
        for step in range(1, 401):
            obs, _, terminated, truncated, info = env.step(controller.act(obs))
            if terminated or truncated:
                break
        assert rate == float(info["is_success"])
        if rate:
            assert steps == step


def test_search_writes_an_entry_that_baseline_settings_reads(tmp_path, monkeypatch):
    monkeypatch.setattr(baseline_search, "GAINS", (0.17, 0.5))
    monkeypatch.setattr(baseline_search, "MAX_OFFSETS", (0.2,))
    monkeypatch.setattr(baseline_search, "HYSTERESES", (1.5,))
    output = tmp_path / "baselines.yaml"
    assert main(["--env", "snake_env/SnakeReach8-v1", "--episodes", "16", "--validate-episodes", "16",
                 "--top", "2", "--output", str(output)]) == 0
    settings = baseline_settings("reach", GoalSeekingController, 8, output)
    assert settings["gain"] in (0.17, 0.5) and settings["max_offset"] == 0.2 and settings["turn_gain"] > 0
    entry = yaml.safe_load(output.read_text())["reach"][8]
    assert entry["search"]["settings_evaluated"] == 2 and 0.0 <= entry["search"]["validation_success_rate"] <= 1.0


@pytest.mark.parametrize("argv, message", [
    (["--env", "snake_env/Snake5-v2"], "reach task id"),
    (["--env", "snake_env/NoSuch-v0"], "unknown env id"),
    (["--env", "snake_env/SnakeReach8-v1", "--episodes", "0"], "--episodes must be >= 1"),
])
def test_cli_rejects_bad_input_with_exit_code_2(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv + ["--dry-run"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
