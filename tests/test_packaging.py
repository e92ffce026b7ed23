"""The distribution: ``python -m build`` makes an sdist and a wheel; the wheel puts only
``snake_env`` (and its dist-info) at the top of site-packages, carries the shipped configs,
and, installed into a fresh venv, trains and evaluates from an unrelated directory.

Cost: the venv is created without pip and sees this interpreter's packages through a .pth
file, so installing the wheel with ``--no-index`` checks its dependency metadata against
what is installed here without downloading anything (torch included): ~1 min on the
2-core machine, most of it the tiny training run.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
import tarfile
import zipfile
from pathlib import Path

import pytest

from tests.newest_ids import newest_id

REPO = Path(__file__).resolve().parents[1]
IGNORED = shutil.ignore_patterns(".git", ".venv", "runs", "docs", "tests", "__pycache__", "*.egg-info", "build",
                                 "dist", ".pytest_cache", ".hypothesis", "*.tfevents.*")


def run(argv, cwd, env, timeout=900):
    proc = subprocess.run([str(a) for a in argv], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, f"{argv}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return proc


@pytest.fixture(scope="module")
def dists(tmp_path_factory):
    pytest.importorskip("build")
    root = tmp_path_factory.mktemp("dist")
    source = root / "source"
    shutil.copytree(REPO, source, ignore=IGNORED)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    # --no-isolation: build with this environment's setuptools (no download); the wheel is
    # built from the sdist, so a file missing from the sdist fails here
    run([sys.executable, "-m", "build", "--no-isolation", "--outdir", root / "out", source], root, env)
    (wheel,) = (root / "out").glob("snake_env-*.whl")
    (sdist,) = (root / "out").glob("snake_env-*.tar.gz")
    return wheel, sdist


def test_wheel_top_level_is_only_snake_env(dists):
    wheel, sdist = dists
    names = zipfile.ZipFile(wheel).namelist()
    top = sorted({name.split("/")[0] for name in names})
    assert [t for t in top if not t.endswith(".dist-info")] == ["snake_env"], top
    assert len(top) == 2 and top[1].startswith("snake_env-") and top[1].endswith(".dist-info")
    for inside in ("snake_env/configs/ppo.yaml", "snake_env/configs/sac.yaml", "snake_env/configs/serpenoid.yaml",
                   "snake_env/controllers/serpenoid.py", "snake_env/agents/search.py", "snake_env/train/train.py",
                   "snake_env/benchmarks/bench.py", "snake_env/envs/snake.py", "snake_env/dynamics/kane.py"):
        assert inside in names, inside
    entry_points = zipfile.ZipFile(wheel).read(f"{top[1]}/entry_points.txt").decode()
    for script in ("snake-train", "snake-eval", "snake-export", "snake-bench", "snake-reproduce"):
        assert f"{script} = snake_env." in entry_points, script
    with tarfile.open(sdist) as archive:
        members = {Path(m).relative_to(Path(m).parts[0]).as_posix() for m in archive.getnames() if "/" in m}
    assert {"pyproject.toml", "setup.py", "README.md", "configs/ppo.yaml", "agents/search.py",
            "snake_env/controllers/serpenoid.py", "train/train.py"} <= members


def test_wheel_in_fresh_venv_trains_and_evaluates_from_any_directory(dists, tmp_path):
    wheel, _ = dists
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", venv], check=True, timeout=300)
    python = venv / "bin" / "python"
    purelib = Path(run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], tmp_path,
                       None).stdout.strip())
    # every site directory this interpreter sees (its .pth files, e.g. an editable install's finder, are not run)
    here = [p for p in sys.path if Path(p).name in ("site-packages", "dist-packages")]
    here += [sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]]
    (purelib / "parent_packages.pth").write_text("\n".join(dict.fromkeys(here)) + "\n")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env.update(OMP_NUM_THREADS="1", NUMBA_NUM_THREADS="1", MPLBACKEND="Agg")
    run([python, "-m", "pip", "install", "--no-index", "--no-build-isolation", wheel], tmp_path, env)
    work = tmp_path / "elsewhere"  # no configs/ here: the shipped ones must be found
    work.mkdir()
    probe = run([python, "-c", "import importlib.util as u, snake_env.train.config as c; "
                               "print(c.__file__); print(c.default_config_path('ppo')); "
                               "print(u.find_spec('agents'), u.find_spec('train'), u.find_spec('benchmarks'))"],
                work, env).stdout.splitlines()
    assert probe[0].startswith(str(purelib)) and probe[1].startswith(str(purelib / "snake_env" / "configs"))
    assert probe[2] == "None None None"  # no top-level agents/train/benchmarks
    bin_dir = venv / "bin"
    run([bin_dir / "snake-train", "--algo", "ppo", "--env", newest_id("Snake3"), "--total-timesteps", "128",
         "--n-envs", "2", "--run-dir", "run", "--set", "n_steps=32", "--set", "batch_size=32", "--set", "n_epochs=1",
         "--set", "env_kwargs.max_episode_steps=50", "--set", "eval_freq=64", "--set", "n_eval_episodes=1",
         "--set", "policy_kwargs.net_arch=[8]"], work, env)
    assert (work / "run" / "model.zip").is_file() and (work / "run" / "vecnormalize.pkl").is_file()
    assert "gae_lambda: 0.95" in (work / "run" / "config.yaml").read_text()  # the shipped ppo.yaml entry
    out = run([bin_dir / "snake-eval", "--baseline", "serpenoid", "--env", newest_id("Snake5"), "--episodes", "1",
               "--max-steps", "50", "--json", "serpenoid.json"], work, env)
    assert "serpenoid baseline (SerpenoidController" in out.stdout and (work / "serpenoid.json").is_file()
    out = run([bin_dir / "snake-eval", "run", "--episodes", "1"], work, env)
    assert "PPO" in out.stdout
