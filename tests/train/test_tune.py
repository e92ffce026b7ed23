"""snake-tune on SQLite: outputs, resume, pruning, a killed worker, clean CLI errors."""

from __future__ import annotations

import hashlib
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import optuna
import pytest
import yaml
from optuna.trial import TrialState

from snake_env.train import tune
from snake_env.train.train import main as train_main
from snake_env.train.tune_objective import TrialEvalCallback
from stable_baselines3.common.callbacks import BaseCallback

REPO = Path(__file__).resolve().parents[2]
ENV = "snake_env/Snake3-v2"
# seconds per trial: 50-step episodes, 2 envs, an 8-unit network, one evaluation episode
TINY = ["--algo", "ppo", "--env", ENV, "--n-envs", "2", "--n-evaluations", "2",
        "--set", "env_kwargs.max_episode_steps=50", "--set", "n_eval_episodes=1",
        "--set", "policy_kwargs.net_arch=[8]", "--set", "n_steps=32", "--set", "batch_size=32",
        "--set", "n_epochs=1"]


def tune_args(out, steps=256, trials=2, *extra) -> list[str]:
    return [*TINY, "--n-timesteps", str(steps), "--n-trials", str(trials), "--out", str(out), *extra]


def load(out, name="ppo-Snake3-v2", storage=None):
    return optuna.load_study(study_name=name, storage=storage or f"sqlite:///{Path(out).resolve() / 'study.db'}")


def worker(args, **kwargs) -> subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1",
           "PYTHONPATH": str(REPO)}
    return subprocess.Popen([sys.executable, "-m", "snake_env.train.tune", *args], cwd=REPO, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, **kwargs)


def test_sqlite_study_writes_a_best_config_that_trains_and_resumes(tmp_path, capsys):
    out = tmp_path / "study"
    assert tune.main(tune_args(out)) == 0
    printed = capsys.readouterr().out
    assert printed.count("COMPLETE") >= 2 and "best: trial" in printed  # a line per trial, a summary
    for name in ("study.db", "study.csv", "best_config.yaml", "optimization_history.png", "param_importances.png"):
        assert (out / name).is_file(), name
    study = load(out)
    assert [t.state for t in study.trials] == [TrialState.COMPLETE] * 2
    assert len((out / "study.csv").read_text().strip().splitlines()) == 1 + 2

    best = yaml.safe_load((out / "best_config.yaml").read_text())
    assert list(best) == [ENV]
    entry = best[ENV]
    assert entry["gamma"] == pytest.approx(1 - study.best_trial.params["one_minus_gamma"])
    assert entry["learning_rate"] == pytest.approx(study.best_trial.params["learning_rate"])
    assert entry["n_steps"] == 32 and entry["n_timesteps"] == 256  # fixed keys and the budget kept
    # snake-train accepts it as a --config and trains with it
    run_dir = tmp_path / "run"
    assert train_main(["--algo", "ppo", "--env", ENV, "--config", str(out / "best_config.yaml"),
                       "--total-timesteps", "128", "--run-dir", str(run_dir), "--no-progress-bar"]) == 0
    saved = yaml.safe_load((run_dir / "config.yaml").read_text())
    assert saved["gamma"] == pytest.approx(entry["gamma"]) and (run_dir / "model.zip").is_file()

    # the same command again resumes the study: trials accumulate
    assert tune.main(tune_args(out, trials=1)) == 0
    assert "2 trials so far" in capsys.readouterr().out
    assert len(load(out).trials) == 3
    assert len((out / "study.csv").read_text().strip().splitlines()) == 1 + 3


def make_hopeless_study(n_evaluations: int):
    """Five finished trials that reached 1 m/s at every evaluation."""
    study = optuna.create_study(direction="maximize", pruner=tune.make_pruner("median", n_evaluations))
    distribution = optuna.distributions.FloatDistribution(0.0, 1.0)
    for k in range(tune.MEDIAN_STARTUP_TRIALS):
        study.add_trial(optuna.trial.create_trial(
            params={"x": 0.1 * k}, distributions={"x": distribution}, value=1.0,
            intermediate_values={step: 1.0 for step in range(1, n_evaluations + 1)}))
    return study


