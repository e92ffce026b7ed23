"""Compiled O(n) Kane hot path (numba), for single states and batches.

The same sweep as :mod:`snake_env.dynamics.kane`, written with scalars: the
partial velocities (eqs. 12-14), velocities (eqs. 6-7) and bias
accelerations are carried link by link and M, N omega, F (eqs. 9-11) are
accumulated on the fly, so one derivative costs O(n) time and O(1) memory.
Correctness is anchored to the numpy ``kane_paper`` reference by the tests.

Soft joint limits (used by the RL env, off for the paper's model) are a joint
torque -k (phi - limit) - c phidot applied only beyond |phi| > limit, evaluated
inside every RK4 stage so a stiff limit stays stable.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange


@njit(cache=True, nogil=True)
def derivatives(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, q, u, torques, dq, du):
    """Write qdot into dq (n+2,), udot into du (2,); return dK/dt (W).

    The returned power is that of every load (actuators, damping, limits), so
    K(t) minus its integral is constant in the continuous model.

    ``limit`` <= 0 disables the soft joint limits.
    """
    n = m.shape[0]
    # channel values of link k: dV/du1, dV/du2, V, Vb and domega/du1, domega/du2, omega, omegab
    a1 = 1.0
    a2 = 0.0
    V = u[0]
    Vb = 0.0
    b1 = 0.0
    b2 = 1.0
    W = u[1]
    Wb = 0.0
    M00 = 0.0
    M01 = 0.0
    M11 = 0.0
    r0 = 0.0
    r1 = 0.0
    power = 0.0
    for k in range(n):
        # eq. 9 and N omega, accumulated for link k
        mk = m[k]
        Ik = inertia[k]
        M00 += mk * a1 * a1 + Ik * b1 * b1
        M01 += mk * a1 * a2 + Ik * b1 * b2
        M11 += mk * a2 * a2 + Ik * b2 * b2
        f = -c_wheel[k] * V  # rolling resistance (N)
        power += f * V
        r0 += f * a1 - (mk * a1 * Vb + Ik * b1 * Wb)
        r1 += f * a2 - (mk * a2 * Vb + Ik * b2 * Wb)
        dq[k] = W
        if k == n - 1:
            break
        # eqs. 6-7, 13-14 and their time derivative, link k -> k+1
        phi = q[k + 1] - q[k]
        C = math.cos(phi)
        S = math.sin(phi)
        hk = h[k]
        inv_hn = 1.0 / h[k + 1]
        hS = hk * S
        hC = hk * C
        na1 = a1 * C + b1 * hS
        na2 = a2 * C + b2 * hS
        nV = V * C + W * hS
        nVb = Vb * C + Wb * hS
        nb1 = (a1 * S - b1 * hC) * inv_hn
        nb2 = (a2 * S - b2 * hC) * inv_hn
        nW = (V * S - W * hC) * inv_hn
        nWb = (Vb * S - Wb * hC) * inv_hn
        phidot = nW - W
        nVb -= h[k + 1] * nW * phidot
        nWb += nV * phidot * inv_hn
        # eq. 11: joint k acts +T on link k+1, -T on link k
        T = torques[k] - c_joint[k] * phidot
        if limit > 0.0:
            if phi > limit:
                T -= k_limit * (phi - limit) + c_limit * phidot
            elif phi < -limit:
                T -= k_limit * (phi + limit) + c_limit * phidot
        r0 += T * (nb1 - b1)
        r1 += T * (nb2 - b2)
        power += T * phidot
        a1 = na1
        a2 = na2
        V = nV
        Vb = nVb
        b1 = nb1
        b2 = nb2
        W = nW
        Wb = nWb
    det = M00 * M11 - M01 * M01
    du[0] = (M11 * r0 - M01 * r1) / det
    du[1] = (M00 * r1 - M01 * r0) / det
    dq[n] = u[0] * math.cos(q[0])
    dq[n + 1] = u[0] * math.sin(q[0])
    return power


@njit(cache=True, nogil=True)
def rk4_step(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, q, u, torques, dt, n_substeps):
    """Advance one state (q, u) in place by ``n_substeps`` RK4 steps of ``dt``
    with torques held constant; return the work of all loads (J)."""
    nq = q.shape[0]
    k1q = np.empty(nq)
    k2q = np.empty(nq)
    k3q = np.empty(nq)
    k4q = np.empty(nq)
    k1u = np.empty(2)
    k2u = np.empty(2)
    k3u = np.empty(2)
    k4u = np.empty(2)
    qs = np.empty(nq)
    us = np.empty(2)
    work = 0.0
    for _ in range(n_substeps):
        p1 = derivatives(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, q, u, torques, k1q, k1u)
        for j in range(nq):
            qs[j] = q[j] + 0.5 * dt * k1q[j]
        us[0] = u[0] + 0.5 * dt * k1u[0]
        us[1] = u[1] + 0.5 * dt * k1u[1]
        p2 = derivatives(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, qs, us, torques, k2q, k2u)
        for j in range(nq):
            qs[j] = q[j] + 0.5 * dt * k2q[j]
        us[0] = u[0] + 0.5 * dt * k2u[0]
        us[1] = u[1] + 0.5 * dt * k2u[1]
        p3 = derivatives(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, qs, us, torques, k3q, k3u)
        for j in range(nq):
            qs[j] = q[j] + dt * k3q[j]
        us[0] = u[0] + dt * k3u[0]
        us[1] = u[1] + dt * k3u[1]
        p4 = derivatives(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, qs, us, torques, k4q, k4u)
        for j in range(nq):
            q[j] += dt / 6.0 * (k1q[j] + 2.0 * k2q[j] + 2.0 * k3q[j] + k4q[j])
        u[0] += dt / 6.0 * (k1u[0] + 2.0 * k2u[0] + 2.0 * k3u[0] + k4u[0])
        u[1] += dt / 6.0 * (k1u[1] + 2.0 * k2u[1] + 2.0 * k3u[1] + k4u[1])
        work += dt / 6.0 * (p1 + 2.0 * p2 + 2.0 * p3 + p4)
    return work


@njit(cache=True, parallel=True)
def rk4_step_batch(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, q, u, torques, dt, n_substeps, work):
    """Batched :func:`rk4_step`: q (B, n+2), u (B, 2), torques (B, n-1) in place; work (B,) out."""
    for b in prange(q.shape[0]):
        work[b] = rk4_step(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, q[b], u[b], torques[b], dt, n_substeps)


@njit(cache=True, parallel=True)
def derivatives_batch(m, h, inertia, c_joint, c_wheel, q, u, torques, dq, du, power):
    """Batched :func:`derivatives` without joint limits (the paper's model)."""
    for b in prange(q.shape[0]):
        power[b] = derivatives(m, h, inertia, c_joint, c_wheel, 0.0, 0.0, 0.0, q[b], u[b], torques[b], dq[b], du[b])


@njit(cache=True, nogil=True)
def udot_single(m, h, inertia, c_joint, c_wheel, q, u, torques, du):
    """udot (2,) of one state of the paper's model (no joint limits), written into du."""
    dq = np.empty(q.shape[0])
    derivatives(m, h, inertia, c_joint, c_wheel, 0.0, 0.0, 0.0, q, u, torques, dq, du)


@njit(cache=True, nogil=True)
def udot_batch(m, h, inertia, c_joint, c_wheel, q, u, torques, du):
    """udot (B, 2) of the paper's model (no joint limits) for q (B, n+2),
    u (B, 2), torques (B, n-1); serial, for the small batches of ``model.udot``."""
    dq = np.empty(q.shape[1])
    for b in range(q.shape[0]):
        derivatives(m, h, inertia, c_joint, c_wheel, 0.0, 0.0, 0.0, q[b], u[b], torques[b], dq, du[b])


@njit(cache=True, parallel=True)
def udot_batch_parallel(m, h, inertia, c_joint, c_wheel, q, u, torques, du):
    """:func:`udot_batch` spread over threads, for large batches."""
    nq = q.shape[1]
    for b in prange(q.shape[0]):
        dq = np.empty(nq)
        derivatives(m, h, inertia, c_joint, c_wheel, 0.0, 0.0, 0.0, q[b], u[b], torques[b], dq, du[b])
