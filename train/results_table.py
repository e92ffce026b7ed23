"""Evaluate a campaign of runs against the serpenoid baseline; print a markdown table.

    python -m snake_env.train.results_table runs/results --episodes 10 --images docs/images

Expects run directories ``<root>/<Env>__<algo>__s<seed>/`` made by snake-train.
Each final model is evaluated with snake-eval (deterministic; and stochastic
and the EvalCallback's best model as extra columns), each env's serpenoid
gait with ``snake-eval --baseline serpenoid`` on the same episode seeds.
Results are cached as ``eval_*.json`` in every run directory. The tables give, per algorithm and id,
the interquartile mean over seeds of the speed and of its ratio to the serpenoid with 95 %
stratified-bootstrap CIs (rliable, ``pip install -e ".[stats]"``), then every seed.

With ``--images`` it also draws ``speed_vs_n.png``: the learned runs' speed
and the serpenoid's (every id of ``configs/serpenoid.yaml`` named SnakeN)
against n; ``--earlier CSV`` (columns env, algo, seed, speed) adds hollow
points for speeds measured in an earlier campaign whose runs are not at hand,
and ``--measured CSV`` (same columns) adds this campaign's speeds of runs that
are not under ``root`` (e.g. evaluated on another machine) as filled points; with no runs under ``root``,
``--measured`` alone redraws ``speed_vs_n.png`` from recorded speeds (``docs/results_v3.csv``: the
tables of docs/results.md), the serpenoid evaluated on the CSV's version.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from snake_env.train.evaluate import main as evaluate_main

RUN_RE = re.compile(r"^(?P<env>[^_]+)__(?P<algo>ppo|sac)__s(?P<seed>\d+)$")
SIZE_RE = re.compile(r"^Snake(?P<n>\d+)-v\d+$")


def evaluate_cached(json_path: Path, argv: list[str]) -> dict:
    if not json_path.is_file():
        code = evaluate_main([*argv, "--json", str(json_path)])
        if code != 0:
            raise SystemExit(f"evaluation failed: {argv}")
    return json.loads(json_path.read_text())


def wall_seconds(run_dir: Path) -> float:
    try:
        return float((run_dir / "wall_time.txt").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return float("nan")


def timesteps(run_dir: Path) -> int:
    from snake_env.agents.policy_loading import CHECKPOINT_RE

    steps = [int(m.group(1)) for p in (run_dir / "checkpoints").glob("*.zip") if (m := CHECKPOINT_RE.match(p.name))]
    return max(steps, default=0)


def speeds_from_csv(path, label: str, into=None) -> dict:
    """{(algo, "ALGO (label)"): {n: [speed per seed]}} of the SnakeN rows of a CSV with columns env,
    algo, seed, speed (m/s) and optionally label (the curve's own name, e.g. a JointPolicy run's zero-shot
    speeds), added to ``into`` if given; other ids (Snake-v2, tasks) are skipped."""
    import csv

    speeds = into if into is not None else defaultdict(lambda: defaultdict(list))
    with open(path, newline="") as handle:
        for row in csv.DictReader(handle):
            if (m := SIZE_RE.match(row["env"])):
                name = row.get("label") or f"{row['algo'].upper()} ({label})"
                speeds[(row["algo"], name)][int(m["n"])].append(float(row["speed"]))
    return speeds


def csv_versions(path) -> set[str]:
    """The versions ("v3") of the SnakeN rows of a speeds CSV (none without a path)."""
    import csv

    if not path:
        return set()
    with open(path, newline="") as handle:
        return {row["env"].rsplit("-", 1)[-1] for row in csv.DictReader(handle) if SIZE_RE.match(row["env"])}


def env_arguments(env_id: str) -> list[str]:
    """snake-eval's arguments for a forward id; a length with no id of its own (a gait searched with
    ``--n-links``, e.g. snake_env/Snake10-v3) runs on the generic id with n_links."""
    import gymnasium as gym

    if env_id in gym.registry:
        return ["--env", env_id]
    m = re.fullmatch(r"(snake_env/Snake)(\d+)-(v\d+)", env_id)
    return ["--env", f"{m[1]}-{m[3]}", "--env-kwarg", f"n_links={m[2]}"]


def plot_sizes(root: Path, runs: dict, episodes: int, path: Path, earlier_csv=None, measured_csv=None) -> None:
    """speed_vs_n.png from the runs (and the measured CSV), the serpenoid of every SnakeN id and the
    earlier CSV."""
    from snake_env.controllers import load_gaits
    from snake_env.train.plots import plot_speed_vs_n

    serpenoid = {}
    # the serpenoid searched on the runs' physics (and the measured CSV's)
    versions = {env.rsplit("-", 1)[-1] for env, _ in runs} | csv_versions(measured_csv)
    for env_id in load_gaits():
        env = env_id.split("/")[-1]
        if (m := SIZE_RE.match(env)) and env.rsplit("-", 1)[-1] in versions:
            serpenoid[int(m["n"])] = evaluate_cached(root / f"serpenoid_{env}_{episodes}.json",
                                                     ["--baseline", "serpenoid", *env_arguments(env_id),
                                                      "--episodes", str(episodes)])["mean_forward_velocity"]
    learned = defaultdict(lambda: defaultdict(list))
    for (env, algo), items in runs.items():
        if (m := SIZE_RE.match(env)):
            learned[(algo, f"{algo.upper()} (this table)")][int(m["n"])] += [r["det"]["mean_forward_velocity"]
                                                                             for r in items]
    if measured_csv:
        speeds_from_csv(measured_csv, "this table", into=learned)
    earlier = speeds_from_csv(earlier_csv, "earlier campaign") if earlier_csv else None
    plot_speed_vs_n(learned, serpenoid, path, earlier)


def print_tables(runs: dict, baselines: dict) -> None:
    """One summary table per algorithm (IQM over seeds of the ratio to the serpenoid, with its 95 %
    stratified-bootstrap CI: train/aggregate.py), then the per-seed table."""
    from snake_env.train.aggregate import iqm

    for algo in sorted({algo for _, algo in runs}):
        cells = {env: sorted(items, key=lambda r: r["seed"]) for (env, a), items in runs.items() if a == algo}
        print(f"{algo.upper()}: forward speed over seeds, interquartile mean [95 % CI]")
        print()
        print("| env | seeds | v_x IQM (m/s) | ratio to serpenoid, IQM | lowest seed's ratio "
              "| seeds >= 0.8x | serpenoid v_x (m/s) | wall time (min, median) |")
        print("|---|---|---|---|---|---|---|---|")
        ratios = {}
        for env, items in sorted(cells.items(), key=lambda kv: size_key(kv[0])):
            speed = np.array([r["det"]["mean_forward_velocity"] for r in items])
            serp = baselines[env]["mean_forward_velocity"]
            ratios[env] = speed / serp
            print(f"| {env} | {', '.join(str(r['seed']) for r in items)} | {iqm(speed)} | {iqm(ratios[env])} "
                  f"| {ratios[env].min():.2f} | {int(np.sum(ratios[env] >= 0.8))} of {len(items)} | {serp:.3f} "
                  f"| {np.median([r['wall'] for r in items]) / 60:.1f} |")
        counts = {len(r) for r in ratios.values()}
        if len(ratios) > 1 and len(counts) == 1:  # the stratified bootstrap needs a full (runs, tasks) matrix
            matrix = np.stack([ratios[env] for env in sorted(ratios)], axis=1)
            print(f"| all {len(ratios)} ids | {counts.pop()} per id | | {iqm(matrix)} | {matrix.min():.2f} "
                  f"| {int(np.sum(matrix >= 0.8))} of {matrix.size} | | |")
        print()
    print("Per seed (deterministic policy, mean ± std over episodes; stochastic policy and the "
          "EvalCallback's best model beside it):")
    print()
    print("| env | algo | seed | timesteps | wall (s) | v_x (m/s) | ratio to serpenoid | v_x stochastic (m/s) "
          "| v_x best model (m/s) | joint freq. (Hz) | peak joint rate (rad/s) | wheel-steps outside the cone |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for (env, algo), items in sorted(runs.items(), key=lambda kv: (kv[0][1], size_key(kv[0][0]))):
        serp = baselines[env]["mean_forward_velocity"]
        for r in sorted(items, key=lambda r: r["seed"]):
            d = r["det"]
            best = f"{r['best']['mean_forward_velocity']:.3f}" if r["best"] else "-"
            print(f"| {env} | {algo.upper()} | {r['seed']} | {r['steps']} | {r['wall']:.0f} "
                  f"| {d['mean_forward_velocity']:.3f} ± {d['std_forward_velocity']:.3f} "
                  f"| {d['mean_forward_velocity'] / serp:.2f} | {r['sto']['mean_forward_velocity']:.3f} | {best} "
                  f"| {gait(d, 'mean_dominant_joint_frequency', '.2f')} | {gait(d, 'max_peak_joint_rate', '.1f')} "
                  f"| {gait(d, 'mean_outside_friction_cone_share', '.1%')} |")


def gait(result: dict, key: str, spec: str) -> str:
    """One gait metric of a snake-eval result, formatted ("-" where the eval has none)."""
    value = result.get(key)
    return "-" if value is None else format(value, spec)


def size_key(env: str):
    """Sort ids by their number of links (Snake3 before Snake12), others by name after them."""
    m = SIZE_RE.match(env)
    return (int(m["n"]), env) if m else (10**6, env)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m snake_env.train.results_table", description=__doc__.split("\n\n")[0])
    parser.add_argument("root", help="directory holding the run directories")
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--extra-episodes", type=int, default=5, help="episodes for the stochastic/best columns")
    parser.add_argument("--images", help="copy learning curves here as curve_<env>_<algo>_s<seed>.png")
    parser.add_argument("--earlier", help="CSV (env, algo, seed, speed) of earlier measured runs for speed_vs_n.png")
    parser.add_argument("--measured", help="CSV (env, algo, seed, speed) of this campaign's runs not under root, "
                                           "drawn with them in speed_vs_n.png")
    args = parser.parse_args(argv)
    root = Path(args.root)
    runs = defaultdict(list)
    for run_dir in sorted(p for p in root.iterdir() if p.is_dir() and RUN_RE.match(p.name)):
        if not (run_dir / "model.zip").is_file():
            continue
        match = RUN_RE.match(run_dir.name)
        env, algo, seed = match["env"], match["algo"], int(match["seed"])
        n = args.episodes
        det = evaluate_cached(run_dir / f"eval_deterministic_{n}.json", [str(run_dir), "--episodes", str(n)])
        k = args.extra_episodes
        sto = evaluate_cached(run_dir / f"eval_stochastic_{k}.json",
                              [str(run_dir), "--episodes", str(k), "--stochastic"])
        best = None
        if (run_dir / "best_model" / "best_model.zip").is_file():
            best = evaluate_cached(run_dir / f"eval_best_{k}.json",
                                   [str(run_dir / "best_model" / "best_model.zip"), "--episodes", str(k)])
        runs[(env, algo)].append({"seed": seed, "steps": timesteps(run_dir), "wall": wall_seconds(run_dir),
                                  "det": det, "sto": sto, "best": best})
        if args.images:
            curve = run_dir / "learning_curve.png"
            if curve.is_file():
                Path(args.images).mkdir(parents=True, exist_ok=True)
                shutil.copy(curve, Path(args.images) / f"curve_{env}_{algo}_s{seed}.png")
    baselines = {}
    for env in sorted({env for env, _ in runs}):
        baselines[env] = evaluate_cached(root / f"serpenoid_{env}_{args.episodes}.json",
                                         ["--baseline", "serpenoid", "--env", f"snake_env/{env}",
                                          "--episodes", str(args.episodes)])
    if args.images and runs:
        from snake_env.train.plots import plot_campaign

        groups = {key: [root / f"{key[0]}__{key[1]}__s{r['seed']}" / "eval" / "evaluations.npz" for r in items]
                  for key, items in runs.items()}
        plot_campaign(groups, {env: b["mean_forward_velocity"] for env, b in baselines.items()},
                      Path(args.images) / "curve_summary.png")
    if args.images and (runs or args.measured):  # speeds from a CSV alone: speed_vs_n.png only
        plot_sizes(root, runs, args.episodes, Path(args.images) / "speed_vs_n.png", args.earlier, args.measured)
    print_tables(runs, baselines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