def test_median_pruner_prunes_a_hopeless_trial_through_the_reporting_callback():
    study = make_hopeless_study(n_evaluations=4)
    callback = TrialEvalCallback(study.ask(), eval_env=None, n_evaluations=4, n_timesteps=400, n_eval_episodes=1)
    # step 1 (= the warm-up, 4 // 3: the first compared step), far below every other trial's 1 m/s
    with pytest.raises(optuna.TrialPruned):
        callback.report(-0.5)
    assert callback.eval_index == 1
    good = TrialEvalCallback(study.ask(), eval_env=None, n_evaluations=4, n_timesteps=400, n_eval_episodes=1)
    for _ in range(4):
        good.report(1.2)  # above the median: never pruned
    assert good.eval_index == 4


@pytest.mark.parametrize("pruner", ["hyperband"])
def test_other_pruner_prunes_too(pruner):
    study = optuna.create_study(direction="maximize", pruner=tune.make_pruner(pruner, 9),
                                sampler=optuna.samplers.RandomSampler(seed=0))
    pruned = 0
    for k in range(30):
        trial = study.ask()
        callback = TrialEvalCallback(trial, eval_env=None, n_evaluations=9, n_timesteps=900, n_eval_episodes=1)
        value = 1.0 if k % 2 == 0 else -1.0  # every other trial hopeless
        try:
            for _ in range(9):
                callback.report(value)
            study.tell(trial, value)
        except optuna.TrialPruned:
            study.tell(trial, state=TrialState.PRUNED)
            pruned += 1
            assert value < 0  # only hopeless trials are pruned
    assert pruned > 0


def test_non_finite_speed_prunes():
    study = optuna.create_study(direction="maximize", pruner=tune.make_pruner("none", 2))
    callback = TrialEvalCallback(study.ask(), eval_env=None, n_evaluations=2, n_timesteps=200, n_eval_episodes=1)
    with pytest.raises(optuna.TrialPruned):
        callback.report(math.nan)


