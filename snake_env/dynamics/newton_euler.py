"""Newton-Euler formulation after Walker and Orin (paper section V).

The unconstrained chain of :mod:`.lagrange` (q = theta_1..theta_n, x, y) is
handled the way Walker and Orin handle a serial manipulator:

* bias vector B(q, qdot): the generalized forces that produce qddot = 0, from
  a recursive Newton-Euler pass. Forward: CM accelerations with qddot = 0,
  a_0 = 0, a_{k+1} = a_k - h_k thetadot_k^2 e_k - h_{k+1} thetadot_{k+1}^2 e_{k+1}
  (eq. 3 differentiated twice); inertial forces f_k = m_k a_k (link rotations
  have no bias: alpha_k = thetaddot_k = 0). Backward: F_k = f_k + F_{k+1}, the
  resultant of the links beyond, projected on each coordinate. O(n).
* inertia matrix M(q): Walker-Orin's composite-rigid-body method. Column j is
  the generalized force for a unit qddot_j at rest. A unit thetaddot_j spins
  link j about its CM and translates the composite of links j+1..n (mass
  Mc_{j+1}) rigidly by g_j e_j_perp, so the resultant force on links j..n is
  F_j = (m_j c_jj + Mc_{j+1} g_j) e_j_perp and M[i, j] = g_i e_i_perp . F_j
  for i < j. O(n^2).

The constraints are applied exactly as in :mod:`.lagrange` (eqs. 26-27).
Everything is plain numpy arithmetic so it also runs on counting scalars.
"""

from __future__ import annotations

import numpy as np

from .lagrange import consistent_qdot, lever_arms, solve_multipliers, udot_from_qddot, unit_vectors


def composite_masses(mass: np.ndarray) -> np.ndarray:
    """Mc (n+1,): Mc[k] = sum_{l >= k} m_l (kg), Mc[n] = 0. A model constant."""
    out = np.zeros(mass.shape[0] + 1, dtype=mass.dtype)
    for k in range(mass.shape[0] - 1, -1, -1):
        out[k] = out[k + 1] + mass[k]
    return out


def outboard_levers(c: np.ndarray) -> np.ndarray:
    """g (n,): d CM_k / d theta_j = g_j e_j_perp for every k > j (m); g_{n-1} = 0."""
    n = c.shape[0]
    return np.array([c[j + 1, j] if j + 1 < n else c[j, j] * 0 for j in range(n)], dtype=c.dtype)


def inertia_matrix(model, q, dtype=None):
    """M (..., n+2, n+2) by composite rigid bodies (Walker-Orin method 3)."""
    dtype = q.dtype if dtype is None else dtype
    m, h, inertia, _, _ = model.parameters(dtype)
    _, e_perp = unit_vectors(q[..., : model.n_links])
    return _composite_inertia(m, inertia, lever_arms(h), e_perp, q.shape[:-1], dtype)


def _composite_inertia(m, inertia, c, e_perp, batch, dtype):
    n = m.shape[0]
    Mc = composite_masses(m)
    g = outboard_levers(c)
    M = np.zeros(batch + (n + 2, n + 2), dtype=dtype)
    total = Mc[0]
    M[..., n, n] = total
    M[..., n + 1, n + 1] = total
    for j in range(n - 1, -1, -1):
        # composite of links j..n-1 under a unit thetaddot_j (model constants)
        resultant = m[j] * c[j, j] + Mc[j + 1] * g[j]  # kg m
        M[..., j, j] = inertia[j] + m[j] * c[j, j] * c[j, j] + Mc[j + 1] * g[j] * g[j]
        F = resultant * e_perp[..., j, :]  # (..., 2) (N per rad/s^2)
        M[..., n:, j] = F
        M[..., j, n:] = F
        if j > 0:
            # joints i < j see the composite force through the lever g_i e_i_perp
            proj = g[:j] * (e_perp[..., :j, 0] * F[..., None, 0] + e_perp[..., :j, 1] * F[..., None, 1])
            M[..., :j, j] = proj
            M[..., j, :j] = proj
    return M


def bias_vector(model, q, qdot):
    """B (..., n+2): recursive Newton-Euler with qddot = 0 (Walker-Orin)."""
    m, h, _, _, _ = model.parameters(qdot.dtype)
    e, e_perp = unit_vectors(q[..., : model.n_links])
    return _recursive_bias(m, h, lever_arms(h), e, e_perp, qdot)


def _recursive_bias(m, h, c, e, e_perp, qdot):
    n = m.shape[0]
    g = outboard_levers(c)
    w2 = qdot[..., :n] * qdot[..., :n]
    # forward pass: CM accelerations with qddot = 0 (m/s^2); tip_k = h_k thetadot_k^2
    tip = h[:, None] * (w2[..., :, None] * e)  # (..., n, 2) centripetal term of each half link
    batch = np.broadcast_shapes(e.shape[:-2], qdot.shape[:-1])
    a = np.zeros(batch + (n, 2), dtype=qdot.dtype)
    for k in range(n - 1):
        a[..., k + 1, :] = a[..., k, :] - tip[..., k, :] - tip[..., k + 1, :]
    f = m[:, None] * a  # inertial forces (N)
    # backward pass: resultant of links k..n-1
    F = np.zeros(batch + (n + 1, 2), dtype=qdot.dtype)
    for k in range(n - 1, -1, -1):
        F[..., k, :] = F[..., k + 1, :] + f[..., k, :]
    # generalized force on theta_j: e_j_perp . (c_jj f_j + g_j F_{j+1})
    lever_force = np.diagonal(c)[:, None] * f + g[:, None] * F[..., 1:, :]
    B_theta = e_perp[..., 0] * lever_force[..., 0] + e_perp[..., 1] * lever_force[..., 1]
    return np.concatenate([B_theta, F[..., 0, :]], axis=-1)


def qddot(model, q, qdot, torques, baumgarte: float = 0.0, with_multipliers: bool = False, rotor_inertia=None):
    """Coordinate accelerations (..., n+2) from eq. 27 with Walker-Orin's M and B (``rotor_inertia``: as
    :func:`snake_env.dynamics.lagrange.qddot`'s)."""
    m, h, inertia, _, _ = model.parameters(qdot.dtype)
    n = model.n_links
    e, e_perp = unit_vectors(q[..., :n])
    c = lever_arms(h)
    batch = np.broadcast_shapes(q.shape[:-1], qdot.shape[:-1])
    M = _composite_inertia(m, inertia, c, e_perp, batch, qdot.dtype)
    B = _recursive_bias(m, h, c, e, e_perp, qdot)
    # J is only needed for the wheel-damping loads; generalized_forces builds it then
    return solve_multipliers(model, q, qdot, torques, M, B, c, e, e_perp, None, baumgarte, with_multipliers,
                             rotor_inertia)


def udot(model, q, u, torques):
    """Generalized accelerations (..., 2) by Walker-Orin plus multipliers."""
    qd = consistent_qdot(model, q, u)
    return udot_from_qddot(q, qd, qddot(model, q, qd, torques))
