"""Fixed-step integrators and the paper's simulation driver.

The state is (q, u) (eq. 1-2) plus the work W of all loads, integrated with
the same RK4 stages so the paper's energy function (section VI.3)

    S(t) = K(t) - integral_0^t sum_k T_k (omega_{k+1} - omega_k) dt

is evaluated to the integrator's own order. With damping, W also holds the
(negative) work of the damping forces, so S stays a conservation check.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .forces import generalized_power
from .kane import PARALLEL_BATCH
from .validation import state_array


@dataclass(frozen=True)
class Simulation:
    """Output of :func:`simulate`: times (T,), q (T, ..., n+2), u (T, ..., 2),
    kinetic energy K (T, ...) (J), load work W (T, ...) (J), S = K - W (J)."""

    t: np.ndarray
    q: np.ndarray
    u: np.ndarray
    kinetic_energy: np.ndarray
    work: np.ndarray

    @property
    def energy_function(self) -> np.ndarray:
        return self.kinetic_energy - self.work


def _derivatives(model, q, u, torques, method):
    """(qdot, udot, power of all loads)."""
    m, h, inertia, c_joint, c_wheel = model.parameters(u.dtype)
    V, W = model.link_velocities(q, u)
    qdot = np.concatenate([W, (u[..., 0] * np.cos(q[..., 0]))[..., None], (u[..., 0] * np.sin(q[..., 0]))[..., None]], axis=-1)
    power = generalized_power(c_joint, c_wheel, torques, V, W)
    return qdot, model.udot(q, u, torques, method=method), power


def _check_positive(name, value, unit):
    if not (isinstance(value, (int, float, np.floating, np.integer)) and np.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a finite number > 0 ({unit}), got {value!r}")
    return float(value)


def rk4_step(model, q, u, torques, dt: float, method: str = "kane"):
    """One classical RK4 step with torques held constant over the step.

    Works for any formulation and dtype (the numpy path); returns (q, u, work).
    """
    dt = _check_positive("dt", dt, "s")
    k1 = _derivatives(model, q, u, torques, method)
    k2 = _derivatives(model, q + 0.5 * dt * k1[0], u + 0.5 * dt * k1[1], torques, method)
    k3 = _derivatives(model, q + 0.5 * dt * k2[0], u + 0.5 * dt * k2[1], torques, method)
    k4 = _derivatives(model, q + dt * k3[0], u + dt * k3[1], torques, method)
    c = np.asarray(dt / 6.0, dtype=u.dtype)
    q_new = q + c * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
    u_new = u + c * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
    work = c * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
    return q_new, u_new, work


def simulate(model, q0, u0, torque_fn, t_end: float, dt: float, method: str = "kane", dtype=None):
    """Integrate eq. 8 with fixed-step RK4 from (q0, u0) to ``t_end``.

    Args:
        model: a :class:`SnakeModel`.
        q0, u0: initial state, (..., n+2) and (..., 2); batch dimensions allowed.
        torque_fn: ``torque_fn(t, q, u) -> torques`` of shape (..., n-1) (N m),
            evaluated at every RK4 stage (the paper's T_k = sin(t)/(n-k) is smooth).
        t_end: final time (s); dt: step (s).
        method: formulation name, see :meth:`SnakeModel.udot`.
        dtype: np.float32 to integrate in single precision (paper Figs. 4-5);
            default float64. float64 "kane" runs use the compiled kernel.

    Returns a :class:`Simulation`; ``energy_function`` is the paper's S(t).
    """
    t_end = _check_positive("t_end", t_end, "s")
    dt = _check_positive("dt", dt, "s")
    if not callable(torque_fn):
        raise ValueError(f"torque_fn must be callable as torque_fn(t, q, u), got {torque_fn!r}")
    dtype = np.dtype(np.float64 if dtype is None else dtype)
    if dtype not in (np.float32, np.float64):
        raise ValueError(f"dtype must be float32 or float64, got {dtype}")
    q = state_array("q0", q0, model.nq).astype(dtype)
    u = state_array("u0", u0, 2).astype(dtype)
    batch = np.broadcast_shapes(q.shape[:-1], u.shape[:-1])
    q = np.broadcast_to(q, batch + (model.nq,)).copy()
    u = np.broadcast_to(u, batch + (2,)).copy()
    n_steps = int(round(t_end / dt))
    if n_steps < 1:
        raise ValueError(f"t_end must be at least dt, got t_end={t_end}, dt={dt}")

    def torques_at(t, q, u):
        T = state_array("torque_fn(t, q, u)", np.asarray(torque_fn(t, q, u)), model.n_joints)
        return np.broadcast_to(T.astype(dtype, copy=False), batch + (model.n_joints,))

    if method == "kane" and dtype == np.float64:
        deriv = _compiled_derivatives(model, batch)
    else:
        model.udot(q, u, torques_at(0.0, q, u), method=method)  # validates the method name once

        def deriv(q, u, T):
            return _derivatives(model, q, u, T, method)

    qs = np.empty((n_steps + 1,) + q.shape, dtype)
    us = np.empty((n_steps + 1,) + u.shape, dtype)
    work = np.zeros((n_steps + 1,) + batch, dtype)
    qs[0], us[0] = q, u
    w = np.zeros(batch, dtype)
    half = dtype.type(0.5 * dt)
    full = dtype.type(dt)
    sixth = dtype.type(dt / 6.0)
    for step in range(n_steps):
        t = step * dt
        k1 = deriv(q, u, torques_at(t, q, u))
        q2, u2 = q + half * k1[0], u + half * k1[1]
        k2 = deriv(q2, u2, torques_at(t + 0.5 * dt, q2, u2))
        q3, u3 = q + half * k2[0], u + half * k2[1]
        k3 = deriv(q3, u3, torques_at(t + 0.5 * dt, q3, u3))
        q4, u4 = q + full * k3[0], u + full * k3[1]
        k4 = deriv(q4, u4, torques_at(t + dt, q4, u4))
        q = q + sixth * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        u = u + sixth * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        w = w + sixth * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
        qs[step + 1], us[step + 1], work[step + 1] = q, u, w
    t = np.arange(n_steps + 1) * dt
    K = model.kinetic_energy(qs, us)
    return Simulation(t=t, q=qs, u=us, kinetic_energy=K, work=work)


def _compiled_derivatives(model, batch):
    """Derivative function backed by the numba kernel, for float64 batches."""
    from . import compiled

    m, h, inertia, c_joint, c_wheel = model.parameters(np.float64)
    size = int(np.prod(batch)) if batch else 1
    kernel = compiled.derivatives_batch if size >= PARALLEL_BATCH else compiled.derivatives_batch_serial

    def deriv(q, u, T):
        qf = np.ascontiguousarray(q.reshape(size, -1))
        uf = np.ascontiguousarray(u.reshape(size, 2))
        Tf = np.ascontiguousarray(T.reshape(size, -1))
        dq = np.empty_like(qf)
        du = np.empty_like(uf)
        power = np.empty(size)
        kernel(m, h, inertia, c_joint, c_wheel, qf, uf, Tf, dq, du, power)
        return dq.reshape(q.shape), du.reshape(u.shape), power.reshape(batch)

    return deriv