def test_a_killed_worker_trial_is_failed_on_the_next_start(tmp_path):
    """SIGKILL mid-trial: the next worker fails the stale trial (heartbeat) and the study completes."""
    out = tmp_path / "killed"
    args = tune_args(out, 20_000, 1, "--heartbeat-interval", "1", "--pruner", "none")
    process = worker(args)
    storage = f"sqlite:///{out.resolve() / 'study.db'}"
    try:
        deadline = time.monotonic() + 180
        running = False
        while time.monotonic() < deadline and process.poll() is None:
            try:
                running = any(t.state == TrialState.RUNNING for t in load(out, storage=storage).trials)
            except (KeyError, Exception):
                running = False
            if running:
                break
            time.sleep(0.2)
        assert running, "the worker never started a trial"
        time.sleep(1.0)  # training, at least one heartbeat written
        process.send_signal(signal.SIGKILL)
        process.wait(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert [t.state for t in load(out, storage=storage).trials] == [TrialState.RUNNING]
    time.sleep(2.5)  # past the grace period (2 heartbeat intervals)
    restarted = worker(tune_args(out, 20_000, 1, "--heartbeat-interval", "1", "--pruner", "none"))
    stdout, stderr = restarted.communicate(timeout=600)
    assert restarted.returncode == 0, stderr
    assert "failed stale trial(s) [0]" in stdout
    states = [t.state for t in load(out, storage=storage).trials]
    assert states == [TrialState.FAIL, TrialState.COMPLETE]
    assert (out / "best_config.yaml").is_file()


def file_digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def existing_study(tmp_path):
    """An existing study (one finished trial) whose database file must stay untouched by bad commands."""
    out = tmp_path / "existing"
    out.mkdir()
    study = optuna.create_study(study_name="ppo-Snake3-v2", storage=f"sqlite:///{out.resolve()}/study.db",
                                direction="maximize")
    study.set_user_attr("algo", "ppo")
    study.set_user_attr("env_id", ENV)
    study.set_user_attr("n_timesteps", 256)
    study.tell(study.ask(), 0.5)
    return out


BAD = [
    (["--algo", "dqn"], "--algo must be one of ['ppo', 'sac']"),
    (["--sampler", "grid"], "--sampler must be one of ['tpe', 'cmaes', 'random']"),
    (["--pruner", "asha"], "--pruner must be one of ['median', 'hyperband', 'none']"),
    (["--n-trials", "0"], "--n-trials must be a positive integer"),
    (["--n-timesteps", "-5"], "--n-timesteps must be a positive integer"),
    (["--n-evaluations", "0"], "--n-evaluations must be a positive integer"),
    (["--n-envs", "0"], "--n-envs must be a positive integer"),
    (["--n-trials", "many"], "argument --n-trials: invalid int value"),
    (["--timeout", "-1"], "--timeout must be a positive number"),
    (["--env", "snake_env/Snake4-v2"], "--env 'snake_env/Snake4-v2' is not a registered env id; registered snake envs:"),
    (["--storage", "no url"], "--storage 'no url' is not an SQLAlchemy URL"),
    (["--storage", "postgresql+psycopg://snake@127.0.0.1:1/optuna"], "cannot connect"),
    (["--storage", "nosuchdb://x/y"], "no database driver"),
    (["--storage", "sqlite:////nonexistent-dir/study.db"], "directory /nonexistent-dir does not exist"),
    (["--set", "n_stepz=32"], "unknown config key(s) ['n_stepz']"),
    (["--n-timesteps", "512"], "--n-timesteps 512 differs from the 256 that study 'ppo-Snake3-v2' was created with"),
]


@pytest.mark.parametrize("bad, message", BAD, ids=[" ".join(b) for b, _ in BAD])
def test_bad_input_one_line_exit_2_and_the_study_untouched(existing_study, capsys, bad, message):
    database = existing_study / "study.db"
    before = file_digest(database)
    with pytest.raises(SystemExit) as exit_info:
        tune.main(tune_args(existing_study, 256, 1) + bad)  # later flags win
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("snake-tune: error: ") and message in err, err
    assert "Traceback" not in err
    assert file_digest(database) == before
    assert sorted(p.name for p in existing_study.iterdir()) == ["study.db"]


def test_bad_input_from_the_command_line(tmp_path):
    process = worker(["--algo", "ppo", "--env", ENV, "--n-trials", "1", "--n-timesteps", "100",
                      "--out", str(tmp_path / "x"), "--pruner", "nope"])
    stdout, stderr = process.communicate(timeout=120)
    assert process.returncode == 2
    assert stderr == "snake-tune: error: --pruner must be one of ['median', 'hyperband', 'none'], got 'nope'\n"
    assert not (tmp_path / "x").exists()


SAC_TINY = ["--algo", "sac", "--env", ENV, "--n-envs", "2", "--n-evaluations", "2",
            "--set", "env_kwargs.max_episode_steps=50", "--set", "n_eval_episodes=1",
            "--set", "policy_kwargs.net_arch=[8]", "--set", "learning_starts=64", "--set", "buffer_size=2000",
            "--set", "batch_size=32"]


@pytest.mark.parametrize("algo_args, sampler, pruner", [(SAC_TINY, "cmaes", "hyperband"), (TINY, "random", "none")],
                         ids=["sac-cmaes-hyperband", "ppo-random-none"])
def test_every_algo_sampler_and_pruner_runs_a_study(tmp_path, algo_args, sampler, pruner):
    out = tmp_path / "study"
    args = [*algo_args, "--n-timesteps", "256", "--n-trials", "2", "--out", str(out), "--sampler", sampler,
            "--pruner", pruner, "--seed", "3"]
    assert tune.main(args) == 0
    algo = algo_args[1]
    study = load(out, name=f"{algo}-Snake3-v2")
    assert len(study.trials) == 2 and all(t.state == TrialState.COMPLETE for t in study.trials)
    searched = set(study.trials[0].params)
    assert "learning_rate" in searched and "net_arch" not in searched  # --set keys are not searched
    entry = yaml.safe_load((out / "best_config.yaml").read_text())[ENV]
    assert entry["learning_rate"] == pytest.approx(study.best_trial.params["learning_rate"])


def test_baseline_searches_nothing(tmp_path):
    out = tmp_path / "baseline"
    assert tune.main(tune_args(out, 256, 1, "--baseline")) == 0
    study = load(out)
    assert study.trials[0].params == {} and study.trials[0].state == TrialState.COMPLETE


class CountingCallback(BaseCallback):
    """Counts the trainings it was started in (class-level: the tuner builds its own instance)."""

    started = 0

    def _on_training_start(self) -> None:
        type(self).started += 1

    def _on_step(self) -> bool:
        return True


def test_the_configs_callbacks_run_in_every_trial(tmp_path):
    """A ``callback`` entry (e.g. ResidualBurnIn) acts in tuning trials as in snake-train."""
    CountingCallback.started = 0
    out = tmp_path / "study"
    assert tune.main(tune_args(out, 128, 2, "--set", "callback=tests.train.test_tune.CountingCallback")) == 0
    assert CountingCallback.started == len(load(out).trials) == 2
