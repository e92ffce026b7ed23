"""The measurements of ``snake-bench``, one function per section.

Every function returns plain JSON-ready data (dicts, lists, floats) and takes
its sizes as arguments, so ``--quick`` and the full run differ only in the
numbers passed in. Speeds are the best of ``rounds`` repeats (the timeit
convention: on a shared machine the fastest repeat is the one least slowed by
other processes); every repeat is kept in the JSON. Snake and MuJoCo Swimmer
are measured in the same process, interleaved round by round, so both see the
same machine load.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import numpy as np

SWIMMER_ID = "Swimmer-v5"


def snake_id(n_links: int) -> str:
    """The newest forward id for n links (the default physics: servo motors, finite grip)."""
    from snake_env.tasks.forward import ForwardTask

    return f"snake_env/Snake{n_links}-v{ForwardTask.version}"


def mujoco_available() -> tuple[bool, str]:
    """(True, "") if gym.make("Swimmer-v5") works, else (False, the reason)."""
    try:
        import gymnasium as gym

        env = gym.make(SWIMMER_ID)
        env.close()
        return True, ""
    except Exception as exc:  # noqa: BLE001 - any failure means "not measurable", with the reason kept
        return False, f"{type(exc).__name__}: {exc}"


# --------------------------------------------------------------------------- single env
def _fixed_actions(space, count: int, seed: int) -> list:
    """Pre-drawn actions so sampling cost is not part of the step time."""
    rng = np.random.default_rng(seed)
    low, high = space.low, space.high
    return [rng.uniform(low, high).astype(space.dtype) for _ in range(count)]


def _time_single_env(env, actions, sample_time: float) -> float:
    """Steps per second of ``env.step`` over about ``sample_time`` seconds
    (resets at episode end are part of the time, as in training)."""
    env.reset(seed=0)
    n_actions = len(actions)
    steps = 0
    start = time.perf_counter()
    deadline = start + sample_time
    while True:
        for i in range(100):  # check the clock every 100 steps only
            _, _, terminated, truncated, _ = env.step(actions[i % n_actions])
            if terminated or truncated:
                env.reset()
        steps += 100
        now = time.perf_counter()
        if now >= deadline:
            return steps / (now - start)


def single_env_speeds(env_ids, sample_time: float, rounds: int) -> dict:
    """Single-env steps/s of each id, made with ``gym.make`` (default wrappers
    included, as users get them), interleaved over ``rounds``."""
    import gymnasium as gym

    import snake_env  # noqa: F401 - registers the ids

    envs = {env_id: gym.make(env_id) for env_id in env_ids}
    actions = {env_id: _fixed_actions(env.action_space, 256, seed=1) for env_id, env in envs.items()}
    for env_id, env in envs.items():  # warm-up: compile/load kernels, allocate
        _time_single_env(env, actions[env_id], 0.1 * sample_time)
    samples = {env_id: [] for env_id in env_ids}
    for _ in range(rounds):
        for env_id, env in envs.items():
            samples[env_id].append(_time_single_env(env, actions[env_id], sample_time))
    for env in envs.values():
        env.close()
    return {env_id: {"steps_per_s": max(s), "samples": s, "sample_time_s": sample_time} for env_id, s in samples.items()}


# --------------------------------------------------------------------------- vector env
def vector_env_speeds(n_links: int, num_envs_list, sample_time: float, rounds: int, env_kwargs=None) -> dict:
    """env-steps/s of ``gym.make_vec(..., vectorization_mode="vector_entry_point")``
    at each number of envs, each sample about ``sample_time`` seconds (autoreset included)."""
    import gymnasium as gym

    import snake_env  # noqa: F401

    results = {}
    for num_envs in num_envs_list:
        envs = gym.make_vec(snake_id(n_links), num_envs=num_envs, vectorization_mode="vector_entry_point",
                            **(env_kwargs or {}))
        rng = np.random.default_rng(2)
        space = envs.action_space
        actions = [rng.uniform(space.low, space.high).astype(space.dtype) for _ in range(8)]
        envs.reset(seed=0)
        for i in range(3):  # warm-up
            envs.step(actions[i % 8])
        samples = []
        batch_steps = []
        for _ in range(rounds):
            steps = 0
            start = time.perf_counter()
            while True:
                envs.step(actions[steps % 8])
                steps += 1
                now = time.perf_counter()
                if now - start >= sample_time:
                    break
            samples.append(num_envs * steps / (now - start))
            batch_steps.append(steps)
        envs.close()
        results[str(num_envs)] = {"env_steps_per_s": max(samples), "samples": samples, "batch_steps": batch_steps}
    return results


# --------------------------------------------------------------------------- wheel models
def wheel_model_speeds(links, num_envs: int, sample_time: float, rounds: int) -> dict:
    """The vector env's env-steps/s on the no-slip wheels (``wheel_model="no_slip"``, v3's) and on the default
    sliding wheels at each n of ``links``, ``num_envs`` envs: what the sliding model costs."""
    results = {}
    for n_links in links:
        row = {}
        for model in ("no_slip", "sliding"):
            speeds = vector_env_speeds(n_links, [num_envs], sample_time, rounds, {"wheel_model": model})
            row[model] = speeds[str(num_envs)]["env_steps_per_s"]
        row["cost_ratio"] = row["no_slip"] / row["sliding"]
        results[str(n_links)] = row
    return {"num_envs": num_envs, "links": results}


# --------------------------------------------------------------------------- udot scaling
def _time_call(fn, min_time: float) -> float:
    """Seconds per call: repeat until ``min_time`` has elapsed, best of 3 such blocks."""
    fn()
    best = float("inf")
    for _ in range(3):
        calls = 0
        start = time.perf_counter()
        while True:
            fn()
            calls += 1
            elapsed = time.perf_counter() - start
            if elapsed >= min_time:
                break
        best = min(best, elapsed / calls)
    return best


def udot_scaling(n_list, min_time: float, max_call_time: float) -> dict:
    """Seconds per ``model.udot(q, u, torques, method)`` for one float64 state,
    for every method the model accepts, at each n in ``n_list``.

    Besides the public ``model.udot`` (input checks included), two series show
    where the time goes: ``kane_kernel`` (the compiled sweep alone) and
    ``kane_numpy`` (the vectorised numpy sweep, the float32 path). A method
    stops growing n once one call takes longer than ``max_call_time`` (s), so
    the O(n^2) and O(n^3) formulations stay quick.
    """
    from snake_env.dynamics import METHODS, SnakeModel, compiled, kane

    rng = np.random.default_rng(3)
    series = {}
    skipped = {}
    probe = SnakeModel(3)
    methods = []
    for method in METHODS:
        try:
            probe.udot(np.zeros(5), np.zeros(2), np.zeros(2), method=method)
            methods.append(method)
        except ValueError as exc:
            skipped[method] = str(exc)

    def state(n):
        q = np.concatenate([np.cumsum(rng.uniform(-0.3, 0.3, n)), [0.0, 0.0]])
        return q, np.array([0.2, 0.1]), rng.normal(size=n - 1) * 0.1

    runners = {method: (lambda model, q, u, T, method=method: model.udot(q, u, T, method=method)) for method in methods}
    runners["kane_numpy"] = lambda model, q, u, T: kane.udot_sweep(model, q, u, T)

    def kernel(model, q, u, T, du=np.empty((1, 2))):
        compiled.udot_batch(*model.parameters(), q[None], u[None], T[None], du)

    runners["kane_kernel"] = kernel
    for name, run in runners.items():
        times = {}
        for n in n_list:
            model = SnakeModel(n)
            q, u, T = state(n)
            seconds = _time_call(lambda: run(model, q, u, T), min_time)
            times[str(n)] = seconds
            if seconds > max_call_time:
                break
        series[name] = times
    return {"seconds_per_call": series, "skipped_methods": skipped, "n": list(n_list)}


# --------------------------------------------------------------------------- PPO
def _ppo_run(env, total_timesteps: int, ppo_kwargs: dict) -> float:
    """Wall-clock SB3 PPO fps: collected timesteps over the time of ``learn``
    (rollouts and gradient updates both included)."""
    from stable_baselines3 import PPO

    model = PPO("MlpPolicy", env, seed=0, device="cpu", verbose=0, **ppo_kwargs)
    start = time.perf_counter()
    model.learn(total_timesteps=total_timesteps)
    elapsed = time.perf_counter() - start
    return model.num_timesteps / elapsed


def ppo_speeds(snake_links: int, snake_num_envs: int, iterations: int, rounds: int, ppo_kwargs: dict,
               with_swimmer: bool, torch_threads: int = 1) -> dict:
    """SB3 PPO training fps on the batched snake env (SnakeSB3VecEnv) and on a
    single Swimmer-v5 env, same PPO settings, interleaved round by round.

    Each run is ``iterations`` full PPO iterations (rollout of n_steps per env
    plus n_epochs of updates), so fps counts training time as SB3 users see it.
    Torch runs on ``torch_threads`` threads for both (1 by default: for SB3's
    small MLPs on a 2-core machine, torch's intra-op threads only contend with
    each other and with the env; with 2 threads under load we measured PPO
    50x slower).
    """
    import gymnasium as gym
    import torch

    from snake_env.agents.sb3_vec_env import SnakeSB3VecEnv

    previous_threads = torch.get_num_threads()
    torch.set_num_threads(torch_threads)
    try:
        n_steps = ppo_kwargs.get("n_steps", 2048)
        snake_env = SnakeSB3VecEnv(snake_id(snake_links), num_envs=snake_num_envs)
        snake_env.reset()  # warm-up: load the compiled kernels before any timing
        snake_env.step(np.zeros((snake_num_envs,) + snake_env.action_space.shape, snake_env.action_space.dtype))
        samples = {"snake": [], "swimmer": []}
        for _ in range(rounds):
            samples["snake"].append(_ppo_run(snake_env, iterations * n_steps * snake_num_envs, ppo_kwargs))
            if with_swimmer:
                swimmer = gym.make(SWIMMER_ID)
                samples["swimmer"].append(_ppo_run(swimmer, iterations * n_steps, ppo_kwargs))
                swimmer.close()
        snake_env.close()
    finally:
        torch.set_num_threads(previous_threads)
    out = {
        "snake": {"env": snake_id(snake_links), "num_envs": snake_num_envs, "fps": max(samples["snake"]),
                  "samples": samples["snake"]},
        "ppo_kwargs": ppo_kwargs, "iterations": iterations, "torch_threads": torch_threads,
    }
    if with_swimmer:
        out["swimmer"] = {"env": SWIMMER_ID, "num_envs": 1, "fps": max(samples["swimmer"]), "samples": samples["swimmer"]}
    return out


# --------------------------------------------------------------------------- subprocess measurements
def _run_child(code: str, timeout: float, extra_env: dict | None = None) -> dict:
    """Run ``code`` in a fresh interpreter (with ``extra_env`` set); it prints one JSON line last."""
    env = {**os.environ, **(extra_env or {})}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout, env=env)
    if proc.returncode != 0:
        raise RuntimeError(f"child process failed ({proc.returncode}): {proc.stderr.strip()[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


# VmHWM (the kernel's peak RSS of this process), not getrusage's ru_maxrss:
# Linux carries ru_maxrss across fork + exec, so a child of a big parent
# (torch loaded) would report the parent's size.
MEMORY_CHILD = """
import json
def status_mb(field):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024.0
import gymnasium as gym, numpy as np, snake_env
base = status_mb("VmRSS")
envs = gym.make_vec("{env_id}", num_envs={num_envs}, vectorization_mode="vector_entry_point")
envs.reset(seed=0)
action = np.zeros(envs.action_space.shape, dtype=envs.action_space.dtype)
for _ in range({steps}):
    envs.step(action)
