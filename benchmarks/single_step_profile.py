"""Where one single-env step's time goes: the step through ``gym.make``'s wrappers, then each layer
below it down to the compiled kernel alone (the profile of docs/benchmarks.md).

    python -m snake_env.benchmarks.single_step_profile [--env snake_env/Snake3-v3] [--calls 20000]

Every part is timed on the same state (restored before each call, its cost taken out), as the
fastest of 7 blocks of ``--calls`` calls, in microseconds. The parts are nested: each row includes
the rows below it that it calls. Run it on an idle machine; timings are not asserted anywhere.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

BLOCKS = 7


def best_time(fn, calls: int) -> float:
    """The fastest of BLOCKS blocks of ``calls`` calls of ``fn``, per call (us)."""
    best = float("inf")
    for _ in range(BLOCKS):
        start = time.perf_counter()
        for _ in range(calls):
            fn()
        best = min(best, (time.perf_counter() - start) / calls * 1e6)
    return best


def profile(env_id: str, calls: int) -> dict[str, float]:
    import gymnasium as gym

    import snake_env  # noqa: F401  (registers the ids)
    from snake_env.envs.core import action_array
    from snake_env.physics import stepping
    from snake_env.tasks.base import common_step_values

    env = gym.make(env_id)
    env.reset(seed=0)
    single = env.unwrapped
    batch = single._batch
    action = np.zeros(env.action_space.shape, env.action_space.dtype)
    checked = action_array(action, action.shape)
    q0, u0 = batch.q.copy(), batch.u.copy()

    def restore():
        batch.q[:] = q0
        batch.u[:] = u0

    params = batch.physics.params
    kernel_args = (params.kernel_model, params.kernel_settings, batch.q, batch.u, batch.torques, batch.physics_obs,
                   batch.aux, batch.wheel_force, batch.traction_scale)
    restoring = best_time(restore, calls)
    stateful = {
        "the whole step through gym.make's wrappers": lambda: (restore(), env.step(action)),
        "SnakeEnv.step": lambda: (restore(), single.step(action)),
        "SnakeBatch.step_first (the info of row 0)": lambda: (restore(), batch.step_first(checked)),
        "SnakeBatch._advance (physics, reward, costs, wheel info)": lambda: (restore(), batch._advance(checked[None], True)),
        "the physics step (bound to the batch's buffers)": lambda: (restore(), batch._step_physics()),
        "the compiled kernel alone, through numba's dispatcher": lambda: (restore(), stepping._step_lanes(*kernel_args)),
    }
    rows = {name: best_time(fn, calls) - restoring for name, fn in stateful.items()}
    rows["the task's reward"] = best_time(lambda: batch.task.evaluate(batch.config, batch._context, batch.task_state),
                                          calls)
    rows["action_array (the action's float64 copy; the clip is the step's)"] = best_time(
        lambda: action_array(action, action.shape), calls)
    rows["the common info values (and the wheels' slip), bound"] = best_time(batch._common_step_values, calls)
    rows["the same through numba's dispatcher"] = best_time(
        lambda: common_step_values(batch._context, batch.common_values, batch.failed, batch._wheels), calls)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m snake_env.benchmarks.single_step_profile",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="snake_env/Snake3-v3", help="a forward id (default: %(default)s)")
    parser.add_argument("--calls", type=int, default=20000, help="calls per timing block (default: %(default)s)")
    args = parser.parse_args(argv)
    if args.calls < 1:
        parser.error(f"--calls must be a positive integer, got {args.calls}")
    try:
        rows = profile(args.env, args.calls)
    except Exception as exc:  # an unknown id or kwarg: one line, exit 2
        from snake_env.train.config import first_line

        print(f"single_step_profile: error: --env {args.env!r}: {first_line(exc)}", file=sys.stderr)
        return 2
    print("| part of one step | us |")
    print("|---|---|")
    for name, value in rows.items():
        print(f"| {name} | {value:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
