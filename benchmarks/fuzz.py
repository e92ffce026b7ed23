"""Reliability fuzz of the batched env: does any non-finite or non-physical value reach the agent?

    python -m snake_env.benchmarks.fuzz [--steps-per-cell N] [--num-envs B] [--seconds-per-cell S] [--quick]
                              [--json PATH] [--markdown PATH] [--only TEXT] [--shard I/K]
                              [--resume OLD.json ... --seed S] [--budget-s T]
    python -m snake_env.benchmarks.fuzz --from-json PART.json [PART.json ...] --markdown PATH

``--shard I/K`` runs every K-th setting (both paper_model cells of it) starting
at the I-th (I = 0..K-1), so K processes or machines split the matrix.
``--resume OLD.json ... --seed S`` runs only the cells that have fewer than
``--steps-per-cell`` env-steps in the old files, for the steps they lack, with a
new seed, cheapest first (by the seconds each lacks at its old env-steps/s), so
``--budget-s T`` (no cell runs past T seconds of wall time; the last one stops
where the budget ends and its row says how far it got) tops up as many cells as
T allows. ``--from-json`` joins any such files into one report: the parts of a
cell add their counts, and the residual median is read off their summed
histograms (20 bins per decade).

The matrix of issue 10: n in {2, 3, 5, 12, 30, 100}, max_torque in {0.1, 1, 10,
100} N m, length in {0.02, 0.2, 1} m, mass in {0.05, 1, 20} kg (inertia m L^2 / 12),
paper_model off/on. Each cell runs ``num_envs`` sub-envs of the vector env
(autoreset), half of them with bang-bang actions (+-1) and half with uniform
random actions, for about ``steps_per_cell`` env-steps, and counts through the
public interface only (observations, rewards, infos):

* sim_failures: steps with ``info["sim_failure"]`` (the env's own verdict);
* leaked values: steps *not* flagged as failures whose observation, reward or info
  is non-finite, or whose work-energy residual |K1 - K0 - W| / (max(K0, K1) + floor)
  (from ``kinetic_energy`` and ``power`` of consecutive infos) exceeds the env's
  energy_tolerance (plus 1e-9 for the rounding of recomputing it), or whose joint
  angle reaches the fold (170 deg), or whose observed rates (joint rates,
  thetadot_1) exceed the finest substep's resolution (1 rad per substep). Must be 0;
* the residual's median and maximum over the accepted steps, and env-steps/s.

A cell whose kwargs the env refuses at the default sim_dt (0.01 s) is run at the
largest accepted sim_dt (``max_stable_sim_dt``, two significant digits, rounded
down) with frame_skip = ceil(0.04 s / sim_dt), so the env step stays 0.04 s; when
that needs frame_skip > 64 the cell is reported as refused.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import platform
import sys
import time
import warnings

import numpy as np

N_LINKS = (2, 3, 5, 12, 30, 100)
MAX_TORQUES = (0.1, 1.0, 10.0, 100.0)  # N m
LENGTHS = (0.02, 0.2, 1.0)  # m
MASSES = (0.05, 1.0, 20.0)  # kg
PAPER_MODEL = (False, True)
MATRIX_KEYS = ("n_links", "max_torque", "length", "mass", "inertia", "paper_model")
ENV_DT = 0.04  # s, the default env step
MAX_FRAME_SKIP = 64
RESIDUAL_ROUNDING = 1e-9
# the residual histogram of a row: 20 bins per decade from 1e-20 to 1 (see residual_histogram)
RESIDUAL_LOG10_MIN, RESIDUAL_BINS_PER_DECADE = -20, 20
RESIDUAL_BINS = -RESIDUAL_LOG10_MIN * RESIDUAL_BINS_PER_DECADE
# --quick and the CI test: cells where v0 leaked (strong torque, long snakes, light or short links)
QUICK_CELLS = {(5, 100.0, 0.2, 1.0), (30, 10.0, 0.2, 1.0), (3, 1.0, 0.02, 1.0), (12, 0.1, 0.2, 0.05),
               (2, 10.0, 1.0, 20.0)}  # recomputing the residual from infos rounds differently than the kernel


def matrix():
    """Every cell of the issue's matrix as a dict of env kwargs."""
    for n, torque, length, mass, paper in itertools.product(N_LINKS, MAX_TORQUES, LENGTHS, MASSES, PAPER_MODEL):
        yield dict(n_links=n, max_torque=torque, length=length, mass=mass, inertia=mass * length ** 2 / 12.0,
                   paper_model=paper)


