"""Where a sliding-wheel vector step's time goes (the profile of docs/benchmarks.md, "The sliding step
against the CPU's limit").

    python -m snake_env.benchmarks.sliding_step_profile [--env snake_env/Snake5-v4] [--envs 1024] [--steps 40]

Steps a ``gym.make_vec`` vector env under uniform random actions with timers around the sliding step's
compiled calls (the step's start, the row kernel ``sliding_step.ADVANCE_ROWS``, the verdicts, the step's end), then replays
the row kernel on the last step's rows with the env step cut into 1, 2, 5, 10, 20 and 40 substeps of
the same total time, which splits its time into a cost per substep and a cost per row. Times in
microseconds per env-step (row); run it on an idle machine, timings are not asserted anywhere.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

REPLAY_SUBSTEPS = (1, 2, 5, 10, 20, 40)
REPEATS = 5
WARMUP_STEPS = 10


class _Timed:
    """A callable that times the calls of ``fn`` into ``totals[name]``; while ``keep`` is set it also keeps a copy
    of the arguments of its last full-batch call (outside the timed steps: the copy is not the step's work)."""

    def __init__(self, fn, name, totals, batch):
        self.fn, self.name, self.totals, self.batch = fn, name, totals, batch
        self.keep = False
        self.last_args = None

    def __call__(self, *args):
        if self.keep and len(args[-6]) == self.batch:  # every row: the step's first call, not a refinement
            self.last_args = _copies(args)
        start = time.perf_counter()
        out = self.fn(*args)
        self.totals[self.name] = self.totals.get(self.name, 0.0) + time.perf_counter() - start
        return out


def _copies(args) -> list:
    """The arguments with every array copied (a kernel call changes its arrays in place)."""
    return [a.copy() if isinstance(a, np.ndarray) else a for a in args]


def profile(env_id: str, num_envs: int, steps: int) -> dict:
    import gymnasium as gym

    import snake_env  # noqa: F401  (registers the ids)
    from snake_env.dynamics import sliding_step
    from snake_env.physics import sliding_wheels

    envs = gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point")
    physics = getattr(getattr(envs.unwrapped, "_batch", None), "physics", None)
    if not isinstance(physics, sliding_wheels.SlidingWheelPhysics):
        envs.close()
        raise ValueError(f"--env {env_id!r}: needs the sliding wheels (v4 or newer, wheel_model='sliding')")
    rng = np.random.default_rng(0)
    envs.reset(seed=0)
    for _ in range(WARMUP_STEPS):  # compiled and off the start states
        envs.step(rng.uniform(-1.0, 1.0, envs.action_space.shape))
    totals: dict[str, float] = {}
    kernels = sliding_step.ADVANCE_ROWS
    row_kernel = _Timed(kernels[physics.method], "row kernel", totals, num_envs)
    begin, verdicts, finish = sliding_wheels._begin, sliding_wheels._verdicts, sliding_wheels._finish
    try:
        sliding_step.ADVANCE_ROWS = tuple(row_kernel if i == physics.method else _Timed(k, "exact solve", totals, 0)
                                          for i, k in enumerate(kernels))
        sliding_wheels._begin = _Timed(begin, "step's start", totals, 0)
        sliding_wheels._verdicts = _Timed(verdicts, "verdicts", totals, 0)
        sliding_wheels._finish = _Timed(finish, "step's end", totals, 0)
        start = time.perf_counter()
        for _ in range(steps):
            envs.step(rng.uniform(-1.0, 1.0, envs.action_space.shape))
        wall = time.perf_counter() - start
        per_step = 1e6 / (steps * num_envs)
        result = {"env": env_id, "envs": num_envs, "substeps": int(physics.substeps),
                  "env step (us)": wall * per_step, **{f"{k} (us)": v * per_step for k, v in totals.items()}}
        row_kernel.keep = True  # one more step, untimed, for the row kernel's arguments to replay
        envs.step(rng.uniform(-1.0, 1.0, envs.action_space.shape))
    finally:
        sliding_step.ADVANCE_ROWS = kernels
        sliding_wheels._begin, sliding_wheels._verdicts, sliding_wheels._finish = begin, verdicts, finish
        envs.close()
    args = row_kernel.last_args
    h, substeps = args[-8], args[-7]
    replay = {}
    for count in REPLAY_SUBSTEPS:  # the same step time cut into `count` substeps
        best = float("inf")
        for _ in range(REPEATS):
            call = _copies(args)
            call[-8], call[-7] = h * substeps / count, np.full_like(substeps, count)
            start = time.perf_counter()
            kernels[physics.method](*call)
            best = min(best, time.perf_counter() - start)
        replay[count] = best * 1e6 / num_envs
    slope, intercept = np.polyfit(list(replay), list(replay.values()), 1)
    result.update({"replay (us per row)": replay, "per substep (us)": slope, "per row (us)": intercept})
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m snake_env.benchmarks.sliding_step_profile", description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="snake_env/Snake5-v4", help="a sliding-wheel id, v4 or newer (default: %(default)s)")
    parser.add_argument("--envs", type=int, default=1024, help="sub-envs of the vector env (default: %(default)s)")
    parser.add_argument("--steps", type=int, default=40, help="timed vector steps (default: %(default)s)")
    args = parser.parse_args(argv)
    for name in ("envs", "steps"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} must be an integer >= 1, got {getattr(args, name)}")
    try:
        result = profile(args.env, args.envs, args.steps)
    except Exception as exc:  # an unknown or unsuitable id or kwarg: one line, exit 2
        from snake_env.train.config import first_line

        message = first_line(exc)
        if not message.startswith("--env"):
            message = f"--env {args.env!r}: {message}"
        print(f"sliding_step_profile: error: {message}", file=sys.stderr)
        return 2
    for key, value in result.items():
        if isinstance(value, dict):
            print(f"{key}: " + ", ".join(f"{k}: {v:.2f}" for k, v in value.items()))
        else:
            print(f"{key}: {value:.2f}" if isinstance(value, float) else f"{key}: {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