after_steps = status_mb("VmRSS")  # read before the peak, which can only have grown since
print(json.dumps({{"peak_rss_mb": status_mb("VmHWM"), "rss_after_imports_mb": base,
                  "rss_after_steps_mb": after_steps}}))
"""


def vector_env_memory(n_links: int, num_envs: int, steps: int) -> dict:
    """Peak resident memory (MiB) of a fresh process holding the vector env
    (imports, env, reset and ``steps`` steps), and its RSS after the imports alone."""
    out = _run_child(MEMORY_CHILD.format(env_id=snake_id(n_links), num_envs=num_envs, steps=steps), timeout=600)
    out.update({"env": snake_id(n_links), "num_envs": num_envs, "steps": steps})
    return out


STARTUP_CHILD = """
import json, time
start = time.perf_counter()
import gymnasium as gym
import snake_env
env = gym.make("{env_id}", **{env_kwargs!r})
env.reset(seed=0)
env.action_space.seed(0)  # the same first actions every run (whether a first step refines moves the figure)
env.step(env.action_space.sample())
single = time.perf_counter() - start
envs = gym.make_vec("{env_id}", num_envs=32, vectorization_mode="vector_entry_point", **{env_kwargs!r})
envs.reset(seed=0)
envs.action_space.seed(0)
envs.step(envs.action_space.sample())
vector = time.perf_counter() - start
from snake_env.physics import stepping
stepping.await_background_compile(until_exit=True)  # every kernel compiled beside this process: all cached now
print(json.dumps({{"import_and_first_step_s": single, "plus_vector_first_step_s": vector,
                  "all_kernels_s": time.perf_counter() - start}}))