def _round_down(x: float) -> float:
    """x rounded down to two significant digits."""
    scale = 10.0 ** (math.floor(math.log10(x)) - 1)
    return math.floor(x / scale) * scale


def make_env(kwargs: dict, num_envs: int, auto_substeps: bool = False):
    """(vector env, sim_dt note) for a cell, or (None, refusal message). ``auto_substeps``: sim_dt left at
    its default, so the env divides it into the substeps RK4 needs (as a user gets it)."""
    from snake_env.physics.config import PhysicsConfig, max_stable_sim_dt
    from snake_env.envs.vector import SnakeVectorEnv

    if auto_substeps:
        try:
            env = SnakeVectorEnv(num_envs=num_envs, **kwargs)
        except ValueError as exc:
            return None, str(exc)
        return env, f"default sim_dt, {env.params.substeps} substeps"

    try:  # sim_dt given, so the env refuses what RK4 cannot step at 0.01 s instead of choosing substeps
        return SnakeVectorEnv(num_envs=num_envs, **{"sim_dt": 0.01, **kwargs}), ""
    except ValueError as exc:
        if not str(exc).startswith("sim_dt"):
            return None, str(exc)
        refusal = str(exc)
    # the stability bound of these kwargs, from the same function the env's check uses
    physical = {key: kwargs[key] for key in ("n_links", "mass", "length", "inertia", "paper_model", "max_torque")}
    _, params = PhysicsConfig(sim_dt=1e-12, frame_skip=1, **physical).build()
    bound, _ = max_stable_sim_dt(params, kwargs["max_torque"])
    sim_dt = _round_down(bound)
    frame_skip = math.ceil(ENV_DT / sim_dt - 1e-9)
    if frame_skip > MAX_FRAME_SKIP:
        return None, refusal + f" (needs frame_skip {frame_skip} > {MAX_FRAME_SKIP} for a 0.04 s env step)"
    try:  # kwargs beyond the matrix's (a latency of whole 0.01 s substeps, randomized robots) may not fit it
        env = SnakeVectorEnv(num_envs=num_envs, sim_dt=sim_dt, frame_skip=frame_skip, **kwargs)
    except ValueError as exc:
        return None, f"{refusal}; at sim_dt={sim_dt:.2g} s: {exc}"
    return env, f"sim_dt={sim_dt:.2g} s, frame_skip={frame_skip} (0.01 s refused)"


