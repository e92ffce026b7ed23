"""Kane's equations in O(n): the fast default formulation.

The paper's eq. 8, M(phi) udot + N(phi, u) omega = F, needs N omega, which it
builds from the n x n matrices dV/dq and domega/dq (eqs. 15-21): O(n^2).
But N omega = sum_k m_k dV_k/du V_k^b + I_k domega_k/du omega_k^b, where
(V_k^b, omega_k^b) are the time derivatives of (V_k, omega_k) with udot = 0.
Differentiating eqs. 6-7 in time gives them in the same forward sweep:

    Vdot_{i+1}     =  Vdot_i C_i + omegadot_i h_i S_i - h_{i+1} omega_{i+1} phidot_i
    omegadot_{i+1} = (Vdot_i S_i - omegadot_i h_i C_i + V_{i+1} phidot_i) / h_{i+1}

(the phidot terms are d/dphi of eqs. 6-7, simplified with eqs. 6-7 themselves).
With Vdot_1 = omegadot_1 = 0 this is the velocity-product ("bias")
acceleration; the partials dV/du, domega/du (eqs. 12-14) run through the same
linear map. Four channels, one sweep: O(n) for the whole udot.

:func:`udot` sends float64 input to the compiled scalar version of this sweep
(:mod:`snake_env.dynamics.compiled`); :func:`udot_sweep` is the vectorised
numpy sweep, used for float32 (the paper's single-precision runs) and kept as
the readable reference.
"""

from __future__ import annotations

import numpy as np

from .forces import effective_joint_torques, wheel_forces
from .kinematics import joint_angles


def forward_sweep(half_length, cos_phi, sin_phi, u):
    """Partial velocities, velocities and bias accelerations in one sweep.

    Returns P, Q of shape (..., 4, n): channel 0, 1 = dV/du_1, dV/du_2
    (P) and domega/du_1, domega/du_2 (Q); channel 2 = V, omega; channel 3 = the
    bias accelerations Vdot^b, omegadot^b (udot = 0).
    """
    n = half_length.shape[0]
    batch = np.broadcast_shapes(cos_phi.shape[:-1], u.shape[:-1])
    P = np.zeros(batch + (4, n), dtype=u.dtype)
    Q = np.zeros(batch + (4, n), dtype=u.dtype)
    P[..., 0, 0] = 1.0  # eq. 12: dV_1/du_1 = 1
    Q[..., 1, 0] = 1.0  # eq. 12: domega_1/du_2 = 1
    P[..., 2, 0] = u[..., 0]
    Q[..., 2, 0] = u[..., 1]
    for i in range(n - 1):
        C = cos_phi[..., i, None]
        S = sin_phi[..., i, None]
        hi, hn = half_length[i], half_length[i + 1]
        p, q = P[..., :, i], Q[..., :, i]
        p_next = p * C + q * (hi * S)  # eqs. 6, 13
        q_next = (p * S - q * (hi * C)) / hn  # eqs. 7, 14
        phidot = q_next[..., 2] - q[..., 2]
        p_next[..., 3] -= hn * q_next[..., 2] * phidot
        q_next[..., 3] += p_next[..., 2] * phidot / hn
        P[..., :, i + 1] = p_next
        Q[..., :, i + 1] = q_next
    return P, Q


def solve_2x2(M00, M01, M11, r0, r1):
    """Explicit solve of the symmetric 2x2 system of eq. 8."""
    det = M00 * M11 - M01 * M01
    return np.stack([(M11 * r0 - M01 * r1) / det, (M00 * r1 - M01 * r0) / det], axis=-1)


# Batches at least this large go to the threaded kernel. Waking threads costs
# more than small batches take: on the shared 2-core machine, the env's RK4 step
# (16 udot evaluations per snake) was no faster threaded than serial up to
# ~1000 snakes, so a bare udot gets a higher threshold.
PARALLEL_BATCH = 4096


def udot(model, q, u, torques):
    """Generalized accelerations (..., 2) by the O(n) Kane sweep.

    float64 goes to the compiled kernel, anything else to :func:`udot_sweep`.
    """
    if u.dtype != np.float64 or q.dtype != np.float64 or torques.dtype != np.float64:
        return udot_sweep(model, q, u, torques)
    return udot_compiled(model, q, u, torques)


def udot_compiled(model, q, u, torques):
    """float64 udot (..., 2) by the numba kernel, batch flattened to one axis."""
    from . import compiled  # lazy: keeps `import snake_env` free of numba start-up

    if q.ndim == 1 and u.ndim == 1 and torques.ndim == 1:  # one state: skip the batch bookkeeping
        du = np.empty(2)
        compiled.udot_single(*model.parameters(np.float64), q, u, torques, du)
        return du
    batch = np.broadcast_shapes(q.shape[:-1], u.shape[:-1], torques.shape[:-1])
    size = int(np.prod(batch, dtype=np.int64))
    qf = np.ascontiguousarray(np.broadcast_to(q, batch + q.shape[-1:]).reshape(size, q.shape[-1]))
    uf = np.ascontiguousarray(np.broadcast_to(u, batch + (2,)).reshape(size, 2))
    tf = np.ascontiguousarray(np.broadcast_to(torques, batch + torques.shape[-1:]).reshape(size, torques.shape[-1]))
    du = np.empty((size, 2))
    kernel = compiled.udot_batch_parallel if size >= PARALLEL_BATCH else compiled.udot_batch
    kernel(*model.parameters(np.float64), qf, uf, tf, du)
    return du.reshape(batch + (2,))


def udot_sweep(model, q, u, torques):
    """Generalized accelerations (..., 2) by the vectorised numpy O(n) sweep."""
    m, h, inertia, c_joint, c_wheel = model.parameters(u.dtype)
    n = model.n_links
    phi = joint_angles(q[..., :n])
    P, Q = forward_sweep(h, np.cos(phi), np.sin(phi), u)
    dV, dW = P[..., :2, :], Q[..., :2, :]  # (..., 2, n)
    V, W = P[..., 2, :], Q[..., 2, :]
    Vb, Wb = P[..., 3, :], Q[..., 3, :]

    mdV = m * dV
    IdW = inertia * dW
    # eq. 9
    M00 = np.sum(mdV[..., 0, :] * dV[..., 0, :] + IdW[..., 0, :] * dW[..., 0, :], axis=-1)
    M01 = np.sum(mdV[..., 0, :] * dV[..., 1, :] + IdW[..., 0, :] * dW[..., 1, :], axis=-1)
    M11 = np.sum(mdV[..., 1, :] * dV[..., 1, :] + IdW[..., 1, :] * dW[..., 1, :], axis=-1)
    # N omega (eq. 10 contracted with omega) = sum m dV/du Vb + I dW/du Wb
    bias = np.sum(mdV * Vb[..., None, :] + IdW * Wb[..., None, :], axis=-1)
    # eq. 11, with damping folded into the joint torques and wheel forces
    T = effective_joint_torques(c_joint, torques, W)
    f = wheel_forces(c_wheel, V)
    F = np.sum(T[..., None, :] * (dW[..., 1:] - dW[..., :-1]), axis=-1) + np.sum(f[..., None, :] * dV, axis=-1)
    rhs = F - bias
    return solve_2x2(M00, M01, M11, rhs[..., 0], rhs[..., 1])
