"""How much per-step action noise a searched serpenoid gait survives (docs/learning.md, note 4).

    python -m snake_env.benchmarks.serpenoid_noise --env snake_env/Snake12-v2

Rows: the saved gait of configs/serpenoid.yaml as env torques (its own PD),
plus Gaussian noise of std sigma (units of max_torque) on every action; and
the same gait written as joint targets through the opt-in wrappers
(``joint_target`` + ``phase_observation`` at the gait's frequency), i.e. the
policy that is linear in the clock features, plus noise of std sigma (units
of the target range). Mean forward CM speed (m/s) over ``--envs`` envs and
``--steps`` env steps, one seed.
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np


def speeds(env_id: str, sigmas, envs: int, steps: int, seed: int, kp: float, kd: float) -> list[tuple]:
    import gymnasium as gym

    import snake_env  # noqa: F401
    from snake_env.agents.search import env_geometry
    from snake_env.controllers import SerpenoidController, load_params
    from snake_env.wrappers import wrap_vector_env

    params, env_kwargs = load_params(env_id)
    n, max_torque, dt, include_position = env_geometry(env_id, env_kwargs)
    joints = np.arange(n - 1)
    rows = []
    for sigma in sigmas:
        rng = np.random.default_rng(seed)
        venv = gym.make_vec(env_id, num_envs=envs, vectorization_mode="vector_entry_point", **env_kwargs)
        controller = SerpenoidController(params, n, max_torque, dt, num_envs=envs, include_position=include_position)
        obs, _ = venv.reset(seed=seed)
        total = 0.0
        for _ in range(steps):
            action = np.clip(controller.act(obs) + sigma * rng.standard_normal((envs, n - 1)), -1, 1)
            obs, _, _, _, info = venv.step(action.astype(np.float32))
            total += float(np.mean(info["x_velocity"]))
        torque_speed = total / steps
        venv.close()
        venv = wrap_vector_env(gym.make_vec(env_id, num_envs=envs, vectorization_mode="vector_entry_point", **env_kwargs),
                               {"joint_target": {"kp": kp, "kd": kd},
                                "phase_observation": {"frequencies": [params.frequency]}})
        target_range = venv.pd.target_range if hasattr(venv, "pd") else venv.env.pd.target_range
        obs, _ = venv.reset(seed=seed)
        total = 0.0
        for _ in range(steps):
            sin, cos = obs[:, -2:-1], obs[:, -1:]
            # alpha sin(w t + i beta) = alpha (cos(i beta) sin(w t) + sin(i beta) cos(w t)): linear in the clock
            target = params.amplitude * (sin * np.cos(joints * params.phase_lag) + cos * np.sin(joints * params.phase_lag))
            action = np.clip(target / target_range + sigma * rng.standard_normal(target.shape), -1, 1)
            obs, _, _, _, info = venv.step(action.astype(np.float32))
            total += float(np.mean(info["x_velocity"]))
        venv.close()
        rows.append((sigma, torque_speed, total / steps))
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m snake_env.benchmarks.serpenoid_noise", description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", dest="env_id", default="snake_env/Snake12-v2")
    parser.add_argument("--sigmas", type=float, nargs="+", default=[0.0, 0.05, 0.135, 0.37, 1.0])
    parser.add_argument("--envs", type=int, default=8)
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--kp", type=float, default=1.0, help="joint_target PD stiffness (N m/rad)")
    parser.add_argument("--kd", type=float, default=0.05, help="joint_target PD damping (N m s/rad)")
    args = parser.parse_args(argv)
    if args.envs < 1 or args.steps < 1 or any(not (s >= 0 and math.isfinite(s)) for s in args.sigmas):
        parser.exit(2, f"{parser.prog}: error: --envs and --steps must be >= 1 and --sigmas finite >= 0\n")
    try:
        rows = speeds(args.env_id, args.sigmas, args.envs, args.steps, args.seed, args.kp, args.kd)
    except ValueError as exc:
        parser.exit(2, f"{parser.prog}: error: {str(exc).splitlines()[0]}\n")
    print(f"{args.env_id}: mean forward speed (m/s), {args.envs} envs x {args.steps} steps, seed {args.seed}")
    print("| noise std | serpenoid PD (torque noise) | serpenoid as joint targets + clock (target noise) |")
    print("|---|---|---|")
    for sigma, torque_speed, target_speed in rows:
        print(f"| {sigma:g} | {torque_speed:.3f} | {target_speed:.3f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
