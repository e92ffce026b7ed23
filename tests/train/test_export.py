"""snake-export: the ONNX graph reproduces model.predict(normalize(obs), deterministic=True)
for PPO and SAC, with and without VecNormalize; the onnxruntime runner needs neither
torch nor SB3 and reports snake-eval's metrics; bad inputs fail with one line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

from tests.newest_ids import newest_id
from tests.train.conftest import ENV, train_args

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")

from snake_env.agents.policy_loading import load_policy  # noqa: E402
from snake_env.train.config import load_run_config  # noqa: E402
from snake_env.train.export import main as export_main  # noqa: E402
from snake_env.train.export import read_metadata  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
N_OBS = 1000


@pytest.fixture(scope="module")
def runs(ppo_run, tmp_path_factory):
    """Tiny runs: PPO normalized (the shared fixture), PPO plain, SAC normalized, SAC plain."""
    from snake_env.train.train import main

    root = tmp_path_factory.mktemp("export_runs")
    made = {("ppo", True): ppo_run}
    for algo, normalize in (("ppo", False), ("sac", True), ("sac", False)):
        run_dir = root / f"{algo}_{'norm' if normalize else 'plain'}"
        extra = [] if normalize else ["--set", "normalize=false"]
        assert main(train_args(algo, run_dir, 192 if algo == "sac" else 128, *extra)) == 0
        assert (run_dir / "vecnormalize.pkl").is_file() == normalize
        made[(algo, normalize)] = run_dir
    return made


def recorded_observations(n: int) -> np.ndarray:
    """Raw observations of random-action rollouts (several episodes, diverse states)."""
    env = gym.make(ENV, max_episode_steps=50)
    obs, _ = env.reset(seed=0)
    env.action_space.seed(0)
    observations = []
    while len(observations) < n:
        observations.append(obs)
        obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            obs, _ = env.reset()
    env.close()
    return np.asarray(observations, np.float32)


@pytest.mark.parametrize("algo", ["ppo", "sac"])
@pytest.mark.parametrize("normalize", [True, False])
def test_onnx_actions_equal_sb3_predict(runs, tmp_path, algo, normalize):
    run_dir = runs[(algo, normalize)]
    out = tmp_path / "policy.onnx"
    assert export_main([str(run_dir), "--out", str(out)]) == 0
    model = onnx.load(str(out))
    onnx.checker.check_model(model, full_check=True)
    meta = read_metadata(out)
    assert meta["env_id"] == ENV and meta["algo"] == algo and meta["n_links"] == "3"
    assert meta["obs_size"] == "8" and meta["action_size"] == "2"
    assert meta["vecnormalize"] == ("folded" if normalize else "none")
    assert json.loads(meta["env_kwargs"]) == {"max_episode_steps": 50}
    import snake_env

    assert meta["snake_env_version"] == snake_env.__version__

    env = gym.make(ENV)
    loaded = load_policy(run_dir, env.observation_space, env.action_space,
                         {"algo": algo, "normalize": normalize})
    env.close()
    assert (loaded.normalizer is not None) == normalize
    observations = recorded_observations(N_OBS)
    expected = np.stack([loaded.model.predict(loaded.normalize(o), deterministic=True)[0] for o in observations])
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    batched = session.run(None, {"obs": observations})[0]
    single = np.stack([session.run(None, {"obs": o[None]})[0][0] for o in observations[:50]])
    assert batched.shape == expected.shape == (N_OBS, 2)
    np.testing.assert_allclose(batched, expected, rtol=0, atol=1e-5)
    np.testing.assert_allclose(single, expected[:50], rtol=0, atol=1e-5)
    assert np.all(batched >= -1.0) and np.all(batched <= 1.0)
    if algo == "ppo":  # the clip to the action range is part of the graph, and was exercised
        raw = loaded.model.policy.predict(loaded.normalize(observations), deterministic=True)[0]
        assert raw.shape == batched.shape


FORBID_HOOK = """
import importlib.abc, runpy, sys
class Forbid(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("torch", "stable_baselines3"):
            raise ImportError(f"{name} is forbidden in the ONNX deploy path")
        return None
sys.meta_path.insert(0, Forbid())
"""
FORBID_TORCH = FORBID_HOOK + """
sys.argv = sys.argv[1:]
runpy.run_path(sys.argv[0], run_name="__main__")
"""


def eval_json(path: Path, *argv) -> dict:
    from snake_env.train.evaluate import main as eval_main

    assert eval_main([*map(str, argv), "--json", str(path)]) == 0
    return json.loads(path.read_text())


def test_onnx_runner_without_torch_matches_snake_eval(runs, tmp_path):
    run_dir = runs[("ppo", True)]
    out = tmp_path / "policy.onnx"
    assert export_main([str(run_dir), "--out", str(out)]) == 0
    reference = eval_json(tmp_path / "sb3.json", run_dir, "--episodes", "2", "--seed", "7")
    via_onnx = eval_json(tmp_path / "onnx.json", "--onnx", out, "--episodes", "2", "--seed", "7")
    assert [e["length"] for e in via_onnx["episodes"]] == [e["length"] for e in reference["episodes"]]
    for ours, theirs in zip(via_onnx["episodes"], reference["episodes"]):
        for key in ("return", "forward_velocity", "distance", "x_displacement"):
            assert ours[key] == pytest.approx(theirs[key], abs=1e-6), key

    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "-c", FORBID_TORCH, str(REPO / "examples" / "run_onnx.py"), str(out),
                           "--episodes", "2", "--seed", "7"], capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    rows = [line.split() for line in proc.stdout.splitlines() if line.split()[:1] in (["0"], ["1"])]
    assert [int(r[1]) for r in rows] == [7, 8]
    for row, theirs in zip(rows, reference["episodes"]):
        assert float(row[2]) == pytest.approx(theirs["return"], abs=1e-3)  # printed with 3 decimals
        assert float(row[3]) == pytest.approx(theirs["forward_velocity"], abs=1e-4)
    # the hook does forbid: importing torch (or snake-eval's SB3 path) under it fails
    proc = subprocess.run([sys.executable, "-c", FORBID_HOOK + "import torch\n"], capture_output=True, text=True,
                          env=env, timeout=300)
    assert proc.returncode != 0 and "forbidden" in proc.stderr


def test_a_run_with_opt_in_wrappers_exports_and_evaluates_in_the_wrapped_env(tmp_path):
    """The network of a CPG-action run maps the wrapped observation (+2 phase entries) to the
    4 CPG parameters; the metadata names the wrappers and snake-eval --onnx applies them,
    giving SB3's evaluation over a short horizon (longer ones diverge by chaos from float32
    rounding, as any two float32 implementations of the same policy would)."""
    from snake_env.train.train import main

    run_dir = tmp_path / "cpg_run"
    assert main(train_args("ppo", run_dir, 128, "--set", "env_wrapper={cpg: {max_frequency: 30.0}}")) == 0
    out = tmp_path / "cpg.onnx"
    assert export_main([str(run_dir), "--out", str(out)]) == 0
    meta = read_metadata(out)
    assert json.loads(meta["env_wrapper"]) == {"cpg": {"max_frequency": 30.0}}
    assert meta["obs_size"] == "10" and meta["action_size"] == "4"
    reference = eval_json(tmp_path / "sb3.json", run_dir, "--episodes", "1", "--max-steps", "5")
    via_onnx = eval_json(tmp_path / "onnx.json", "--onnx", out, "--episodes", "1", "--max-steps", "5")
    assert via_onnx["episodes"][0]["return"] == pytest.approx(reference["episodes"][0]["return"], abs=1e-5)


def run_cli(*argv):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, "-m", "snake_env.train.export", *map(str, argv)], capture_output=True, text=True,
                          env=env, timeout=300)


def test_export_errors_are_one_line(runs, tmp_path):
    run_dir = runs[("ppo", True)]
    bad_dir = tmp_path / "empty"
    bad_dir.mkdir()
    not_zip = tmp_path / "model.zip"
    not_zip.write_text("not a zip")
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    cases = [
        ((tmp_path / "missing", "--out", tmp_path / "a.onnx"), "no such run directory"),
        ((bad_dir, "--out", tmp_path / "a.onnx"), "holds no model.zip"),
        ((not_zip, "--out", tmp_path / "a.onnx"), "not an SB3 model file"),
        ((run_dir, "--out", tmp_path / "a.txt"), "must end with .onnx"),
        ((run_dir, "--out", tmp_path / "nodir" / "a.onnx"), "does not exist"),
        ((run_dir, "--out", tmp_path / "a.onnx", "--env", newest_id("Snake5")), "was trained on"),
    ]
    from stable_baselines3 import TD3

    TD3("MlpPolicy", gym.make(ENV), device="cpu").save(tmp_path / "td3" / "model.zip")
    cases.append(((tmp_path / "td3", "--out", tmp_path / "a.onnx", "--env", ENV), "not one of ['ppo', 'sac']"))
    if os.geteuid() != 0:  # root writes anywhere
        cases.append(((run_dir, "--out", locked / "a.onnx"), "not writable"))
    for argv, message in cases:
        proc = run_cli(*argv)
        assert proc.returncode == 2, (argv, proc.stderr)
        assert proc.stderr.count("\n") == 1 and message in proc.stderr, proc.stderr
        assert "Traceback" not in proc.stderr
    # a model whose spaces do not fit the env (another n_links): copied without its config
    alone = tmp_path / "alone"
    alone.mkdir()
    (alone / "model.zip").write_bytes((run_dir / "model.zip").read_bytes())
    proc = run_cli(alone, "--out", tmp_path / "b.onnx", "--env", newest_id("Snake5"))
    assert proc.returncode == 2 and "another env or n_links" in proc.stderr and proc.stderr.count("\n") == 1
    assert not (tmp_path / "a.onnx").exists() and not (tmp_path / "b.onnx").exists()
    locked.chmod(0o700)


def test_snake_eval_onnx_errors(tmp_path):
    from snake_env.train.evaluate import main as eval_main

    garbage = tmp_path / "garbage.onnx"
    garbage.write_bytes(b"not a model")
    for argv, message in (
        (["--onnx", str(tmp_path / "missing.onnx")], "no such ONNX file"),
        (["--onnx", str(garbage)], "not a readable ONNX model"),
        (["--onnx", str(garbage), "--baseline", "serpenoid", "--env", ENV], "not --baseline and --onnx"),
    ):
        with pytest.raises(SystemExit) as exit_info:
            eval_main(argv)
        assert exit_info.value.code == 2
    proc = subprocess.run([sys.executable, "-m", "snake_env.train.evaluate", "--onnx", str(garbage)], capture_output=True,
                          text=True, timeout=300,
                          env={**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])})
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "not a readable ONNX model" in proc.stderr


REACH = "snake_env/SnakeReach5-v1"


@pytest.mark.parametrize("algo, extra", [
    # the shipped PPO entry: residual on goal seeking, observations normalized per key
    ("ppo", ["--set", "n_steps=32", "--set", "batch_size=32", "--set", "n_epochs=1"]),
    # with the goal in the heading frame appended (opt-in goal_frame; trains on same-step autoreset)
    ("ppo", ["--set", "n_steps=32", "--set", "batch_size=32", "--set", "n_epochs=1",
             "--set", "env_wrapper=[serpenoid_residual, goal_frame]"]),
    # SAC + HER, no normalization (the shipped SAC entry)
    ("sac", ["--set", "learning_starts=120", "--set", "buffer_size=2000", "--set", "batch_size=32"]),
    # the same with the goal in the heading frame computed inside the policy (GoalFrameExtractor)
    ("sac", ["--set", "learning_starts=120", "--set", "buffer_size=2000", "--set", "batch_size=32",
             "--set", "policy_kwargs=dict(net_arch=[8], features_extractor_class='goal_frame')"]),
])
def test_a_goal_task_policy_exports_one_input_per_key(tmp_path, algo, extra):
    """Dict observation (observation / achieved_goal / desired_goal): one named graph input per
    key; the graph gives SB3's predict on recorded observations, and snake-eval --onnx gives
    the SB3 evaluation, task metrics included."""
    from snake_env.train.train import main
    from snake_env.wrappers import wrap_env

    run_dir = tmp_path / algo
    assert main(["--algo", algo, "--env", REACH, "--total-timesteps", "300" if algo == "sac" else "128",
                 "--run-dir", str(run_dir), "--n-envs", "2", "--set", "env_kwargs.max_episode_steps=50",
                 "--set", "eval_freq=1000", "--set", "n_eval_episodes=1", "--no-progress-bar", *extra]) == 0
    out = tmp_path / "reach.onnx"
    assert export_main([str(run_dir), "--out", str(out)]) == 0
    meta = read_metadata(out)
    config = load_run_config(run_dir / "config.yaml")
    env = wrap_env(gym.make(REACH, **config["env_kwargs"]), config.get("env_wrapper"))
    sizes = {key: space.shape[0] for key, space in env.observation_space.spaces.items()}
    assert json.loads(meta["obs_keys"]) == sizes and meta["obs_size"] == str(sum(sizes.values()))
    assert meta["vecnormalize"] == ("folded" if algo == "ppo" else "none")
    session = ort.InferenceSession(str(out), providers=["CPUExecutionProvider"])
    assert [i.name for i in session.get_inputs()] == list(sizes)

    loaded = load_policy(run_dir, env.observation_space, env.action_space, config)
    observations = []
    obs, _ = env.reset(seed=0)
    env.action_space.seed(0)
    while len(observations) < 200:
        observations.append(obs)
        obs, _, terminated, truncated, _ = env.step(env.action_space.sample())
        if terminated or truncated:
            obs, _ = env.reset()
    env.close()
    expected = np.stack([loaded.act(o) for o in observations])
    batch = {key: np.stack([o[key] for o in observations]).astype(np.float32) for key in sizes}
    np.testing.assert_allclose(session.run(None, batch)[0], expected, rtol=0, atol=1e-5)

    reference = eval_json(tmp_path / "sb3.json", run_dir, "--episodes", "1", "--max-steps", "5")
    via_onnx = eval_json(tmp_path / "onnx.json", "--onnx", out, "--episodes", "1", "--max-steps", "5")
    assert via_onnx["task"] == reference["task"] == "reach"
    assert via_onnx["episodes"][0]["return"] == pytest.approx(reference["episodes"][0]["return"], abs=1e-5)
    assert via_onnx["mean_final_goal_distance"] == pytest.approx(reference["mean_final_goal_distance"], abs=1e-5)
