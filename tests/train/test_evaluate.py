"""snake-eval: reproducible, uses (never updates) the training normalization,
agrees with SB3's own VecNormalize evaluation path, clean errors for bad files."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from snake_env.train.evaluate import main
from tests.newest_ids import newest_id
from tests.train.conftest import ENV as RUN_ENV

REPO = Path(__file__).resolve().parents[2]
ENV = newest_id("Snake3")


def evaluate_json(tmp_path, *argv) -> dict:
    path = tmp_path / f"eval_{len(list(tmp_path.glob('eval_*.json')))}.json"
    assert main([*map(str, argv), "--json", str(path)]) == 0
    return json.loads(path.read_text())


def test_metrics_and_reproducibility(ppo_run, tmp_path):
    first = evaluate_json(tmp_path, ppo_run, "--episodes", "2", "--seed", "3")
    again = evaluate_json(tmp_path, ppo_run, "--episodes", "2", "--seed", "3")
    other = evaluate_json(tmp_path, ppo_run, "--episodes", "2", "--seed", "4")
    for key in ("mean_return", "std_return", "mean_forward_velocity", "mean_distance", "episodes"):
        assert key in first
    assert first["episodes"] == again["episodes"]
    assert first["episodes"] != other["episodes"]
    assert [e["length"] for e in first["episodes"]] == [50, 50]  # env_kwargs come from config.yaml
    returns = [e["return"] for e in first["episodes"]]
    assert first["mean_return"] == pytest.approx(np.mean(returns))
    assert first["std_return"] == pytest.approx(np.std(returns))
    stochastic = [evaluate_json(tmp_path, ppo_run, "--episodes", "1", "--seed", "5", "--stochastic")
                  for _ in range(2)]
    assert stochastic[0]["episodes"] == stochastic[1]["episodes"]


def test_matches_sb3_vecnormalize_evaluation_and_does_not_update_statistics(ppo_run, tmp_path):
    """Cross-check against SB3's documented path: VecNormalize.load(...),
    training=False, norm_reward=False; the statistics file is left untouched."""
    import gymnasium as gym
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    stats_file = ppo_run / "vecnormalize.pkl"
    stats_before = stats_file.read_bytes()
    ours = evaluate_json(tmp_path, ppo_run, "--episodes", "1", "--seed", "11")
    assert stats_file.read_bytes() == stats_before

    # the env the run was trained on (tests/train/conftest.py), which snake-eval reads from its config.yaml
    venv = VecNormalize.load(str(stats_file), DummyVecEnv([lambda: gym.make(RUN_ENV, max_episode_steps=50)]))
    venv.training = False
    venv.norm_reward = False
    mean_before = venv.obs_rms.mean.copy()
    model = PPO.load(ppo_run / "model.zip", device="cpu")
    venv.seed(11)
    obs = venv.reset()
    total, done = 0.0, False
    while not done:
        action, _ = model.predict(obs, deterministic=True)
        obs, reward, done, _ = venv.step(action)
        total += float(reward[0])
    assert ours["episodes"][0]["return"] == pytest.approx(total, rel=1e-6, abs=1e-9)
    np.testing.assert_array_equal(venv.obs_rms.mean, mean_before)
    # and the statistics matter: without them the same policy acts differently
    from snake_env.agents.policy_loading import load_policy

    env = gym.make(ENV)
    loaded = load_policy(ppo_run, env.observation_space, env.action_space, {"algo": "ppo"})
    raw, _ = env.reset(seed=0)
    assert not np.allclose(loaded.normalize(raw), raw)
    env.close()


def test_plot_and_gif_are_written_headless(ppo_run, tmp_path):
    plot, video = tmp_path / "cm.png", tmp_path / "snake.gif"
    assert main([str(ppo_run), "--episodes", "2", "--max-steps", "6", "--plot", str(plot), "--video", str(video)]) == 0
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert video.read_bytes()[:6] in (b"GIF89a", b"GIF87a")


def test_serpenoid_baseline_matches_the_search_score(tmp_path):
    from snake_env.agents.search import rollout_speeds
    from snake_env.controllers.gaits import load_params

    report = evaluate_json(tmp_path, "--baseline", "serpenoid", "--env", ENV, "--episodes", "1", "--seed", "4",
                           "--max-steps", "120")
    params, env_kwargs = load_params(ENV)
    expected = rollout_speeds(ENV, env_kwargs, [params], 120, seed=4)[0]
    assert report["algo"] == "serpenoid"
    assert report["mean_forward_velocity"] == pytest.approx(expected, rel=1e-9)


def bad_model_cases(ppo_run: Path, tmp_path: Path):
    garbage = tmp_path / "garbage.zip"
    garbage.write_bytes(b"not a zip at all")
    truncated = tmp_path / "truncated" / "model.zip"
    truncated.parent.mkdir()
    truncated.write_bytes((ppo_run / "model.zip").read_bytes()[:2000])
    bare = tmp_path / "bare" / "model.zip"  # no config.yaml: the env comes from --env
    bare.parent.mkdir()
    shutil.copy(ppo_run / "model.zip", bare)
    no_stats = tmp_path / "no_stats"
    no_stats.mkdir()
    shutil.copy(ppo_run / "model.zip", no_stats)
    shutil.copy(ppo_run / "config.yaml", no_stats)
    bad_stats = tmp_path / "bad_stats"
    shutil.copytree(no_stats, bad_stats)
    (bad_stats / "vecnormalize.pkl").write_bytes(b"\x80\x04corrupt")
    no_gaits = tmp_path / "gaits.yaml"  # every registered id has a shipped gait, so an empty gait file
    no_gaits.write_text("{}\n")
    return [
        ([str(tmp_path / "missing")], "no such run directory or model file"),
        ([str(garbage), "--env", ENV], "not an SB3 model file"),
        ([str(truncated), "--env", ENV], "not an SB3 model file"),
        ([str(bare), "--env", "snake_env/Snake5-v2"], "expects observations of shape (8,), the env gives (12,)"),
        ([str(ppo_run), "--env", "snake_env/Snake5-v2"], "was trained on snake_env/Snake3-v2"),
        ([str(no_stats)], "VecNormalize statistics are missing"),
        ([str(bad_stats)], "not readable VecNormalize statistics"),
        ([str(tmp_path)], "holds no model.zip"),
        (["--baseline", "serpenoid", "--env", "snake_env/Snake30-v2", "--serpenoid-config", str(no_gaits)],
         "no serpenoid gait for n_links=30"),
        ([str(ppo_run), "--video", str(tmp_path / "v.avi")], "--video must end with one of"),
    ]


def test_bad_model_files_are_one_line_errors(ppo_run, tmp_path, capsys):
    for argv, pattern in bad_model_cases(ppo_run, tmp_path):
        with pytest.raises(SystemExit) as info:
            main(argv)
        assert info.value.code == 2, argv
        err = capsys.readouterr().err.strip()
        assert err.startswith("snake-eval: error:") and pattern in err and "\n" not in err, (argv, err)


def test_cli_process_exits_nonzero_without_traceback(tmp_path):
    garbage = tmp_path / "model.zip"
    garbage.write_bytes(b"PK\x03\x04 corrupt")
    result = subprocess.run([sys.executable, "-m", "snake_env.train.evaluate", str(garbage), "--env", ENV], cwd=REPO,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert result.stderr.startswith("snake-eval: error:") and result.stderr.count("\n") == 1


def test_sliding_wheels_beside_the_env(tmp_path):
    """--sliding-wheels: the serpenoid on the env and on wheels that slide, from one reset state."""
    report = evaluate_json(tmp_path, "--baseline", "serpenoid", "--env", newest_id("Snake5"), "--episodes", "1",
                           "--max-steps", "10", "--sliding-wheels", "10")
    sliding = report["sliding_wheels"]
    assert sliding["steps"] == 10 and sliding["wheel_friction"] == 0.8
    assert sliding["env_x_velocity"] != sliding["sliding_x_velocity"]  # two models
    assert 0.0 <= sliding["wheel_steps_sliding"] <= 1.0 and sliding["friction_power"] >= 0.0


@pytest.mark.parametrize("argv, pattern", [
    (["--sliding-wheels", "0"], "--sliding-wheels must be >= 1"),
    (["--env-kwarg", "wheel_friction=null"], "wheel_friction must be a number > 0"),
])
def test_sliding_wheels_bad_input_is_one_line(capsys, argv, pattern):
    with pytest.raises(SystemExit) as info:
        main(["--baseline", "serpenoid", "--env", newest_id("Snake5"), "--episodes", "1", "--max-steps", "2",
              "--sliding-wheels", "2", *argv])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("snake-eval: error:") and pattern in err and "\n" not in err, err