def run_cell(kwargs: dict, num_envs: int = 256, steps: int = 100_000, seed: int = 0,
             max_seconds: float | None = None, auto_substeps: bool = False) -> dict:
    """Fuzz one setting through the vector env; returns the cell's row (see the module doc).
    ``max_seconds``: stop the cell early after this much wall time (the row says how many
    env-steps ran); cells whose every step fails run at a few hundred steps/s."""
    from snake_env import physics

    env, note = make_env(kwargs, num_envs, auto_substeps)
    row = {**kwargs, "note": note}
    if env is None:
        row.update(refused=True, env_steps=0)
        return row
    rng = np.random.default_rng(seed)
    B = env.num_envs
    bang = np.arange(B) < B // 2
    obs, info = env.reset(seed=seed)
    k_prev = info["kinetic_energy"].copy()
    fresh = np.ones(B, bool)  # rows whose previous value is a reset (no residual across it)
    floor = env.params.energy_floor
    tol = env.energy_tolerance
    rate_bound = physics.MAX_SUBSTEP_ANGLE / (env.sim_dt / 2 ** env.params.max_refinements)
    n = env.n_links
    failures = leaks = env_steps = 0
    reasons: dict[str, int] = {}
    residuals = []
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        # count env-steps, not batches: rows being auto-reset do not step, so a fixed number of
        # batches would fall short of ``steps``
        while env_steps < steps:
            if max_seconds is not None and time.perf_counter() - start > max_seconds:
                break
            a = rng.uniform(-1.0, 1.0, (B, n - 1))
            a[bang] = np.where(a[bang] >= 0.0, 1.0, -1.0)
            obs, reward, terminated, truncated, info = env.step(a)
            stepped = info["_sim_failure"]
            failed = info["sim_failure"] & stepped
            failures += int(failed.sum())
            for code in env._batch.aux[failed, physics.AUX_FAILED]:
                name = physics.FAILURE_REASONS[int(code)]
                reasons[name] = reasons.get(name, 0) + 1
            ok = stepped & ~failed
            env_steps += int(stepped.sum())
            values_finite = np.isfinite(obs).all(axis=1) & np.isfinite(reward)
            for key in ("kinetic_energy", "power", "x_position", "y_position", "x_velocity", "y_velocity"):
                values_finite &= np.isfinite(info[key])
            k1 = info["kinetic_energy"]
            work = info["power"] * env.dt
            residual = np.abs(k1 - k_prev - work) / (np.maximum(k1, k_prev) + floor)
            checked = ok & ~fresh
            bad = ~values_finite & ok
            bad |= checked & ~(residual <= tol + RESIDUAL_ROUNDING)
            angles = obs[:, -(2 * n + 2):][:, : n - 1]
            rates = np.abs(obs[:, -(n - 1):]).max(axis=1, initial=0.0) if n > 1 else np.zeros(B)
            rates = np.maximum(rates, np.abs(obs[:, -n]))  # thetadot_1
            bad |= ok & ((np.abs(angles) >= physics.FOLD_ANGLE).any(axis=1) | (rates > rate_bound))
            leaks += int(bad.sum())
            residuals.append(residual[checked])
            k_prev = k1.copy()
            fresh = ~stepped | (terminated | truncated)
    elapsed = time.perf_counter() - start
    env.close()
    res = np.concatenate(residuals) if residuals else np.zeros(0)
    row.update(refused=False, seed=seed, sim_dt=env.sim_dt, frame_skip=env.frame_skip, env_steps=env_steps,
               sim_failures=failures, failure_reasons=reasons, leaked=leaks,
               residual_median=float(np.median(res)) if res.size else None,
               residual_max=float(np.max(res)) if res.size else None,
               residual_histogram=residual_histogram(res),
               seconds=elapsed, steps_per_s=env_steps / elapsed)
    return row


def residual_histogram(residuals: np.ndarray) -> list[int]:
    """Counts of residuals in RESIDUAL_BINS_PER_DECADE bins per decade from 10^RESIDUAL_LOG10_MIN
    (bin 0 also holds everything below, 0 included) to 1 (the last bin everything above): runs of
    one cell with different seeds add their histograms, and the joint median is read off them."""
    with np.errstate(divide="ignore"):
        index = np.floor((np.log10(residuals) - RESIDUAL_LOG10_MIN) * RESIDUAL_BINS_PER_DECADE)
    index = np.clip(np.nan_to_num(index, nan=0.0, neginf=0.0), 0, RESIDUAL_BINS - 1).astype(np.int64)
    return np.bincount(index, minlength=RESIDUAL_BINS).tolist()


def histogram_median(counts) -> float | None:
    """The median of a :func:`residual_histogram` (the geometric centre of its bin, so within a
    factor 10^(0.5 / RESIDUAL_BINS_PER_DECADE) = 1.06 of the exact one)."""
    counts = np.asarray(counts)
    if counts.sum() == 0:
        return None
    k = int(np.searchsorted(np.cumsum(counts), counts.sum() / 2.0))
    return 10.0 ** (RESIDUAL_LOG10_MIN + (k + 0.5) / RESIDUAL_BINS_PER_DECADE)


def _fmt(x, spec=".2g"):
    return "-" if x is None else format(x, spec)


