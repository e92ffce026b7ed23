"""Learning-curve and trajectory figures (matplotlib, Agg: no display needed)."""

from __future__ import annotations

import csv
from pathlib import Path

import matplotlib
import matplotlib.ticker

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from snake_env.train.atomic import atomic_path  # noqa: E402

STEP_KEY = "time/total_timesteps"
CURVES = (("rollout/ep_rew_mean", "training episodes (mean return)"),
          ("eval/mean_reward", "deterministic evaluation (mean return)"))


def progress_files(log_dir) -> list[Path]:
    """CSV logs of every training segment, oldest first (``--resume`` adds one)."""
    log_dir = Path(log_dir)
    return sorted(log_dir.glob("segment_*/progress.csv"), key=lambda p: int(p.parent.name.split("_")[1]))


def read_curves(log_dir) -> dict[str, list[tuple[int, float]]]:
    curves = {key: [] for key, _ in CURVES}
    for path in progress_files(log_dir):
        with open(path, newline="") as handle:
            for row in csv.DictReader(handle):
                step = row.get(STEP_KEY)
                if not step:
                    continue
                for key in curves:
                    value = row.get(key)
                    if value not in (None, ""):
                        curves[key].append((int(float(step)), float(value)))
    return curves


def save_figure(fig, path) -> None:
    path = Path(path)
    with atomic_path(path, suffix=path.suffix or ".png") as tmp:
        fig.savefig(tmp, dpi=110, format=(path.suffix.lstrip(".") or "png"))
    plt.close(fig)


def plot_learning_curve(log_dir, path, title: str) -> bool:
    """Plot episode return against environment steps; False if nothing was logged."""
    curves = read_curves(log_dir)
    if not any(curves.values()):
        return False
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for key, label in CURVES:
        points = sorted(curves[key])
        if points:
            steps, values = zip(*points)
            ax.plot(steps, values, marker="o" if key.startswith("eval") else None, markersize=3, label=label)
    ax.set_xlabel("environment steps")
    ax.set_ylabel("episode return (1000 steps)")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.tight_layout()
    save_figure(fig, path)
    return True


def plot_trajectories(trajectories, path, title: str) -> None:
    """CM paths (x, y in m), one line per episode, equal axes."""
    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    for index, xy in enumerate(trajectories):
        ax.plot(xy[:, 0], xy[:, 1], label=f"episode {index}")
        ax.plot(xy[0, 0], xy[0, 1], "k.", markersize=6)
    ax.set_xlabel("x of the centre of mass (m)")
    ax.set_ylabel("y of the centre of mass (m)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    if len(trajectories) <= 10:
        ax.legend(fontsize="small")
    fig.tight_layout()
    save_figure(fig, path)


def plot_campaign(groups, baselines, path, episode_steps: int = 1000) -> None:
    """One panel per env: deterministic evaluation speed (eval return / episode
    steps, m/s, as ctrl cost is ~1e-4 of it) of every run against env steps,
    and the serpenoid baseline as a horizontal line.

    ``groups``: {(env, algo): [evaluations.npz paths]}; ``baselines``: {env: m/s}.
    """
    import numpy as np

    envs = sorted({env for env, _ in groups})
    fig, axes = plt.subplots(1, len(envs), figsize=(5.2 * len(envs), 3.8), squeeze=False)
    colors = {"ppo": "tab:blue", "sac": "tab:orange"}
    for ax, env in zip(axes[0], envs):
        for (group_env, algo), files in sorted(groups.items()):
            if group_env != env:
                continue
            for index, npz in enumerate(files):
                data = np.load(npz)
                ax.plot(data["timesteps"], data["results"].mean(axis=1) / episode_steps, color=colors.get(algo),
                        alpha=0.8, linewidth=1.2, label=algo.upper() if index == 0 else None)
        if env in baselines:
            ax.axhline(baselines[env], color="k", linestyle="--", linewidth=1, label="serpenoid (searched)")
        ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(lambda x, _: f"{x / 1000:.0f}k"))
        ax.set_xlabel("environment steps")
        ax.set_ylabel("mean forward speed of the CM (m/s)")
        ax.set_title(env)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize="small")
    fig.tight_layout()
    save_figure(fig, path)


def plot_speed_vs_n(learned, serpenoid, path, earlier=None) -> None:
    """Mean forward speed of the CM (m/s) against the number of links n.

    ``learned``: {(algo, label): {n: [speed per seed]}} (each seed a dot, the
    mean a line); ``serpenoid``: {n: m/s} of the searched gait; ``earlier``:
    like ``learned``, drawn hollow (speeds measured in an earlier campaign).
    Log speed axis: a speed below ``floor`` (m/s, also a backward one) is drawn at the floor."""
    import numpy as np

    floor = 0.005
    fig, ax = plt.subplots(figsize=(6.8, 4.4))
    colors = {"ppo": "tab:blue", "sac": "tab:orange"}
    ns = sorted(serpenoid)
    if ns:
        ax.plot(ns, [max(serpenoid[n], floor) for n in ns], "k--s", markersize=5, linewidth=1.2, label="serpenoid (searched)")
    for hollow, groups in ((False, learned), (True, earlier or {})):
        for (algo, label), by_n in sorted(groups.items()):
            points = sorted(by_n.items())
            if not points:
                continue
            color, marker = colors.get(algo, "tab:green"), "o"
            if algo in colors and "JointPolicy" in label:  # an entry of PPO or SAC that runs the shared policy
                color, marker = {"ppo": "tab:purple", "sac": "tab:red"}[algo], "D"
            for n, speeds in points:
                ax.plot([n] * len(speeds), np.maximum(speeds, floor), marker, color=color, markersize=4,
                        markerfacecolor="none" if hollow else color, alpha=0.8)
            means = [max(float(np.mean(s)), floor) for _, s in points]
            ax.plot([n for n, _ in points], means, "-" if not hollow else ":", color=color, linewidth=1.2, label=label,
                    marker=None if marker == "o" else marker, markersize=4)
    ax.set_xlabel("number of links n")
    ax.set_ylabel("mean forward speed of the CM (m/s)")
    ax.set_yscale("log")
    ax.axhline(floor, color="grey", linewidth=0.8, linestyle=":")
    ax.set_xticks(sorted(set(ns) | {n for g in (learned, earlier or {}) for by_n in g.values() for n in by_n}))
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize="small")
    ax.set_title(f"Learned (deterministic) and serpenoid speed by length; < {floor} m/s drawn at {floor}", fontsize="medium")
    fig.tight_layout()
    save_figure(fig, path)
