"""Evaluate one saved policy on snakes of many lengths, against each length's serpenoid gait.

    python -m snake_env.train.transfer RUN --sizes 3 5 8 10 12 16 20 25 30 --episodes 5 \\
        --json transfer.json --plot transfer.png

For a ``policy: JointPolicy`` run (one set of weights for any n, :mod:`snake_env.train.joint_policy`):
each size runs on its forward id (``snake_env/Snake{n}-vN``, N the run's version) or, for a length
with no id of its own, on the generic id with ``n_links=n``, by ``snake-eval`` (deterministic, episode
seeds 0..episodes-1); the serpenoid searched for that length on the same physics
(``configs/serpenoid.yaml``; ``python -m snake_env.agents.search --env snake_env/Snake-vN --n-links n``
for a new length) runs on the same episode seeds. Prints a markdown table (speed, ratio, and whether
the run trained on that size, its gait's frequency, the share of wheel-steps outside the friction cone and,
on wheels that slide, the share that slid); ``--plot`` draws the ratio against n. ``--version vN`` runs
every size on another version's physics (e.g. a run trained on v3 on v4's wheels that slide), against
the serpenoids searched on that version. Evaluations are cached as JSON
beside ``--json`` (``<json stem>_cache/``), so a rerun only adds what is missing.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

from snake_env.atomic import atomic_write_text


def _size_id(version: str, n: int) -> str:
    """The forward id of length n at ``version`` (v3, 12 -> snake_env/Snake12-v3)."""
    return f"snake_env/Snake{n}-{version}"


def run_version(run: Path) -> str:
    """The version of the id a run was trained on (snake_env/Snake-v3 -> v3)."""
    import yaml

    return yaml.safe_load((run / "config.yaml").read_text())["env_id"].rsplit("-", 1)[-1]


def forward_versions() -> list[str]:
    """The versions of the generic forward id ``snake_env/Snake-vN`` in the registry, oldest first (v2, v3, ...)."""
    import gymnasium as gym

    import snake_env  # noqa: F401  (registers the ids)

    found = (re.fullmatch(r"snake_env/Snake-(v\d+)", env_id) for env_id in gym.registry)
    return sorted((m[1] for m in found if m), key=lambda v: int(v[1:]))


def evaluate_sizes(run: Path, sizes: list[int], episodes: int, cache: Path, version: str | None = None) -> list[dict]:
    """One row per size: the run's and the serpenoid's speed (m/s), their ratio, whether trained on it;
    on ``version``'s physics (default: the run's)."""
    import yaml

    from snake_env.train.evaluate import main as evaluate_main
    from snake_env.train.results_table import env_arguments

    config = yaml.safe_load((run / "config.yaml").read_text())
    trained = set(config.get("n_links_set") or [])
    if not trained and (m := re.search(r"Snake(\d+)-v\d+$", config["env_id"])):
        trained = {int(m[1])}
    own = config["env_id"].rsplit("-", 1)[-1]
    version = version or own
    cache = cache / version if version != own else cache  # the run's own version keeps the cache's old place
    cache.mkdir(parents=True, exist_ok=True)

    def cached(name: str, argv: list[str]) -> dict:
        path = cache / f"{name}.json"
        if not path.is_file():
            if evaluate_main([*argv, "--episodes", str(episodes), "--json", str(path)]) != 0:
                raise SystemExit(f"evaluation failed: {argv}")
        return json.loads(path.read_text())

    rows = []
    for n in sizes:
        target = env_arguments(_size_id(version, n))
        policy = cached(f"policy_n{n}_{episodes}", [str(run), *target])
        serpenoid = cached(f"serpenoid_n{n}_{episodes}", ["--baseline", "serpenoid", *target])
        speed, reference = policy["mean_forward_velocity"], serpenoid["mean_forward_velocity"]
        rows.append({"n_links": n, "trained_on": n in trained, "speed": speed, "serpenoid": reference,
                     "ratio": speed / reference if reference > 0 else float("nan"),
                     "joint_frequency": policy.get("mean_dominant_joint_frequency"),
                     "outside_cone": policy.get("mean_outside_friction_cone_share"),
                     "sliding": policy.get("mean_wheel_slip_share")})
    return rows


def markdown(rows: list[dict]) -> str:
    lines = ["| n | trained on it | v_x (m/s) | serpenoid v_x (m/s) | ratio | joint freq. (Hz) | outside the cone "
             "| sliding |", "|---|---|---|---|---|---|---|---|"]

    def share(value):
        return "-" if value is None else f"{value:.1%}"

    for r in rows:
        freq = "-" if r["joint_frequency"] is None else f"{r['joint_frequency']:.2f}"
        lines.append(f"| {r['n_links']} | {'yes' if r['trained_on'] else 'no'} | {r['speed']:.3f} | "
                     f"{r['serpenoid']:.3f} | {r['ratio']:.2f} | {freq} | {share(r['outside_cone'])} "
                     f"| {share(r.get('sliding'))} |")
    return "\n".join(lines)


def plot(rows: list[dict], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from snake_env.atomic import save_figure

    fig, ax = plt.subplots(figsize=(7, 4))
    n = [r["n_links"] for r in rows]
    ax.plot(n, [r["ratio"] for r in rows], "-", color="tab:blue", label="policy / serpenoid")
    for trained in (True, False):
        sel = [r for r in rows if r["trained_on"] == trained]
        ax.plot([r["n_links"] for r in sel], [r["ratio"] for r in sel], "o", color="tab:blue",
                fillstyle="full" if trained else "none", label="trained on it" if trained else "zero-shot")
    ax.axhline(1.0, color="k", ls="--", lw=1, label="serpenoid")
    ax.set_xlabel("number of links n")
    ax.set_ylabel("forward speed / serpenoid's")
    ax.set_xticks(n)
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=9)
    save_figure(fig, str(path))
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m snake_env.train.transfer", description=__doc__.split("\n\n")[0])
    parser.add_argument("run", help="run directory (snake-train --run-dir)")
    parser.add_argument("--sizes", type=int, nargs="+", required=True, help="numbers of links to evaluate on")
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--json", required=True, help="write the rows here (the cache goes beside it)")
    parser.add_argument("--plot", help="draw the ratio against n (png, svg or pdf)")
    parser.add_argument("--version", help="evaluate on this version's physics, e.g. v4 (default: the run's)")
    args = parser.parse_args(argv)
    run = Path(args.run)
    if not (run / "config.yaml").is_file():
        parser.exit(2, f"{parser.prog}: error: run: {run} is not a run directory (no config.yaml)\n")
    if any(n < 2 for n in args.sizes) or args.episodes < 1:
        parser.exit(2, f"{parser.prog}: error: --sizes must be integers >= 2 and --episodes >= 1\n")
    version = args.version or run_version(run)
    if version not in (allowed := forward_versions()):
        parser.exit(2, f"{parser.prog}: error: --version must be one of {', '.join(allowed)}, got {args.version!r}\n")
    out = Path(args.json)
    rows = evaluate_sizes(run, args.sizes, args.episodes, out.parent / f"{out.stem}_cache", version)
    atomic_write_text(out, json.dumps({"run": str(run), "version": version, "episodes": args.episodes, "rows": rows},
                                      indent=2))
    print(markdown(rows))
    if args.plot:
        plot(rows, Path(args.plot), f"{run.name} on {version}: deterministic policy, {args.episodes} episodes per size")
    return 0


if __name__ == "__main__":
    sys.exit(main())