"""


def startup_time(n_links: int, runs: int, cold: bool = True, env_kwargs: dict | None = None) -> dict:
    """Seconds from a fresh interpreter to the first env step (imports, numba
    cache loads, make, reset, step) and then a first 32-env vector step. With
    ``cold``, every run uses one new NUMBA_CACHE_DIR: the first run starts from an
    empty cache (a new install's cold start, ``cold_start_s``), the later ones are
    the "once caches exist" figure; without it the runs use the current cache. Each run ends when the
    background compile it started (``stepping.compile_in_background``) has finished too
    (``all_kernels_s``), so the next run finds every kernel cached. ``env_kwargs``: the envs' settings (e.g. the
    wheel model, whose kernels differ)."""
    import tempfile

    code = STARTUP_CHILD.format(env_id=snake_id(n_links), env_kwargs=dict(env_kwargs or {}))
    samples = []
    wall = []
    with tempfile.TemporaryDirectory(prefix="snake_bench_numba_") as cache:
        extra_env = {"NUMBA_CACHE_DIR": cache} if cold else None
        for _ in range(runs):
            start = time.perf_counter()
            samples.append(_run_child(code, timeout=900, extra_env=extra_env))
            wall.append(time.perf_counter() - start)
    warm = samples[1:] if len(samples) > 1 else samples
    return {
        "env": snake_id(n_links),
        "env_kwargs": dict(env_kwargs or {}),
        "first_run": samples[0],
        "cold_start_s": samples[0]["plus_vector_first_step_s"] if cold else None,
        "import_and_first_step_s": min(s["import_and_first_step_s"] for s in warm),
        "process_wall_s": min(wall[1:] if len(wall) > 1 else wall),
        "samples": samples,
    }