# bounds of the fold-time classes of the report, in env steps (ENV_DT)
FOLD_TIME_BOUNDS = (0.3, 1.0, 3.0, 10.0, 30.0)


def fold_time(row: dict) -> float:
    """A lower bound on the time (s) the row's max_torque needs to turn a joint from rest to the
    fold (FOLD_ANGLE): constant angular acceleration T / I_j with I_j = inertia / 2, the bound on
    the effective joint inertia that ``config.stiffest_rates`` uses. With paper_model (no joint
    limit) a torque held longer can fold the snake; Snake2 with inertia m L^2 / 12 folds after
    2.25 times this (tests/benchmarks/test_fuzz.py)."""
    from snake_env import physics

    return math.sqrt(2.0 * physics.FOLD_ANGLE * (row["inertia"] / 2.0) / row["max_torque"])


def fold_time_table(rows: list[dict]) -> list[str]:
    """The report's paper-model failure fractions by fold time in env steps (markdown lines)."""
    paper = [r for r in rows if not r["refused"] and r["paper_model"] and r["env_steps"]]
    edges = (0.0,) + FOLD_TIME_BOUNDS + (math.inf,)
    lines = ["| fold time / env step | cells | failed steps: median | max |", "|---|---|---|---|"]
    for low, high in zip(edges[:-1], edges[1:]):
        fractions = [r["sim_failures"] / r["env_steps"] for r in paper if low <= fold_time(r) / ENV_DT < high]
        if fractions:
            label = f"< {high:g}" if low == 0.0 else (f">= {low:g}" if high == math.inf else f"{low:g} - {high:g}")
            lines.append(f"| {label} | {len(fractions)} | {np.median(fractions):.1%} | {max(fractions):.1%} |")
    return lines


