"""A read-only install (the package directory not writable): numba caches the compiled kernels in the
user's cache directory instead, and the env steps. Needs a read-only bind mount (root); skipped where
the machine does not allow one."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import snake_env

CHILD = ("import gymnasium as gym, numpy as np, snake_env\n"
         "print(snake_env.__file__)\n"
         "env = gym.make('snake_env/Snake3-v2'); env.reset(seed=0)\n"
         "obs, *_ = env.step(env.action_space.sample()); assert np.all(np.isfinite(obs))\n")


@pytest.fixture
def read_only_package(tmp_path):
    source = tmp_path / "source"
    shutil.copytree(Path(snake_env.__file__).parent, source / "snake_env",
                    ignore=shutil.ignore_patterns("__pycache__", "*.nbi", "*.nbc"))
    mount = tmp_path / "mounted"
    mount.mkdir()
    done = subprocess.run(["mount", "--bind", str(source), str(mount)], capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"no bind mount here: {done.stderr.decode().strip()}")
    try:
        if subprocess.run(["mount", "-o", "remount,bind,ro", str(mount)], capture_output=True).returncode != 0:
            pytest.skip("no read-only remount here")
        yield mount
    finally:
        subprocess.run(["umount", str(mount)], capture_output=True)


@pytest.mark.slow
def test_read_only_package_caches_in_the_user_cache_directory(read_only_package, tmp_path):
    with pytest.raises(OSError):
        (read_only_package / "snake_env" / "probe").write_text("x")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env.update(PYTHONPATH=str(read_only_package), XDG_CACHE_HOME=str(tmp_path / "user_cache"))
    run = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, env=env, timeout=900,
                         cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.splitlines()[0].startswith(str(read_only_package))  # the read-only copy was imported
    cached = list((tmp_path / "user_cache").rglob("*.nbi"))
    assert cached, "numba wrote no cache index to the user cache directory"
    assert not list(read_only_package.rglob("*.nbi"))
