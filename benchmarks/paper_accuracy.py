"""Precision (Figs. 4-5) and energy error (Fig. 6), Table III run.

Table III: n = 30, 100 s, T_k = 1 N m, L = 0.2 m, m = 1 kg, I = 0.005 kg m^2,
q = 0, u = qdot = 0. The paper gives no step size; we use fixed-step RK4.

* Kane integrates u (eq. 8) with :func:`snake_env.dynamics.simulate`.
* Lagrange integrates (q, qdot) with eq. 27 in
  :func:`snake_env.dynamics.multiplier_sim.simulate_multipliers`, as the paper
  did: the constraints then hold only as well as the integrator keeps
  A qdot = 0. An extra curve adds Baumgarte stabilization; another integrates
  Lagrange's udot in u-space, to separate the formulation from the state
  it is integrated in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from snake_env.dynamics import SnakeModel, simulate
from snake_env.dynamics.multiplier_sim import simulate_multipliers


@dataclass(frozen=True)
class Table3:
    n_links: int = 30
    t_end: float = 100.0  # s
    dt: float = 0.01  # s
    torque: float = 1.0  # N m on every joint
    baumgarte: float = 10.0  # 1/s, the extra stabilized curve


def table3_model(cfg: Table3) -> SnakeModel:
    return SnakeModel(cfg.n_links, mass=1.0, length=0.2, inertia=0.005)


def _head(q, n):
    """(x, y) of link 1's CM and theta_1, each (T,)."""
    return q[:, n], q[:, n + 1], q[:, 0]


def run_precision(cfg: Table3):
    """float32 and float64 responses of Kane (u-space) and Lagrange (q-space)."""
    model = table3_model(cfg)
    n = cfg.n_links
    q0 = np.zeros(n + 2)
    u0 = np.zeros(2)
    qdot0 = model.qdot(q0, u0)
    out = {}
    for dtype in (np.float64, np.float32):
        torque_fn = _constant_torque(n, cfg.torque, dtype)
        kane_run = simulate(model, q0, u0, torque_fn, cfg.t_end, cfg.dt, method="kane", dtype=dtype)
        lag_run = simulate_multipliers(model, q0, qdot0, torque_fn, cfg.t_end, cfg.dt, method="lagrange", dtype=dtype)
        key = np.dtype(dtype).name
        out[("kane", key)] = kane_run
        out[("lagrange", key)] = lag_run
    return out


def run_energy(cfg: Table3, precision_runs):
    """Energy error S(t) - S(0) of Kane, Lagrange (q-space), Lagrange + Baumgarte, Lagrange in u-space."""
    model = table3_model(cfg)
    n = cfg.n_links
    q0 = np.zeros(n + 2)
    u0 = np.zeros(2)
    torque_fn = _constant_torque(n, cfg.torque, np.float64)
    runs = {
        "kane": precision_runs[("kane", "float64")],
        "lagrange": precision_runs[("lagrange", "float64")],
        "lagrange_baumgarte": simulate_multipliers(model, q0, model.qdot(q0, u0), torque_fn, cfg.t_end, cfg.dt,
                                                   method="lagrange", baumgarte=cfg.baumgarte),
        "lagrange_u_space": simulate(model, q0, u0, torque_fn, cfg.t_end, cfg.dt, method="lagrange"),
    }
    return runs


def _constant_torque(n, value, dtype):
    torques = np.full(n - 1, value, dtype=dtype)
    return lambda t, q, u: torques


DEVIATION_THRESHOLDS = (1e-6, 1e-3)  # m: when single and double precision part ways


def first_time_above(t, deviation, threshold):
    """First time (s) the deviation exceeds ``threshold``, or None within the horizon."""
    above = np.nonzero(deviation > threshold)[0]
    return float(t[above[0]]) if above.size else None


def head_deviation(run_a, run_b, n):
    """|head CM of a - head CM of b| (T,) (m)."""
    xa, ya, _ = _head(np.asarray(run_a.q, np.float64), n)
    xb, yb, _ = _head(np.asarray(run_b.q, np.float64), n)
    return np.hypot(xa - xb, ya - yb)


def precision_metrics(runs, n):
    """single vs double precision: max and final head deviation (m), max theta_1
    deviation (rad), and the first times the head deviation exceeds 1 um and 1 mm."""
    metrics = {}
    for method in ("kane", "lagrange"):
        a, b = runs[(method, "float64")], runs[(method, "float32")]
        pos = head_deviation(a, b, n)
        dtheta = np.abs(np.asarray(a.q[:, 0], np.float64) - np.asarray(b.q[:, 0], np.float64))
        metrics[method] = {
            "max_position_deviation_m": float(np.max(pos)),
            "final_position_deviation_m": float(pos[-1]),
            "max_theta1_deviation_rad": float(np.max(dtheta)),
            "final_head_position_m": [float(a.q[-1, n]), float(a.q[-1, n + 1])],
            "time_above_s": {f"{thr:g}": first_time_above(a.t, pos, thr) for thr in DEVIATION_THRESHOLDS},
        }
    return metrics