def markdown(rows: list[dict], meta: dict) -> str:
    run = [r for r in rows if not r["refused"]]
    refused = [r for r in rows if r["refused"]]
    total_leaks = sum(r["leaked"] for r in run)
    joined = sum(isinstance(r.get("seed"), list) for r in run)
    lines = [
        "# Reliability: fuzzing the batched env",
        "",
        "Generated by `" + meta["command"] + "`. Do not edit by hand.",
        "",
        f"- {len(rows)} settings; {len(run)} run, {len(refused)} refused at construction.",
        f"- Env-steps per setting: up to {meta['steps_per_cell']:,} ({meta['num_envs']} sub-envs of the vector env, "
        "half bang-bang, half uniform random actions, autoreset)"
        + (f", each cell stopped after {meta['seconds_per_cell']:g} s" if meta.get("seconds_per_cell") else "")
        + f"; {sum(r['env_steps'] >= 10 ** 6 for r in run)} of the {len(run)} cells run reached the issue's "
        f"10^6 env-steps, {sum(r['env_steps'] for r in run):,} env-steps in total.",
        f"- **Leaked values: {total_leaks}** in total (non-finite, energy residual above tolerance, fold or "
        "runaway rate on a step not flagged `sim_failure`).",
        f"- Machine: {meta['machine']}; "
        + (f"wall time {meta['wall_s']:.0f} s" if meta.get("wall_s") else
           f"{sum(r.get('seconds', 0.0) for r in run):.0f} s of cell time (summed over cells and parts)")
        + f"; {meta['load']}."
        + (f" {joined} cells ran in more than one part (seeds), whose counts are added." if joined else ""),
        "",
        "## Where the paper model folds",
        "",
        "Without joint limits (`paper_model=True`) a held torque folds adjacent links, which the model cannot "
        "simulate (no link contact): such a step is a `sim_failure`. How often it happens depends on the fold "
        "time sqrt(2 * 170 deg * (I / 2) / max_torque), a lower bound on the time the maximum torque needs to "
        f"turn a joint from rest to the fold, here in env steps ({ENV_DT:g} s). With the default joint limits "
        f"(no paper_model), {sum(r['sim_failures'] for r in run if not r['paper_model']):,} steps failed in all.",
        "",
        *fold_time_table(rows),
        "",
        "## Every setting",
        "",
        "Columns: residual = |K1 - K0 - W| / (max(K0, K1) + floor) per accepted env step (the env's "
        "energy_tolerance is 1e-2); failures = steps ended with `info['sim_failure']`, by reason.",
        "",
        "| n | T (N m) | L (m) | m (kg) | paper | sim_dt | env-steps | failures | leaked | residual median | "
        "residual max | steps/s | failure reasons |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if r["refused"]:
            continue
        reasons = "; ".join(f"{k}: {v}" for k, v in sorted(r["failure_reasons"].items())).replace("|", "\\|")
        lines.append(f"| {r['n_links']} | {r['max_torque']:g} | {r['length']:g} | {r['mass']:g} | "
                     f"{'yes' if r['paper_model'] else 'no'} | {r['sim_dt']:.2g} | {r['env_steps']:,} | "
                     f"{r['sim_failures']:,} | {r['leaked']} | {_fmt(r['residual_median'])} | "
                     f"{_fmt(r['residual_max'])} | {r['steps_per_s']:,.0f} | {reasons} |")
    if meta.get("notes"):
        lines += ["", "## Notes", ""] + [f"- {note}" for note in meta["notes"]]
    if refused:
        lines += ["", "## Refused settings", "",
                  "| n | T (N m) | L (m) | m (kg) | paper | reason |", "|---|---|---|---|---|---|"]
        for r in refused:
            lines.append(f"| {r['n_links']} | {r['max_torque']:g} | {r['length']:g} | {r['mass']:g} | "
                         f"{'yes' if r['paper_model'] else 'no'} | {r['note']} |")
    return "\n".join(lines) + "\n"


def parse_args(argv):
    parser = argparse.ArgumentParser(prog="python -m snake_env.benchmarks.fuzz", description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps-per-cell", type=int, default=1_000_000, help="env-steps per setting (default 1e6)")
    parser.add_argument("--num-envs", type=int, default=256, help="sub-envs of the vector env (default 256)")
    parser.add_argument("--seconds-per-cell", type=float, default=None, metavar="S",
                        help="stop a cell after S seconds of wall time (its row gives the env-steps it ran)")
    parser.add_argument("--budget-s", type=float, default=None, metavar="T",
                        help="the run's wall time (s): no cell runs past it (with --resume the cheapest run first)")
    parser.add_argument("--quick", action="store_true", help="a few cells, 64 envs x 20 steps: checks that it runs")
    parser.add_argument("--only", default="", help="run only cells whose kwargs text contains this (e.g. \"'n_links': 5,\")")
    parser.add_argument("--shard", default="0/1", metavar="I/K",
                        help="run every K-th setting from the I-th, I in 0..K-1 (default 0/1: all)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--note", action="append", default=[], metavar="TEXT",
                        help="a line for the report's Notes section (e.g. the machine's load); repeatable")
    parser.add_argument("--json", metavar="PATH", help="write the rows as JSON")
    parser.add_argument("--from-json", metavar="PATH", nargs="+",
                        help="render the report from saved --json files instead of running: shards and resumed "
                             "parts are joined per cell (give --steps-per-cell and --num-envs of the runs)")
    parser.add_argument("--resume", metavar="PATH", nargs="+",
                        help="saved --json files of earlier runs: run only the cells below --steps-per-cell there, "
                             "for the env-steps they lack, with this run's --seed (which must be new for them); "
                             "join all files with --from-json")
    parser.add_argument("--wall-s", type=float, default=0.0, help="with --from-json: the saved run's wall time (s)")
    parser.add_argument("--markdown", metavar="PATH", help="write the report (docs/reliability.md)")
    args = parser.parse_args(argv)
    if args.steps_per_cell < 1 or args.num_envs < 2:
        parser.error(f"--steps-per-cell must be >= 1 and --num-envs >= 2, got {args.steps_per_cell}, {args.num_envs}")
    if args.seconds_per_cell is not None and not args.seconds_per_cell > 0:
        parser.error(f"--seconds-per-cell must be > 0, got {args.seconds_per_cell}")
    if args.budget_s is not None and not args.budget_s > 0:
        parser.error(f"--budget-s must be > 0, got {args.budget_s}")
    try:
        index, count = (int(part) for part in args.shard.split("/"))
        if not 0 <= index < count:
            raise ValueError
    except ValueError:
        parser.error(f"--shard must be I/K with integers 0 <= I < K, got {args.shard!r}")
    args.shard = (index, count)
    return args


def cell_key(row: dict) -> tuple:
    """The matrix cell (n, torque, length, mass, inertia, paper) of a row or a cell's kwargs."""
    return tuple(row[k] for k in MATRIX_KEYS)


def join_rows(rows: list[dict]) -> list[dict]:
    """One row per cell, in the order of :func:`matrix`: the runs of a cell (shards, or parts added
    by ``--resume`` with another seed) summed; the joint residual median is read off the summed
    histograms. Raises ValueError when a cell was run twice with one seed (the same trajectories
    would count twice) or a part has no histogram to join."""
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault(cell_key(row), []).append(row)
    joined = []
    for key, part in groups.items():
        if len(part) == 1 or part[0]["refused"]:
            joined.append(part[0])
            continue
        # a part may itself be joined (its seed a list): the parts of a report can be joined again
        seeds = [int(seed) for r in part for seed in np.atleast_1d(r.get("seed", 0))]
        if len(set(seeds)) < len(seeds):
            raise ValueError(f"cell {dict(zip(MATRIX_KEYS, key))} was run more than once with seed {seeds}: "
                             "each part of a cell needs its own --seed")
        if any("residual_histogram" not in r for r in part):
            raise ValueError(f"cell {dict(zip(MATRIX_KEYS, key))}: a part has no residual_histogram "
                             "(written before parts could be joined); rerun it")
        row = dict(part[0])
        reasons: dict[str, int] = {}
        for r in part:
            for name, count in r["failure_reasons"].items():
                reasons[name] = reasons.get(name, 0) + count
        maxima = [r["residual_max"] for r in part if r["residual_max"] is not None]
        histogram = np.sum([r["residual_histogram"] for r in part], axis=0)
        seconds = sum(r["seconds"] for r in part)
        row.update(seed=seeds, failure_reasons=reasons, residual_max=max(maxima, default=None),
                   residual_histogram=histogram.tolist(), residual_median=histogram_median(histogram),
                   seconds=seconds, **{k: sum(r[k] for r in part) for k in ("env_steps", "sim_failures", "leaked")})
        row["steps_per_s"] = row["env_steps"] / seconds
        joined.append(row)
    order = {cell_key(cell): i for i, cell in enumerate(matrix())}
    return sorted(joined, key=lambda r: order.get(cell_key(r), len(order)))


def _seconds_lacking(row: dict | None, steps: int) -> float:
    """Estimated wall time (s) a resumed cell needs to reach ``steps``, at its old env-steps/s
    (inf when it has no rate yet: such cells run last)."""
    if row is None or row["refused"] or not row["env_steps"]:
        return math.inf
    return max(steps - row["env_steps"], 0) * row["seconds"] / row["env_steps"]


def _load_rows(paths) -> list[dict]:
    rows = []
    for path in paths:
        with open(path) as f:
            rows += json.load(f)
    return rows


def _command(argv: list[str]) -> str:
    """The command line of this run for the report, without its --note texts (the Notes section)."""
    kept, skip = [], False
    for arg in argv:
        if skip or arg.startswith("--note="):
            skip = False
            continue
        if arg == "--note":
            skip = True
            continue
        kept.append(arg)
    return "python -m snake_env.benchmarks.fuzz " + " ".join(kept)


def main(argv=None) -> int:
    from snake_env.atomic import atomic_write_text as write_text

    args = parse_args(sys.argv[1:] if argv is None else argv)
    if args.from_json:
        try:
            rows = join_rows(_load_rows(args.from_json))
        except (OSError, ValueError) as exc:
            print(f"error: --from-json: {exc}", file=sys.stderr)
            return 2
        # the report's command: the runs that wrote the files are given by --note
        meta = {"command": _command(sys.argv[1:] if argv is None else argv),
                "steps_per_cell": args.steps_per_cell, "num_envs": args.num_envs, "wall_s": args.wall_s,
                "seconds_per_cell": args.seconds_per_cell,
                "machine": f"{platform.machine()}, {os.cpu_count()} cores", "load": "shared machine",
                "notes": args.note}
        if args.markdown:
            write_text(args.markdown, markdown(rows, meta))
        return 1 if sum(r.get("leaked", 0) for r in rows) else 0
    cells = list(matrix())
    if args.only:
        cells = [c for c in cells if args.only in repr(c)]
    # by pairs (paper_model off, on) of a setting, so every shard gets both kinds of cell
    cells = [c for i, c in enumerate(cells) if (i // 2) % args.shard[1] == args.shard[0]]
    steps, num_envs = args.steps_per_cell, args.num_envs
    if args.quick:
        cells = [c for c in cells if (c["n_links"], c["max_torque"], c["length"], c["mass"]) in QUICK_CELLS]
        steps, num_envs = 64 * 20, 64
    done = {}
    if args.resume:
        try:
            done = {cell_key(r): r for r in join_rows(_load_rows(args.resume))}
        except (OSError, ValueError) as exc:
            print(f"error: --resume: {exc}", file=sys.stderr)
            return 2
        for key, row in done.items():
            if not row["refused"] and args.seed in np.atleast_1d(row.get("seed", 0)) and row["env_steps"] < steps:
                print(f"error: --seed {args.seed} already ran cell {dict(zip(MATRIX_KEYS, key))} in --resume; "
                      "give the new part another --seed", file=sys.stderr)
                return 2
        cells.sort(key=lambda c: _seconds_lacking(done.get(cell_key(c)), steps))  # stable: ties keep matrix order
    rows = []
    if args.json:  # an empty list until the first cell, also when no cell is left to run
        write_text(args.json, "[]")
    start = time.perf_counter()
    for i, kwargs in enumerate(cells):
        before = done.get(cell_key(kwargs))
        if before is not None and (before["refused"] or before["env_steps"] >= steps):
            continue  # refused, or already has its env-steps
        left = steps - (before["env_steps"] if before else 0)
        max_seconds = args.seconds_per_cell
        if args.budget_s is not None:
            budget_left = args.budget_s - (time.perf_counter() - start)
            if budget_left <= 0.0:
                print(f"--budget-s {args.budget_s:g} spent: the remaining cells did not run", flush=True)
                break
            max_seconds = budget_left if max_seconds is None else min(max_seconds, budget_left)
        row = run_cell(kwargs, num_envs=num_envs, steps=left, seed=args.seed, max_seconds=max_seconds)
        rows.append(row)
        status = "refused" if row["refused"] else (f"{row['env_steps']} steps, {row['sim_failures']} failures, "
                                                   f"{row['leaked']} leaked, {row['steps_per_s']:.0f}/s")
        print(f"[{i + 1}/{len(cells)}] {kwargs}: {status}", flush=True)
        if args.json:  # rewritten after every cell, so a long run can be stopped and still reported
            write_text(args.json, json.dumps(rows, indent=1))
    meta = {"command": _command(sys.argv[1:] if argv is None else argv),
            "steps_per_cell": steps, "num_envs": num_envs, "seconds_per_cell": args.seconds_per_cell, "wall_s": time.perf_counter() - start,
            "machine": f"{platform.machine()}, {os.cpu_count()} cores",
            "load": "load average at the end %.1f (shared machine)" % os.getloadavg()[0], "notes": args.note}
    if args.markdown:
        write_text(args.markdown, markdown(rows, meta))
    leaks = sum(r.get("leaked", 0) for r in rows)
    print(f"{len(rows)} settings, {sum(r['refused'] for r in rows)} refused, {leaks} leaked values")
    return 1 if leaks else 0


if __name__ == "__main__":
    sys.exit(main())
