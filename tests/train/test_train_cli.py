"""snake-train smoke tests: run-dir contents, resume, Ctrl-C keeps a model, clean CLI errors."""

from __future__ import annotations

import os
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from tests.train.conftest import train_args
from snake_env.train.callbacks import latest_checkpoint
from snake_env.train.train import main

REPO = Path(__file__).resolve().parents[2]


def obs_count(path) -> float:
    with open(path, "rb") as handle:
        return float(pickle.load(handle).obs_rms.count)


def check_run_dir(run_dir: Path, algo: str, steps: int) -> None:
    for name in ("config.yaml", "model.zip", "vecnormalize.pkl", "learning_curve.png", "eval/evaluations.npz",
                 "best_model/best_model.zip", "best_model/vecnormalize.pkl", "logs/segment_0/progress.csv"):
        assert (run_dir / name).is_file(), name
    assert list((run_dir / "logs/segment_0").glob("events.out.tfevents.*"))  # TensorBoard
    checkpoints = sorted((run_dir / "checkpoints").glob("model_*_steps.zip"))
    assert len(checkpoints) >= 2
    for path in checkpoints:  # every checkpoint carries its own statistics
        steps_of = path.name.split("_")[1]
        assert (run_dir / "checkpoints" / f"vecnormalize_{steps_of}_steps.pkl").is_file()
    assert latest_checkpoint(run_dir / "checkpoints")[0] >= steps
    config = yaml.safe_load((run_dir / "config.yaml").read_text())
    assert config["algo"] == algo and config["env_id"] == "snake_env/Snake3-v2"
    assert config["n_envs"] == 2 and config["env_kwargs"] == {"max_episode_steps": 50}
    assert not list(run_dir.rglob(".*.tmp*"))  # atomic writes leave no temp files


def test_ppo_run_directory(ppo_run):
    check_run_dir(ppo_run, "ppo", 256)
    # statistics were saved with the final model: they have seen every training observation
    assert obs_count(ppo_run / "vecnormalize.pkl") >= 256


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_resume_continues_from_the_newest_checkpoint(tmp_path, algo, capsys):
    run_dir = tmp_path / algo
    assert main(train_args(algo, run_dir, 192)) == 0
    check_run_dir(run_dir, algo, 192)
    steps_before, _ = latest_checkpoint(run_dir / "checkpoints")
    count_before = obs_count(run_dir / "checkpoints" / f"vecnormalize_{steps_before}_steps.pkl")
    config_before = (run_dir / "config.yaml").read_text()
    if algo == "sac":
        assert (run_dir / "checkpoints" / "replay_buffer.pkl").is_file()
    assert main(["--resume", str(run_dir), "--total-timesteps", "320", "--no-progress-bar"]) == 0
    assert f"from model_{steps_before}_steps.zip" in capsys.readouterr().out
    steps_after, _ = latest_checkpoint(run_dir / "checkpoints")
    assert steps_after >= 320
    # normalization statistics continue from the checkpoint instead of restarting
    assert obs_count(run_dir / "vecnormalize.pkl") >= count_before + (steps_after - steps_before)
    assert (run_dir / "logs/segment_1/progress.csv").is_file()
    assert (run_dir / "config.yaml").read_text() == config_before


def test_an_interrupt_during_a_save_is_raised_when_the_save_ends(tmp_path, monkeypatch):
    """A Ctrl-C inside a checkpoint's torch.save used to break the zip writer, whose RuntimeError then
    replaced the KeyboardInterrupt (exit 1, no final model). The signal handler now holds it until the
    snapshot is written whole; a second signal meanwhile is ignored."""
    from stable_baselines3 import PPO

    from snake_env.train import train as train_module
    from snake_env.train.callbacks import save_snapshot

    monkeypatch.setattr(train_module, "_stopping", False)
    model = PPO("MlpPolicy", "Pendulum-v1", n_steps=64, batch_size=64, device="cpu")
    original = model.policy.state_dict

    def interrupted_midway(*args, **kwargs):  # the signals arrive while the model is being written
        train_module._interrupt(signal.SIGINT, None)
        train_module._interrupt(signal.SIGTERM, None)
        return original(*args, **kwargs)

    monkeypatch.setattr(model.policy, "state_dict", interrupted_midway)
    with pytest.raises(KeyboardInterrupt, match=f"signal {int(signal.SIGINT)}"):
        save_snapshot(model, tmp_path / "model.zip", tmp_path / "vecnormalize.pkl")
    PPO.load(tmp_path / "model.zip", device="cpu")  # written whole before the interrupt was raised


def test_sigint_saves_model_and_statistics(tmp_path):
    """Even when started with SIGINT ignored (a background job of a
    non-interactive shell), Ctrl-C saves the model and exits with 130; a second
    signal (here SIGTERM right after it) waits for the save instead of cutting it short."""
    run_dir = tmp_path / "interrupted"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    process = subprocess.Popen([sys.executable, "-m", "snake_env.train", *train_args("ppo", run_dir, 10_000_000)],
                               cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    try:
        deadline = time.monotonic() + 120
        # wait until training is under way (the first checkpoint exists)
        while latest_checkpoint(run_dir / "checkpoints") is None:
            assert process.poll() is None, process.communicate()
            assert time.monotonic() < deadline, "training did not start"
            time.sleep(0.2)
        process.send_signal(signal.SIGINT)
        process.send_signal(signal.SIGTERM)
        out, err = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 130, err
    assert "Traceback" not in err
    assert "interrupted after" in out
    assert "saving what the run made, please wait" in err
    assert (run_dir / "model.zip").is_file() and (run_dir / "vecnormalize.pkl").is_file()
    steps, path = latest_checkpoint(run_dir / "checkpoints")
    from stable_baselines3 import PPO

    model = PPO.load(run_dir / "model.zip", device="cpu")
    assert model.num_timesteps == steps  # the interrupt also left a checkpoint to resume from
    assert 0 < steps < 10_000_000


@pytest.mark.parametrize("argv, pattern", [
    (["--algo", "a2c", "--env", "snake_env/Snake3-v2"], "algo must be one of ['ppo', 'sac']"),
    (["--algo", "ppo", "--env", "snake_env/Snake3-v2", "--set", "gama=0.9"], "unknown config key(s) ['gama']"),
    (["--algo", "ppo", "--env", "snake_env/Snake9-v2"], "available env ids"),
    (["--algo", "ppo", "--env", "snake_env/Snake3-v2", "--set", "env_kwargs.max_torque=-1", "--total-timesteps", "64"],
     "max_torque"),
    (["--algo", "ppo", "--env", "snake_env/Snake3-v2", "--set", "n_steps=0", "--total-timesteps", "64"],
     "invalid ppo hyperparameters"),
    (["--resume", "no/such/run"], "config.yaml not found"),
    (["--env", "snake_env/Snake3-v2"], "--algo {ppo,sac} and --env ID are required"),
])
def test_bad_input_is_a_one_line_error(tmp_path, capsys, argv, pattern):
    with pytest.raises(SystemExit) as info:
        main([*argv, "--run-dir", str(tmp_path / "r")] if "--resume" not in argv else argv)
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("snake-train: error:") and pattern in err and "\n" not in err


def test_existing_run_dir_is_not_overwritten(ppo_run, capsys):
    with pytest.raises(SystemExit):
        main(["--algo", "ppo", "--env", "snake_env/Snake3-v2", "--run-dir", str(ppo_run)])
    assert "already holds a run; use --resume" in capsys.readouterr().err
