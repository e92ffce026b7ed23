"""snake-train / snake-eval on the task ids: SAC + HerReplayBuffer on the GoalEnv,
MultiInputPolicy for Dict observations, task metrics and cost of transport in the JSON."""

from __future__ import annotations

import json
import math
import zipfile

import numpy as np
import pytest
import yaml

from snake_env.tasks import TASKS
from snake_env.train.evaluate import main as eval_main
from snake_env.train.task_metrics import EpisodeRecorder, summarize_task
from snake_env.train.train import main as train_main

TINY = ["--n-envs", "2", "--set", "env_kwargs.max_episode_steps=50", "--set", "eval_freq=200",
        "--set", "checkpoint_freq=200", "--set", "n_eval_episodes=1", "--set", "policy_kwargs.net_arch=[8]",
        "--no-progress-bar"]


@pytest.mark.parametrize("wrapper", [[], ["--set", "env_wrapper=null"],
                                     ["--set", "policy_kwargs=dict(net_arch=[8], features_extractor_class='goal_frame')"]],
                         ids=["shipped_steering_on_the_gait", "plain_joint_torques", "goal_frame_extractor"])
def test_sac_with_her_smoke_trains_on_reach_and_evaluates(tmp_path, capsys, wrapper):
    run_dir = tmp_path / "her"
    # HER samples only after a finished episode: 2 envs x 50 steps < learning_starts
    assert train_main(["--algo", "sac", "--env", "snake_env/SnakeReach5-v1", "--total-timesteps", "300",
                       "--run-dir", str(run_dir), "--set", "learning_starts=120", "--set", "buffer_size=2000",
                       "--set", "batch_size=32", *TINY, *wrapper]) == 0
    config = yaml.safe_load((run_dir / "config.yaml").read_text())
    assert config["replay_buffer_class"] == "HerReplayBuffer"
    with zipfile.ZipFile(run_dir / "model.zip") as archive:
        data = json.loads(archive.read("data").decode())
    assert "HerReplayBuffer" in json.dumps(data["replay_buffer_class"])
    assert "MultiInputPolicy" in json.dumps(data["policy_class"])
    assert data["num_timesteps"] >= 300
    out = tmp_path / "eval.json"
    assert eval_main([str(run_dir), "--episodes", "2", "--max-steps", "60", "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["task"] == "reach" and 0.0 <= report["success_rate"] <= 1.0
    assert report["mean_cost_of_transport"] > 0 and report["mean_final_goal_distance"] > 0
    assert "success_rate" in capsys.readouterr().out


def test_ppo_picks_multi_input_policy_for_the_dict_observation(tmp_path):
    run_dir = tmp_path / "ppo_reach"
    assert train_main(["--algo", "ppo", "--env", "snake_env/SnakeReach5-v1", "--total-timesteps", "128",
                       "--run-dir", str(run_dir), "--set", "policy=MlpPolicy", "--set", "n_steps=32",
                       "--set", "batch_size=32", "--set", "n_epochs=1", *TINY]) == 0
    from stable_baselines3 import PPO
    from stable_baselines3.common.policies import MultiInputActorCriticPolicy

    assert isinstance(PPO.load(run_dir / "model.zip", device="cpu").policy, MultiInputActorCriticPolicy)
    assert (run_dir / "vecnormalize.pkl").is_file()  # Dict observations are normalized per key
    assert eval_main([str(run_dir), "--episodes", "1", "--max-steps", "20"]) == 0


@pytest.mark.parametrize("env_id, baseline, keys", [
    ("snake_env/SnakePath5-v2", "los", ("mean_cross_track_error", "mean_path_speed")),
    ("snake_env/SnakeCommand5-v1", "steering", ("mean_speed_error", "mean_yaw_rate_error")),
    ("snake_env/Snake5-v2", "serpenoid", ()),
    ("snake_env/SnakeReach5-v1", "homing", ("success_rate", "mean_final_goal_distance")),
])
def test_baselines_report_task_metrics_and_cost_of_transport(tmp_path, env_id, baseline, keys):
    out = tmp_path / "baseline.json"
    assert eval_main(["--baseline", baseline, "--env", env_id, "--episodes", "1", "--max-steps", "150",
                      "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    cot = report["episodes"][0]["cost_of_transport"]
    # the serpenoid gaits move at ~1-2 m/s with ~1 N m torques on a 5 kg snake: CoT of order 0.1
    assert 0.01 < cot < 1.0 and report["mean_cost_of_transport"] == pytest.approx(cot)
    for key in keys:
        assert math.isfinite(report[key])


def test_baseline_on_the_wrong_task_is_a_one_line_error(capsys):
    with pytest.raises(SystemExit) as exit_info:
        eval_main(["--baseline", "los", "--env", "snake_env/SnakeCommand5-v1"])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "--baseline los drives the path task" in err and "steering" in err and "\n" not in err


def test_cost_of_transport_is_actuator_energy_over_weight_times_distance():
    recorder = EpisodeRecorder(TASKS["path"].episode_metrics, dt=0.5, weight=10.0, reset_info={"x_position": 0.0, "y_position": 0.0})
    for x, power, error in ((3.0, 4.0, 0.5), (3.0, 2.0, -0.1), (3.0, 0.0, 0.3)):
        recorder.add({"x_position": x, "y_position": 4.0 if power == 4.0 else 0.0, "actuator_power": power,
                      "cross_track_error": error, "path_speed": 1.0})
    # path (0,0) -> (3,4) -> (3,0) -> (3,0): 5 + 4 m; energy (4 + 2) W x 0.5 s = 3 J
    metrics = recorder.metrics()
    assert metrics["path_length"] == pytest.approx(9.0)
    assert metrics["actuator_energy"] == pytest.approx(3.0)
    assert metrics["cost_of_transport"] == pytest.approx(3.0 / (10.0 * 9.0))
    assert metrics["mean_cross_track_error"] == pytest.approx(0.3)
    summary = summarize_task(TASKS["path"].episode_metrics, [metrics, {**metrics, "cost_of_transport": math.nan}])
    assert summary["mean_cost_of_transport"] == pytest.approx(3.0 / 90.0)  # nan episodes left out


def test_actuator_power_of_ideal_sources_is_the_commanded_work_over_the_joint_angle_changes():
    """On the previous physics (ideal sources, no traction limit) the delivered torque is the held
    command T_k, so the motors' energy of a step, the integral of |T_k phidot_k|, is at least
    |T_k dphi_k| (equal while a joint keeps turning one way; above it where a joint reverses in the step)."""
    import gymnasium as gym

    env = gym.make("snake_env/SnakeCommand5-v1")
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    above = []
    for _ in range(10):
        q0, _ = env.unwrapped.state
        a = rng.uniform(-1, 1, 4)
        *_, info = env.step(a)
        q1, _ = env.unwrapped.state
        dphi = np.diff(q1[:5]) - np.diff(q0[:5])
        commanded = np.sum(np.abs(a * env.unwrapped.max_torque * dphi)) / 0.04
        assert info["actuator_power"] >= commanded * (1.0 - 1e-9)
        above.append(info["actuator_power"] / commanded)
    assert max(above) > 1.01  # some joint reversed within a step under these random commands