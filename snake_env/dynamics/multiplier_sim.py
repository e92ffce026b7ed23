"""q-space simulation of the multiplier formulations (paper sections IV-V, VI.3).

Kane's equations integrate the 2 generalized speeds u, so the no-side-slip
constraints hold by construction. The Lagrange and Newton-Euler formulations
integrate the n + 2 coordinates and their rates (q, qdot): the constraints
enter only differentiated, A qddot = -Adot qdot (eq. 27), so integration
error lets A qdot drift away from 0. The constraint forces then do work and
the energy function S = K - integral of power (section VI.3) drifts: the
cause the paper gives for Lagrange's energy error (Fig. 6). An optional
Baumgarte gain beta adds -beta A qdot to the constraint row, which damps the
drift (first-order stabilization; the constraints are on velocities only).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import lagrange, newton_euler
from .validation import check_choice, state_array

FORMULATIONS = {"lagrange": lagrange.qddot, "newton_euler": newton_euler.qddot}


@dataclass(frozen=True)
class MultiplierSimulation:
    """Times (T,), q and qdot (T, ..., n+2), kinetic energy of eq. 22 (T, ...) (J),
    load work (T, ...) (J) and the constraint residual |A qdot| (T, ...) (m/s)."""

    t: np.ndarray
    q: np.ndarray
    qdot: np.ndarray
    kinetic_energy: np.ndarray
    work: np.ndarray
    constraint_residual: np.ndarray

    @property
    def energy_function(self) -> np.ndarray:
        """The paper's S(t) = K(t) - integral of the load power (J)."""
        return self.kinetic_energy - self.work

    def u(self) -> np.ndarray:
        """(V_1, thetadot_1) (T, ..., 2): V_1 = e_1 . (xdot, ydot)."""
        n = self.q.shape[-1] - 2
        th = self.q[..., 0]
        V1 = np.cos(th) * self.qdot[..., n] + np.sin(th) * self.qdot[..., n + 1]
        return np.stack([V1, self.qdot[..., 0]], axis=-1)


def kinetic_energy(model, q, qdot):
    """K = 1/2 qdot^T M(q) qdot (J), eq. 22 for the unconstrained chain."""
    M = lagrange.inertia_matrix(model, q)
    return 0.5 * np.sum(qdot * lagrange.matvec(M, qdot), axis=-1)


def constraint_residual(model, q, qdot):
    """Euclidean norm of A(q) qdot (m/s): the side-slip speeds, 0 when consistent."""
    _, h, _, _, _ = model.parameters(q.dtype)
    _, e_perp = lagrange.unit_vectors(q[..., : model.n_links])
    A = lagrange.constraint_matrix(lagrange.lever_arms(h), e_perp)
    r = lagrange.matvec(A, qdot)
    return np.sqrt(np.sum(r * r, axis=-1))


def _positive(name, value, unit):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)) \
            or not np.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a finite number > 0 ({unit}), got {value!r}")
    return float(value)


def simulate_multipliers(model, q0, qdot0, torque_fn, t_end: float, dt: float, method: str = "lagrange",
                         dtype=None, baumgarte: float = 0.0) -> MultiplierSimulation:
    """Integrate (q, qdot) with fixed-step RK4 using eq. 27 at every stage.

    Args:
        model: a :class:`SnakeModel`.
        q0, qdot0: initial coordinates and rates, (..., n+2) each; use
            ``model.qdot(q0, u0)`` for a constraint-consistent start.
        torque_fn: ``torque_fn(t, q, qdot) -> torques`` (..., n-1) (N m).
        t_end, dt: horizon and step (s).
        method: "lagrange" or "newton_euler".
        dtype: np.float32 or np.float64 (default) for the whole integration.
        baumgarte: gain beta >= 0 (1/s) of the constraint stabilization; 0 = the paper.
    """
    check_choice("method", method, FORMULATIONS)
    t_end = _positive("t_end", t_end, "s")
    dt = _positive("dt", dt, "s")
    if not callable(torque_fn):
        raise ValueError(f"torque_fn must be callable as torque_fn(t, q, qdot), got {torque_fn!r}")
    if isinstance(baumgarte, bool) or not isinstance(baumgarte, (int, float, np.floating, np.integer)) \
            or not np.isfinite(baumgarte) or baumgarte < 0:
        raise ValueError(f"baumgarte must be a finite number >= 0 (1/s), got {baumgarte!r}")
    dtype = np.dtype(np.float64 if dtype is None else dtype)
    if dtype not in (np.float32, np.float64):
        raise ValueError(f"dtype must be float32 or float64, got {dtype}")
    n_steps = int(round(t_end / dt))
    if n_steps < 1:
        raise ValueError(f"t_end must be at least dt, got t_end={t_end}, dt={dt}")
    q = state_array("q0", q0, model.nq).astype(dtype)
    qd = state_array("qdot0", qdot0, model.nq).astype(dtype)
    batch = np.broadcast_shapes(q.shape[:-1], qd.shape[:-1])
    q = np.broadcast_to(q, batch + (model.nq,)).copy()
    qd = np.broadcast_to(qd, batch + (model.nq,)).copy()
    accel = FORMULATIONS[method]
    beta = float(baumgarte)

    def torques_at(t, q, qd):
        T = state_array("torque_fn(t, q, qdot)", np.asarray(torque_fn(t, q, qd)), model.n_joints)
        return np.broadcast_to(T.astype(dtype, copy=False), batch + (model.n_joints,))

    def deriv(t, q, qd):
        T = torques_at(t, q, qd)
        return qd, accel(model, q, qd, T, baumgarte=beta), lagrange.power(model, q, qd, T)

    qs = np.empty((n_steps + 1,) + q.shape, dtype)
    qds = np.empty((n_steps + 1,) + qd.shape, dtype)
    work = np.zeros((n_steps + 1,) + batch, dtype)
    qs[0], qds[0] = q, qd
    w = np.zeros(batch, dtype)
    half, full, sixth = dtype.type(0.5 * dt), dtype.type(dt), dtype.type(dt / 6.0)
    for step in range(n_steps):
        t = step * dt
        k1 = deriv(t, q, qd)
        k2 = deriv(t + 0.5 * dt, q + half * k1[0], qd + half * k1[1])
        k3 = deriv(t + 0.5 * dt, q + half * k2[0], qd + half * k2[1])
        k4 = deriv(t + dt, q + full * k3[0], qd + full * k3[1])
        q = q + sixth * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        qd = qd + sixth * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        w = w + sixth * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
        qs[step + 1], qds[step + 1], work[step + 1] = q, qd, w
    t = np.arange(n_steps + 1) * dt
    K = kinetic_energy(model, qs, qds)
    residual = constraint_residual(model, qs, qds)
    return MultiplierSimulation(t=t, q=qs, qdot=qds, kinetic_energy=K, work=work, constraint_residual=residual)