def sensitivity_metrics(energy_runs, n):
    """Two double-precision runs of the same motion (Kane, and Lagrange's udot in
    u-space) differ only by rounding: how soon do they part ways? This measures how
    strongly the Table III motion amplifies rounding errors."""
    pos = head_deviation(energy_runs["kane"], energy_runs["lagrange_u_space"], n)
    t = energy_runs["kane"].t
    return {"max_position_deviation_m": float(np.max(pos)),
            "time_above_s": {f"{thr:g}": first_time_above(t, pos, thr) for thr in DEVIATION_THRESHOLDS}}


def energy_metrics(runs):
    out = {}
    for name, run in runs.items():
        S = np.asarray(run.energy_function, dtype=np.float64)
        err = S - S[0]
        entry = {"max_abs_energy_error_J": float(np.max(np.abs(err))), "final_energy_error_J": float(err[-1]),
                 "final_kinetic_energy_J": float(run.kinetic_energy[-1])}
        residual = getattr(run, "constraint_residual", None)
        if residual is not None:
            entry["max_constraint_residual_m_per_s"] = float(np.max(residual))
        out[name] = entry
    return out


def plot_precision(fig, runs, method, n, title):
    a, b = runs[(method, "float64")], runs[(method, "float32")]
    xa, ya, _ = _head(a.q, n)
    xb, yb, _ = _head(b.q.astype(np.float64), n)
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    ax1.plot(a.t, xa, "C0-", lw=1.5, label="x, double precision")
    ax1.plot(b.t, xb, "C0--", lw=1.0, label="x, single precision")
    ax1.plot(a.t, ya, "C3-", lw=1.5, label="y, double precision")
    ax1.plot(b.t, yb, "C3--", lw=1.0, label="y, single precision")
    ax1.set_ylabel("head CM position (m)")
    ax1.set_title(title)
    ax1.legend(fontsize=8)
    ax1.grid(True, alpha=0.3)
    dev = np.hypot(xa - xb, ya - yb)
    ax2.semilogy(a.t, np.maximum(dev, 1e-16), "k-", lw=1)
    ax2.set_ylabel("|single - double| (m)")
    ax2.set_xlabel("t (s)")
    ax2.grid(True, which="both", alpha=0.3)


ENERGY_LABELS = {
    "kane": "Kane (u-space, eq. 8)",
    "lagrange": "Lagrange (q-space, eq. 27), as the paper",
    "lagrange_baumgarte": "Lagrange (q-space) + Baumgarte",
    "lagrange_u_space": "Lagrange's udot integrated in u-space",
}


ENERGY_COLORS = {"kane": "C0", "lagrange": "C3", "lagrange_baumgarte": "C2", "lagrange_u_space": "C1"}
# Lagrange in u-space lies on Kane's curve: dashed on top so both stay visible.
ENERGY_STYLES = {"kane": "-", "lagrange": "-", "lagrange_baumgarte": "-", "lagrange_u_space": "--"}


def plot_energy(fig, runs, beta):
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    for name, run in runs.items():
        err = np.abs(np.asarray(run.energy_function, np.float64) - float(run.energy_function[0]))
        label = ENERGY_LABELS[name] + (f" (beta = {beta:g}/s)" if name == "lagrange_baumgarte" else "")
        ax1.semilogy(run.t, np.maximum(err, 1e-18), ENERGY_STYLES[name], color=ENERGY_COLORS[name], lw=1.2, label=label)
    ax1.set_ylabel("|S(t) - S(0)| (J)")
    ax1.set_title("Fig. 6: energy error, Table III (double precision)")
    ax1.legend(fontsize=8)
    ax1.grid(True, which="both", alpha=0.3)
    for name in ("lagrange", "lagrange_baumgarte"):
        run = runs[name]
        ax2.semilogy(run.t, np.maximum(run.constraint_residual, 1e-18), color=ENERGY_COLORS[name], lw=1,
                     label=ENERGY_LABELS[name])
    ax2.set_ylabel("|A qdot| (m/s)")
    ax2.set_xlabel("t (s)")
    ax2.legend(fontsize=8)
    ax2.grid(True, which="both", alpha=0.3)
