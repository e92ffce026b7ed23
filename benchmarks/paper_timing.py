"""CPU time of one udot evaluation against n (paper Figs. 2-3, Table II).

All four formulations are timed as the same kind of code: vectorised numpy
with Python loops over links (``kane.udot_sweep`` for the O(n) Kane sweep,
not the compiled kernel), so the comparison is of algorithms, not of
compilers. Two regimes are measured:

* batch 1: one state per call, as the paper's simulation does; per-call
  interpreter overhead (proportional to the number of numpy operations) is
  a large part of the time;
* batch B: B states per call, time divided by B; arithmetic dominates, which
  is where operation counts show.

The compiled float64 Kane kernel is timed as an extra reference curve.
"""

from __future__ import annotations

import time

import numpy as np

from snake_env.dynamics import SnakeModel, kane, kane_paper, lagrange, newton_euler

TIMED = {
    "kane_paper": kane_paper.udot,
    "kane": kane.udot_sweep,
    "lagrange": lagrange.udot,
    "newton_euler": newton_euler.udot,
    "kane_compiled": kane.udot,  # float64 -> numba kernel
}
TIMED_LABELS = {
    "kane_paper": "Kane (paper, O(n^2))",
    "kane": "Kane O(n) sweep",
    "lagrange": "Lagrange (eq. 27)",
    "newton_euler": "Newton-Euler (Walker-Orin)",
    "kane_compiled": "Kane O(n), compiled (numba)",
}


def table2_state(n: int, t: float = 1.0, batch: int = 1):
    """Table II: q_k = pi (-1)^k / 6, x = y = 0, u = 0, T_k = sin(t) / (n - k) (N m)."""
    k = np.arange(1, n + 1)
    q = np.concatenate([np.pi * (-1.0) ** k / 6.0, np.zeros(2)])
    torques = np.sin(t) / (n - np.arange(1, n))
    return (np.broadcast_to(q, (batch, n + 2)).copy(), np.zeros((batch, 2)),
            np.broadcast_to(torques, (batch, n - 1)).copy())


def time_call(fn, min_time: float, repeats: int) -> float:
    """Best-of-``repeats`` seconds per call, each repeat running >= ``min_time`` s."""
    fn()  # warm-up (and JIT compilation for the compiled kernel)
    number = 1
    while True:
        start = time.perf_counter()
        for _ in range(number):
            fn()
        elapsed = time.perf_counter() - start
        if elapsed >= min_time:
            break
        number *= 2
    best = elapsed / number
    for _ in range(repeats - 1):
        start = time.perf_counter()
        for _ in range(number):
            fn()
        best = min(best, (time.perf_counter() - start) / number)
    return best


def measure(ns, batch_sizes=(1, 64), min_time: float = 0.05, repeats: int = 5, methods=tuple(TIMED)):
    """{batch: {method: [seconds per state for each n]}}."""
    out = {}
    for batch in batch_sizes:
        out[batch] = {method: [] for method in methods}
        for n in ns:
            model = SnakeModel(n, mass=1.0, length=0.2, inertia=0.005)
            q, u, torques = table2_state(n, batch=batch)
            for method in methods:
                fn = TIMED[method]
                seconds = time_call(lambda: fn(model, q, u, torques), min_time, repeats)
                out[batch][method].append(seconds / batch)
    return out


def linear_fit(x, y):
    """(slope, intercept, R^2) of a least-squares line."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    slope, intercept = np.polyfit(x, y, 1)
    pred = slope * x + intercept
    ss_res = float(np.sum((y - pred) ** 2))
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    return float(slope), float(intercept), (1.0 - ss_res / ss_tot) if ss_tot > 0 else 1.0


def plot_cpu_time(ax, ns, timings):
    styles = {1: "-", }
    for batch, per_method in timings.items():
        ls = styles.get(batch, "--")
        for method, seconds in per_method.items():
            ax.semilogy(ns, np.asarray(seconds) * 1e6, ls, marker="o", ms=3,
                        label=f"{TIMED_LABELS[method]}, batch {batch}", color=COLORS[method])
    ax.set_xlabel("number of links n")
    ax.set_ylabel("CPU time per state and udot evaluation (us)")
    ax.set_title("Fig. 2: CPU time (Table II, solid: one state per call, dashed: per state in a batch)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, ncol=2)


def plot_cpu_ratio(axes, ns, timings, op_ratio=None):
    """Two panels, linear axes (the paper's claim is a linear ratio): Lagrange
    over Kane (paper) and over the O(n) Kane sweep."""
    for ax, ref in zip(axes, ("kane_paper", "kane")):
        for batch, per_method in timings.items():
            ls = "-" if batch == 1 else "--"
            ratio = np.asarray(per_method["lagrange"]) / np.asarray(per_method[ref])
            ax.plot(ns, ratio, ls, marker="o", ms=3, color="C3" if batch == 1 else "C0",
                    label=f"measured, batch {batch}")
            slope, intercept, r2 = linear_fit(ns, ratio)
            ax.plot(ns, slope * np.asarray(ns) + intercept, ":", lw=1, color="C3" if batch == 1 else "C0",
                    label=f"line fit, batch {batch}: {slope:.2f} n + {intercept:.1f} (R^2 {r2:.2f})")
        if op_ratio is not None:
            ax.plot(ns, op_ratio[ref], "k-.", lw=1, label="operation-count ratio (M + A)")
        ax.set_xlabel("number of links n")
        ax.set_ylabel("CPU time ratio")
        ax.set_title(f"Lagrange / {TIMED_LABELS[ref]}", fontsize=10)
        ax.set_ylim(bottom=0)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)


COLORS = {"kane_paper": "C0", "kane": "C1", "lagrange": "C3", "newton_euler": "C2", "kane_compiled": "C7"}
