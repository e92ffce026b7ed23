"""Settings of the reach task's goal-seeking baseline per number of links.

Goal seeking (:class:`~snake_env.controllers.steering.GoalSeekingController`)
was tuned by hand on Snake5; a longer snake turns less per rad of joint offset
and reached 26 % / 17 % of the goals on n = 8 / 12 with Snake5's settings. Per n:

1. the turning gain G (rad/s of yaw rate per rad of offset gamma) is measured:
   the steered gait runs with a fixed gamma on a few starts, and G is the
   least-squares slope through the origin of the mean yaw rate against gamma;
2. a grid over the steering gain, ``max_offset`` and ``hysteresis`` is scored
   on ``--episodes`` goals, all goals of one setting in one batched vector env
   reset with ``--seed`` (one generator draws every sub-env's start and goal);
3. the ``--top`` settings are re-scored on ``--validate-episodes`` other goals
   (the vector env reset with ``--validate-seed``) and the best of those is
   written to ``baselines.yaml`` (``./configs/baselines.yaml`` when it exists, else the
   shipped file: :func:`snake_env.configfiles.config_path`) under ``reach: {n: ...}`` (atomic write).

Neither goal set is ``snake-eval``'s (single-env episode seeds 0-99), so the
evaluation there is on goals the search did not see.

    python -m snake_env.agents.baseline_search --env snake_env/SnakeReach8-v1
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time

import numpy as np
import yaml

from snake_env.agents.search import env_geometry
from snake_env.atomic import atomic_write_text
from snake_env.configfiles import config_path
from snake_env.controllers.gaits import gait_for_links
from snake_env.controllers.steering import (SETTINGS_FILE, GoalSeekingController, SteeredSerpenoid,
                                            load_baseline_settings, mean_link_angle)

GAINS = (0.12, 0.17, 0.25, 0.35, 0.5)  # rad of offset per rad of bearing
MAX_OFFSETS = (0.1, 0.15, 0.2, 0.25, 0.3)  # rad
HYSTERESES = (1.2, 1.5, 2.0, 2.5, 3.0, 4.0)  # turning radii
TURN_OFFSETS = (0.05, 0.1, 0.15, 0.2)  # rad, fixed gamma of the turning-gain measurement


def _check_reach(env_id: str) -> None:
    import gymnasium as gym

    import snake_env  # noqa: F401

    try:
        task = gym.spec(env_id).kwargs.get("task", "forward")
    except gym.error.Error as exc:
        raise ValueError(f"unknown env id {env_id!r}: {str(exc).splitlines()[0]}") from None
    if task != "reach":
        raise ValueError(f"env must be a reach task id (snake_env/SnakeReach{{n}}-v1), got {env_id!r} (task {task!r})")


def _versions_back(env_id: str) -> int:
    """How many physics versions before the newest the id's physics is (its gaits are that version's)."""
    from snake_env.envs.core import env_config

    return env_config(env_id)[1].versions_back


def _vector_env(env_id: str, num_envs: int, **kwargs):
    import gymnasium as gym

    return gym.make_vec(env_id, num_envs=num_envs, vectorization_mode="vector_entry_point", **kwargs)


def measure_turn_gain(env_id: str, offsets=TURN_OFFSETS, starts: int = 3, steps: int = 375, settle: int = 100,
                      seed: int = 0, gaits=None) -> tuple[float, dict]:
    """(G in rad/s per rad, {gamma: mean yaw rate (rad/s)}): the gait steered by each fixed ``offsets``
    value from ``starts`` random starts, the yaw rate of theta_bar measured after ``settle`` steps."""
    n_links, max_torque, dt, include_position = env_geometry(env_id, {})
    params, _ = gait_for_links(n_links, gaits, _versions_back(env_id))
    gamma = np.repeat(np.asarray(offsets, float), starts)
    env = _vector_env(env_id, len(gamma), terminate_on_success=False)
    try:
        obs, _ = env.reset(seed=seed)
        gait = SteeredSerpenoid(params, n_links, max_torque, dt, num_envs=len(gamma),
                                include_position=include_position)
        headings = []
        for _ in range(steps):
            headings.append(mean_link_angle(obs["observation"], n_links, include_position))
            obs, *_ = env.step(gait.gait_action(obs["observation"], gamma, np.ones(len(gamma))))
    finally:
        env.close()
    headings = np.unwrap(np.asarray(headings), axis=0)
    rates = (headings[-1] - headings[settle]) / ((steps - 1 - settle) * dt)
    gain = float(np.sum(gamma * rates) / np.sum(gamma ** 2))
    return gain, {float(g): float(rates[gamma == g].mean()) for g in offsets}


def success_rate(env_id: str, settings: dict, episodes: int, seed: int, gaits=None) -> tuple[float, float]:
    """(fraction of ``episodes`` goals reached, mean steps of the successes) by goal seeking with ``settings``;
    one episode per sub-env of a vector env reset with ``seed``."""
    n_links, max_torque, dt, include_position = env_geometry(env_id, {})
    params, speed = gait_for_links(n_links, gaits, _versions_back(env_id))
    if speed is None:
        raise ValueError(f"the gait for n_links={n_links} has no search.mean_forward_velocity")
    env = _vector_env(env_id, episodes)
    try:
        controller = GoalSeekingController(params, n_links, max_torque, dt, gait_speed=float(speed),
                                           num_envs=episodes, include_position=include_position, **settings)
        obs, _ = env.reset(seed=seed)
        done, success, steps = np.zeros(episodes, bool), np.zeros(episodes, bool), np.zeros(episodes)
        while not done.all():
            obs, _, terminated, truncated, info = env.step(controller.act(obs))
            success |= np.asarray(info["is_success"], bool) & ~done
            steps[~done] += 1
            done |= terminated | truncated  # a finished sub-env autoresets on the next step; it is not counted
    finally:
        env.close()
    return float(success.mean()), (float(steps[success].mean()) if success.any() else float("nan"))


def search(env_id: str, episodes: int = 200, seed: int = 1000, validate_episodes: int = 400,
           validate_seed: int = 2000, top: int = 3, gaits=None, log=print) -> dict:
    """The entry written to ``configs/baselines.yaml``: ``{"settings": ..., "search": ...}``."""
    _check_reach(env_id)
    start = time.perf_counter()
    turn_gain, rates = measure_turn_gain(env_id, gaits=gaits)
    log(f"turning gain G = {turn_gain:.2f} rad/s per rad (yaw rates {rates})")
    if not turn_gain > 0:
        raise ValueError(f"the gait of {env_id} does not turn with a positive offset (G = {turn_gain:.3g})")
    scored = []
    for gain, max_offset, hysteresis in itertools.product(GAINS, MAX_OFFSETS, HYSTERESES):
        settings = {"gain": gain, "max_offset": max_offset, "hysteresis": hysteresis, "turn_gain": round(turn_gain, 2)}
        rate, steps = success_rate(env_id, settings, episodes, seed, gaits)
        scored.append((rate, -steps if steps == steps else 0.0, settings))
    scored.sort(key=lambda row: row[:2], reverse=True)
    finalists = []
    for rate, _, settings in scored[:top]:
        validation, steps = success_rate(env_id, settings, validate_episodes, validate_seed, gaits)
        log(f"{settings}: {rate:.3f} on the search goals, {validation:.3f} on the validation goals")
        finalists.append((validation, rate, steps, settings))
    validation, rate, steps, settings = max(finalists, key=lambda row: row[:2])
    return {"settings": settings,
            "search": {"success_rate": round(rate, 4), "episodes": episodes, "seed": seed,
                       "validation_success_rate": round(validation, 4), "validation_episodes": validate_episodes,
                       "validation_seed": validate_seed, "mean_steps_to_goal": round(steps, 1),
                       "yaw_rates": {g: round(r, 4) for g, r in rates.items()},
                       "settings_evaluated": len(scored), "seconds": round(time.perf_counter() - start, 1)}}


def save_entry(task: str, n_links: int, entry: dict, path=None) -> None:
    """Merge ``entry`` into the settings file (``path``, else the one :func:`config_path` resolves) under
    ``task: {n_links: ...}`` (atomic write)."""
    path = config_path(SETTINGS_FILE, path)
    data = load_baseline_settings(path)
    data.setdefault(task, {})[int(n_links)] = entry
    data[task] = dict(sorted(data[task].items()))
    header = ("# Settings of the task baselines (snake_env/controllers/steering.py) per task and number of links, found by\n"
              "# `python -m snake_env.agents.baseline_search --env ID`; a task and n not listed use the\n"
              "# controllers' defaults, tuned by hand on Snake5. settings: the controller's keyword arguments\n"
              "# (gain, max_offset in rad; turn_gain in rad/s per rad; hysteresis in turning radii).\n")
    atomic_write_text(path, header + yaml.safe_dump(dict(sorted(data.items())), sort_keys=False))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m snake_env.agents.baseline_search",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", dest="env_id", required=True, help="a reach task id, e.g. snake_env/SnakeReach8-v1")
    parser.add_argument("--episodes", type=int, default=200, help="goals per setting of the grid")
    parser.add_argument("--seed", type=int, default=1000, help="vector-env seed of the grid's goals")
    parser.add_argument("--validate-episodes", type=int, default=400, help="goals of the finalists' re-scoring")
    parser.add_argument("--validate-seed", type=int, default=2000, help="vector-env seed of those goals")
    parser.add_argument("--top", type=int, default=3, help="finalists re-scored")
    parser.add_argument("--output", default=None, help="YAML to merge the result into (default: ./configs/"
                        "baselines.yaml when it exists, else the shipped file)")
    parser.add_argument("--dry-run", action="store_true", help="print the result, do not write it")
    args = parser.parse_args(argv)
    for name in ("episodes", "validate_episodes", "top"):
        if getattr(args, name) < 1:
            parser.exit(2, f"{parser.prog}: error: --{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}\n")
    try:
        entry = search(args.env_id, args.episodes, args.seed, args.validate_episodes, args.validate_seed, args.top)
    except ValueError as exc:
        parser.exit(2, f"{parser.prog}: error: {exc}\n")
    n_links = env_geometry(args.env_id, {})[0]
    print(f"{args.env_id}: {entry['settings']} -> {entry['search']['validation_success_rate']:.3f} of "
          f"{args.validate_episodes} validation goals ({entry['search']['seconds']:.0f} s)")
    if not args.dry_run:
        entry["search"]["note"] = (f"`python -m snake_env.agents.baseline_search --env {args.env_id} --episodes "
                                   f"{args.episodes} --seed {args.seed} --validate-episodes {args.validate_episodes} "
                                   f"--validate-seed {args.validate_seed} --top {args.top}`")
        save_entry("reach", n_links, entry, args.output)
        print(f"saved to {config_path(SETTINGS_FILE, args.output)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
