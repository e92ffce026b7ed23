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
    workspace = np.empty(rk4_workspace_size(q.shape[0]))
    return rk4_step_workspace(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, q, u, torques, dt, n_substeps,
                              workspace)


@njit(cache=True, nogil=True)
def rk4_workspace_size(nq):
    """Scratch floats :func:`rk4_step_workspace` needs for nq = n + 2 coordinates."""
    return 3 * nq + 6


@njit(cache=True, nogil=True)
def rk4_step_workspace(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, q, u, torques, dt, n_substeps,
                       workspace):
    """:func:`rk4_step` with caller-owned scratch (``rk4_workspace_size(n+2)``
    floats), so a loop over many steps or snakes allocates nothing.

    The four stage derivatives are summed into one accumulator as they come
    (k1 + 2 k2 + 2 k3 + k4), so only the stage state, the current stage
    derivative and the sum are stored.
    """
    nq = q.shape[0]
    qs = workspace[0:nq]
    kq = workspace[nq:2 * nq]
    acc_q = workspace[2 * nq:3 * nq]
    us = workspace[3 * nq:3 * nq + 2]
    ku = workspace[3 * nq + 2:3 * nq + 4]
    acc_u = workspace[3 * nq + 4:3 * nq + 6]
    half = 0.5 * dt
    sixth = dt / 6.0
    work = 0.0
    for _ in range(n_substeps):
        # stage 1 at (q, u)
        p1 = derivatives(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, q, u, torques, kq, ku)
        for j in range(nq):
            acc_q[j] = kq[j]
            qs[j] = q[j] + half * kq[j]
        acc_u[0] = ku[0]
        acc_u[1] = ku[1]
        us[0] = u[0] + half * ku[0]
        us[1] = u[1] + half * ku[1]
        # stage 2 at the midpoint predicted by stage 1
        p2 = derivatives(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, qs, us, torques, kq, ku)
        for j in range(nq):
            acc_q[j] += 2.0 * kq[j]
            qs[j] = q[j] + half * kq[j]
        acc_u[0] += 2.0 * ku[0]
        acc_u[1] += 2.0 * ku[1]
        us[0] = u[0] + half * ku[0]
        us[1] = u[1] + half * ku[1]
        # stage 3 at the midpoint predicted by stage 2
        p3 = derivatives(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, qs, us, torques, kq, ku)
        for j in range(nq):
            acc_q[j] += 2.0 * kq[j]
            qs[j] = q[j] + dt * kq[j]
        acc_u[0] += 2.0 * ku[0]
        acc_u[1] += 2.0 * ku[1]
        us[0] = u[0] + dt * ku[0]
        us[1] = u[1] + dt * ku[1]
        # stage 4 at the end point predicted by stage 3
        p4 = derivatives(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, qs, us, torques, kq, ku)
        for j in range(nq):
            q[j] += sixth * (acc_q[j] + kq[j])
        u[0] += sixth * (acc_u[0] + ku[0])
        u[1] += sixth * (acc_u[1] + ku[1])
        work += sixth * (p1 + 2.0 * p2 + 2.0 * p3 + p4)
    return work


@njit(cache=True, parallel=True)
def rk4_step_batch(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, q, u, torques, dt, n_substeps, work):
    """Batched :func:`rk4_step`: q (B, n+2), u (B, 2), torques (B, n-1) in place; work (B,) out."""
    size = rk4_workspace_size(q.shape[1])
    for b in prange(q.shape[0]):
        workspace = np.empty(size)
        work[b] = rk4_step_workspace(m, h, inertia, c_joint, c_wheel, limit, k_limit, c_limit, q[b], u[b], torques[b],
                                     dt, n_substeps, workspace)


@njit(cache=True, nogil=True)
def derivatives_batch_serial(m, h, inertia, c_joint, c_wheel, q, u, torques, dq, du, power):
    """:func:`derivatives_batch` on one thread: for small batches (e.g. one
    simulation), where starting threads at every RK4 stage costs more than the work."""
    for b in range(q.shape[0]):
        power[b] = derivatives(m, h, inertia, c_joint, c_wheel, 0.0, 0.0, 0.0, q[b], u[b], torques[b], dq[b], du[b])


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
