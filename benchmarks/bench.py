"""``snake-bench``: speed of snake_env side by side with MuJoCo Swimmer-v5.

    snake-bench [--quick] [--json PATH] [--plot PATH] [--markdown PATH]
                [--sections LIST] [--from-json PATH] [--note TEXT]

Sections (issue 6): single-env steps/s (Snake3, Snake5, Snake30 and
Swimmer-v5), vector env env-steps/s vs number of envs, udot time vs n for every
formulation, SB3 PPO fps (Snake5 batched vs Swimmer-v5 single env), peak memory
of a 4096-env Snake30 vector env and fresh-process start-up time. Prints a
table and the issue's targets (met / not met), writes JSON, a scaling plot and
``docs/benchmarks.md``. ``--quick`` runs every section at tiny sizes (a smoke
test, numbers meaningless). ``--from-json`` re-renders a saved run.

The documented run (about 2 minutes on 2 cores; run it on a quiet machine)::

    snake-bench --json docs/benchmarks.json --plot docs/images/bench_scaling.png --markdown docs/benchmarks.md
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from dataclasses import asdict, dataclass, field

from snake_env.benchmarks import bench_report, bench_sections

SECTIONS = ("single", "vector", "wheels", "udot", "ppo", "memory", "startup")


@dataclass(frozen=True)
class BenchConfig:
    """Sizes of every section; FULL fits in ~10 minutes on 2 cores, QUICK in seconds."""

    single_links: tuple = (3, 5, 30)
    single_sample_time: float = 1.0  # s per repeat
    single_rounds: int = 5
    vector_links: int = 5
    vector_num_envs: tuple = (1, 8, 64, 256, 1024, 4096)
    vector_sample_time: float = 1.0  # s per repeat
    vector_rounds: int = 3
    wheels_links: tuple = (5, 12, 20, 30)  # the sliding-wheel model's cost against the no-slip wheels'
    wheels_num_envs: int = 32
    wheels_sample_time: float = 1.0  # s per repeat
    wheels_rounds: int = 3
    udot_n: tuple = (10, 20, 50, 100, 200, 500, 1000)
    udot_min_time: float = 0.05  # s of repeated calls per timing block
    udot_max_call_time: float = 0.05  # s: a slower method stops growing n
    ppo_links: int = 5
    ppo_num_envs: int = 16
    ppo_iterations: int = 1
    ppo_rounds: int = 3
    ppo_kwargs: dict = field(default_factory=dict)  # SB3 defaults
    memory_links: int = 30
    memory_num_envs: int = 4096
    memory_steps: int = 50
    startup_runs: int = 3
    startup_cold: bool = True  # the first start-up run from an empty numba cache (compiles everything)


FULL = BenchConfig()
QUICK = BenchConfig(
    single_sample_time=0.05, single_rounds=2,
    vector_num_envs=(4, 16), vector_sample_time=0.05, vector_rounds=2,
    wheels_links=(5,), wheels_num_envs=4, wheels_sample_time=0.05, wheels_rounds=1,
    udot_n=(10, 20, 40), udot_min_time=0.002, udot_max_call_time=0.05,
    ppo_num_envs=4, ppo_rounds=1, ppo_kwargs={"n_steps": 64, "batch_size": 32, "n_epochs": 1},
    memory_num_envs=64, memory_steps=5, startup_runs=1, startup_cold=False,
)


def parse_args(argv):
    parser = argparse.ArgumentParser(prog="snake-bench", description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="tiny sizes: checks that every section runs")
    parser.add_argument("--json", metavar="PATH", help="write all results as JSON")
    parser.add_argument("--plot", metavar="PATH", help="write the scaling plot (png, svg or pdf)")
    parser.add_argument("--markdown", metavar="PATH", help="write the results page (docs/benchmarks.md)")
    parser.add_argument("--sections", default=",".join(SECTIONS),
                        help=f"comma-separated subset of {','.join(SECTIONS)} (default: all)")
    parser.add_argument("--from-json", metavar="PATH", help="render a saved JSON instead of measuring")
    parser.add_argument("--note", action="append", default=[], metavar="TEXT",
                        help="add a note to the results (e.g. the run's conditions); repeatable; with --from-json it is saved into that JSON too")
    args = parser.parse_args(argv)
    sections = [s.strip() for s in args.sections.split(",") if s.strip()]
    bad = [s for s in sections if s not in SECTIONS]
    if bad or not sections:
        parser.error(f"--sections must be a comma-separated subset of {', '.join(SECTIONS)}, got {args.sections!r}")
    if args.plot and not args.plot.lower().endswith((".png", ".svg", ".pdf")):
        parser.error(f"--plot must end in .png, .svg or .pdf, got {args.plot!r}")
    if args.from_json and args.quick:
        parser.error("--from-json renders a saved run; it cannot be combined with --quick")
    args.sections = sections
    return args


def run_sections(config: BenchConfig, sections, log=print) -> dict:
    """Run the selected sections; a failing section is recorded, not fatal."""
    results = {"config": {**asdict(config), "vector_n_links": config.vector_links}, "errors": {}, "notes": []}
    has_mujoco, why = bench_sections.mujoco_available()
    results["mujoco"] = {"available": has_mujoco, "reason": why}
    if not has_mujoco:
        results["notes"].append(f"Swimmer-v5 not measured: {why}")

    def attempt(name, fn):
        log(f"[snake-bench] {name} ...", flush=True)
        start = time.perf_counter()
        try:
            results[name] = fn()
        except Exception as exc:  # noqa: BLE001 - one broken section must not hide the others
            results["errors"][name] = f"{type(exc).__name__}: {exc}"
            results["notes"].append(f"section {name} failed: {type(exc).__name__}: {exc}")
        log(f"[snake-bench] {name} done in {time.perf_counter() - start:.1f} s", flush=True)

    if "single" in sections:
        ids = ([bench_sections.SWIMMER_ID] if has_mujoco else []) + [bench_sections.snake_id(n) for n in config.single_links]
        attempt("single_env", lambda: bench_sections.single_env_speeds(ids, config.single_sample_time, config.single_rounds))
    if "vector" in sections:
        attempt("vector_env", lambda: bench_sections.vector_env_speeds(
            config.vector_links, config.vector_num_envs, config.vector_sample_time, config.vector_rounds))
    if "wheels" in sections:
        attempt("wheels", lambda: bench_sections.wheel_model_speeds(
            config.wheels_links, config.wheels_num_envs, config.wheels_sample_time, config.wheels_rounds))
    if "udot" in sections:
        attempt("udot", lambda: bench_sections.udot_scaling(config.udot_n, config.udot_min_time, config.udot_max_call_time))
    if "ppo" in sections:
        attempt("ppo", lambda: bench_sections.ppo_speeds(
            config.ppo_links, config.ppo_num_envs, config.ppo_iterations, config.ppo_rounds, config.ppo_kwargs,
            with_swimmer=has_mujoco))
    if "memory" in sections:
        attempt("memory", lambda: bench_sections.vector_env_memory(
            config.memory_links, config.memory_num_envs, config.memory_steps))
    if "startup" in sections:
        attempt("startup", lambda: bench_sections.startup_time(5, config.startup_runs, config.startup_cold))
        if config.startup_cold:  # the no-slip wheels' kernels are others than the default sliding ones: their own
            attempt("startup_no_slip", lambda: bench_sections.startup_time(5, 1, True, {"wheel_model": "no_slip"}))
    return results


def write_outputs(results: dict, args) -> None:
    if args.json:
        bench_report.write_atomic(args.json, json.dumps(results, indent=2) + "\n")
    if args.plot:
        bench_report.write_plot(results, args.plot)
    if args.markdown:
        page = bench_report.format_markdown(results, args.plot, args.markdown)
        tail = bench_report.kept_tail(args.markdown)  # the hand-written profile stays
        bench_report.write_atomic(args.markdown, page + ("\n" + tail if tail else ""))


def main(argv=None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    if args.from_json:
        try:
            with open(args.from_json) as f:
                results = json.load(f)
        except (OSError, json.JSONDecodeError) as exc:
            print(f"snake-bench: error: --from-json {args.from_json!r} is not a readable JSON file: {exc}", file=sys.stderr)
            return 2
        if args.plot is None and results.get("plot"):
            args.plot = results["plot"]
        results["json"] = args.from_json  # the page's regenerate command names this file
    else:
        config = QUICK if args.quick else FULL
        started = time.time()
        results = {"machine": bench_report.machine_description(),
                   "started_utc": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(started)),
                   "command": "snake-bench " + " ".join(shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:])),
                   "quick": args.quick}
        results.update(run_sections(config, args.sections, log=lambda *a, **k: print(*a, file=sys.stderr, **k)))
        results["duration_s"] = time.time() - started
        results["plot"] = args.plot
        results["json"] = args.json
        if args.quick:
            results["notes"].append("--quick run: tiny sizes, numbers are not meaningful")
    results.setdefault("notes", []).extend(note for note in args.note if note not in results["notes"])
    results["targets"] = bench_report.evaluate_targets(results)
    print(bench_report.format_text(results))
    write_outputs(results, args)
    if args.from_json and args.note:  # keep the notes with the saved run
        bench_report.write_atomic(args.from_json, json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
