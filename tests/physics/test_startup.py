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


# The kernels for the rows the lane kernel leaves (refinement, the per-snake path) compile in a second
# process started when the env is made; this process then loads them from the cache instead of compiling.
BACKGROUND = ("import gymnasium as gym, numpy as np, snake_env\n"
              "from snake_env.physics import stepping\n"
              "env = gym.make('snake_env/Snake5-v3'); env.reset(seed=0)\n"
              "assert stepping._background is not None, 'no background compile started'\n"
              "stepping.await_background_compile()\n"
              "p = env.unwrapped.params\n"
              "q = np.zeros((1, 7)); u = np.zeros((1, 2)); torques = np.zeros((1, 4))\n"
              "obs, aux = np.empty((1, p.obs_size)), np.empty((1, stepping.AUX_SIZE))\n"
              "forces, scale = np.empty((1, 5)), np.empty(1)\n"
              "stepping.step_inplace(p, q, u, torques, obs, aux, forces, scale)\n"
              "aux[0, stepping.AUX_FAILED] = stepping.FAIL_FOLD  # a failed lane attempt, to be undone\n"
              "aux[0, stepping.AUX_REFINEMENTS] = stepping.PENDING_LANE\n"
              "stepping._finish_rows(p.kernel_model, p.kernel_settings, q, u, torques, obs, aux, forces, scale)\n"
              "assert aux[0, stepping.AUX_FAILED] == stepping.FAIL_FOLD and aux[0, stepping.AUX_REFINEMENTS] == 0\n"
              "print(sum(stepping._finish_rows._cache_hits.values()), len(stepping._finish_rows._cache_misses))\n")


@pytest.mark.slow
def test_the_rarely_needed_kernels_compile_in_a_background_process(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba_cache")}
    run = subprocess.run([sys.executable, "-c", BACKGROUND], capture_output=True, text=True, env=env, timeout=900)
    assert run.returncode == 0, run.stderr[-2000:]
    hits, misses = map(int, run.stdout.split())
    assert (hits, misses) == (1, 0)  # loaded from what the background process cached, not compiled here


# The default (sliding) wheels: their row kernel, about half of a first step's compile, compiles in a second
# process while this one compiles the reset, observation and task kernels; this process then loads it.
SLIDING_FIRST_STEPS = ("import gymnasium as gym, numpy as np, snake_env\n"
                       "from snake_env.dynamics import sliding_step\n"
                       "from snake_env.physics import stepping\n"
                       "env = gym.make('snake_env/Snake5-v4'); env.reset(seed=0)\n"
                       "assert stepping._background is not None, 'no background compile started'\n"
                       "obs, *_ = env.step(env.action_space.sample()); assert np.all(np.isfinite(obs))\n"
                       "envs = gym.make_vec('snake_env/Snake5-v4', num_envs=32, "
                       "vectorization_mode='vector_entry_point')\n"
                       "envs.reset(seed=0); obs, *_ = envs.step(envs.action_space.sample())\n"
                       "assert np.all(np.isfinite(obs))\n"
                       "kernel = sliding_step.advance_rows\n"
                       "print(sum(kernel._cache_hits.values()), len(kernel._cache_misses))\n")


@pytest.mark.slow
def test_the_sliding_row_kernel_compiles_in_a_background_process(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba_cache")}
    run = subprocess.run([sys.executable, "-c", SLIDING_FIRST_STEPS], capture_output=True, text=True, env=env,
                         timeout=900)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stderr.count(COMPILE_NOTICE) == 1
    hits, misses = map(int, run.stdout.split())
    assert (hits, misses) == (1, 0)  # loaded from what the background process cached, not compiled here


def test_one_background_compile_at_a_time():
    """A background compile waits while another holds the cache's lock (SubprocVecEnv workers each start
    one), then runs (loading what the other cached; here the cache is warm) and exits cleanly."""
    import fcntl
    import time

    from snake_env.physics import background_compile

    with open(background_compile.lock_path(), "a") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        child = subprocess.Popen([sys.executable, "-m", "snake_env.physics.background_compile"],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        time.sleep(3.0)
        assert child.poll() is None, child.communicate()  # still waiting for the lock
    out, err = child.communicate(timeout=600)
    assert child.returncode == 0, err[-2000:]


def test_awaiting_a_background_compile_that_exits_without_saying_done_returns():
    """The parent waits on the child's pipe; a child that exits without writing (a crash) closes it, and
    the wait returns at once (the kernels then compile in this process when first needed)."""
    from snake_env.physics import stepping

    read, write = os.pipe()
    child = subprocess.Popen([sys.executable, "-c", "pass"], pass_fds=(write,))
    os.close(write)
    saved = stepping._background, stepping._background_done
    stepping._background, stepping._background_done = child, read
    try:
        stepping.await_background_compile()
        assert stepping._background is None and stepping._background_done is None
    finally:
        stepping._background, stepping._background_done = saved
    assert child.wait(timeout=60) == 0


def test_a_lock_not_waited_for_is_none_while_another_holds_it():
    """The sliding wheels' exact-solve kernel compiles after the child has said "done", under a lock of its own
    that a second child does not wait for (the first one caches the kernel)."""
    import fcntl

    from snake_env.physics import background_compile

    with open(background_compile.lock_path() + ".exact", "a") as held:
        fcntl.flock(held, fcntl.LOCK_EX)
        assert background_compile.hold_the_lock(".exact", wait=False) is None
    again = background_compile.hold_the_lock(".exact", wait=False)
    assert again is not None
    again.close()
