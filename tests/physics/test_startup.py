"""The first run compiles the physics kernels: it says so once on stderr, then works; the next
process reuses numba's on-disk cache and says nothing. A fresh process with an empty
NUMBA_CACHE_DIR is a new install's first step (no timing asserted: docs/benchmarks.md times it)."""

import os
import subprocess
import sys

import pytest

from snake_env.physics.stepping import COMPILE_NOTICE

FIRST_STEPS = ("import gymnasium as gym, numpy as np, snake_env\n"
               "env = gym.make('snake_env/Snake5-v2'); env.reset(seed=0)\n"
               "obs, *_ = env.step(env.action_space.sample()); assert np.all(np.isfinite(obs))\n"
               "envs = gym.make_vec('snake_env/Snake5-v2', num_envs=32, vectorization_mode='vector_entry_point')\n"
               "envs.reset(seed=0); envs.step(envs.action_space.sample())\n"
               "print('stepped')\n")


@pytest.mark.slow
def test_first_run_announces_the_compile_once_and_the_second_is_silent(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba_cache")}
    runs = [subprocess.run([sys.executable, "-c", FIRST_STEPS], capture_output=True, text=True, env=env,
                           timeout=900) for _ in range(2)]
    for run in runs:
        assert run.returncode == 0, run.stderr[-2000:]
        assert run.stdout.strip() == "stepped"
    assert runs[0].stderr.count(COMPILE_NOTICE) == 1
    assert COMPILE_NOTICE not in runs[1].stderr
    assert any((tmp_path / "numba_cache").rglob("*.nbi"))  # the cache went where NUMBA_CACHE_DIR says
