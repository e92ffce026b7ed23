"""Kane's equations exactly as the paper prints them: O(n^2).

Partial derivatives with respect to u by eqs. 12-14, with respect to q by
eqs. 15-21 (an n x n lower-bidiagonal-plus-triangle matrix), then M, N, F by
eqs. 9-11 and eq. 8 solved for udot. This is the reference the paper's
operation counts describe; :mod:`snake_env.dynamics.kane` gives the same
numbers in O(n).

Indices here are 0-based: link i, q_i = theta_i, phi_i = theta_{i+1} - theta_i.
"""

from __future__ import annotations

import numpy as np

from .forces import effective_joint_torques, wheel_forces
from .kane import solve_2x2
from .kinematics import joint_angles, link_speeds


def partials_wrt_u(h, C, S, dtype, batch):
    """Eqs. 12-14: dV/du and domega/du, each (..., n, 2)."""
    n = h.shape[0]
    dVdu = np.zeros(batch + (n, 2), dtype=dtype)
    dWdu = np.zeros(batch + (n, 2), dtype=dtype)
    dVdu[..., 0, 0] = 1.0  # eq. 12
    dWdu[..., 0, 1] = 1.0
    for i in range(n - 1):
        c, s = C[..., i, None], S[..., i, None]
        dVdu[..., i + 1, :] = dVdu[..., i, :] * c + dWdu[..., i, :] * (s * h[i])  # eq. 13
        dWdu[..., i + 1, :] = (dVdu[..., i, :] * s - dWdu[..., i, :] * (c * h[i])) / h[i + 1]  # eq. 14
    return dVdu, dWdu


def partials_wrt_q(h, C, S, V, W, dtype, batch):
    """Eqs. 15-21: dV/dtheta and domega/dtheta, each (..., n, n).

    Row i+1 depends on columns j <= i+1 only (eq. 21: the rest are zero), so
    each row update touches the lower triangle: O(n^2) in all.
    """
    n = h.shape[0]
    dVdq = np.zeros(batch + (n, n), dtype=dtype)
    dWdq = np.zeros(batch + (n, n), dtype=dtype)
    for i in range(n - 1):
        c, s = C[..., i], S[..., i]
        Vi, Wi = V[..., i], W[..., i]
        cols = slice(0, i + 1)
        # eqs. 19-20 (j < i) and the first two terms of eqs. 17-18 (j = i)
        dVdq[..., i + 1, cols] = dVdq[..., i, cols] * c[..., None] + dWdq[..., i, cols] * (s * h[i])[..., None]
        dWdq[..., i + 1, cols] = (dVdq[..., i, cols] * s[..., None] - dWdq[..., i, cols] * (c * h[i])[..., None]) / h[i + 1]
        # the explicit terms of eqs. 17-18 (j = i: dphi_i/dtheta_i = -1)
        dVdq[..., i + 1, i] += Vi * s - Wi * c * h[i]
        dWdq[..., i + 1, i] += (-Vi * c - Wi * s * h[i]) / h[i + 1]
        # eqs. 15-16 (j = i + 1: dphi_i/dtheta_{i+1} = +1)
        dVdq[..., i + 1, i + 1] = -Vi * s + Wi * c * h[i]
        dWdq[..., i + 1, i + 1] = (Vi * c + Wi * s * h[i]) / h[i + 1]
    return dVdq, dWdq


def mass_matrix(model, q):
    """Eq. 9: the 2 x 2 mass matrix M(phi), (..., 2, 2) (kg, kg m, kg m^2)."""
    q = np.asarray(q)
    m, h, inertia, _, _ = model.parameters(q.dtype)
    phi = joint_angles(q[..., : model.n_links])
    dVdu, dWdu = partials_wrt_u(h, np.cos(phi), np.sin(phi), q.dtype, phi.shape[:-1])
    return (np.einsum("k,...ki,...kj->...ij", m, dVdu, dVdu)
            + np.einsum("k,...ki,...kj->...ij", inertia, dWdu, dWdu))


def udot(model, q, u, torques):
    """Generalized accelerations (..., 2) by the paper's eqs. 8-21."""
    m, h, inertia, c_joint, c_wheel = model.parameters(u.dtype)
    n = model.n_links
    phi = joint_angles(q[..., :n])
    C, S = np.cos(phi), np.sin(phi)
    batch = np.broadcast_shapes(phi.shape[:-1], u.shape[:-1])
    V, W = link_speeds(h, C, S, u)
    dVdu, dWdu = partials_wrt_u(h, C, S, u.dtype, batch)
    dVdq, dWdq = partials_wrt_q(h, C, S, V, W, u.dtype, batch)

    mdVdu = m[:, None] * dVdu  # (..., n, 2)
    IdWdu = inertia[:, None] * dWdu
    M = np.einsum("...ki,...kj->...ij", mdVdu, dVdu) + np.einsum("...ki,...kj->...ij", IdWdu, dWdu)  # eq. 9
    N = np.einsum("...ki,...kj->...ij", mdVdu, dVdq) + np.einsum("...ki,...kj->...ij", IdWdu, dWdq)  # eq. 10, (..., 2, n)
    T = effective_joint_torques(c_joint, torques, W)
    f = wheel_forces(c_wheel, V)
    F = np.einsum("...k,...ki->...i", T, dWdu[..., 1:, :] - dWdu[..., :-1, :])  # eq. 11
    F = F + np.einsum("...k,...ki->...i", f, dVdu)
    rhs = F - np.einsum("...ij,...j->...i", N, W)  # eq. 8: M udot = F - N omega
    return solve_2x2(M[..., 0, 0], M[..., 0, 1], M[..., 1, 1], rhs[..., 0], rhs[..., 1])
