"""Lagrange's method with multipliers (paper section IV, eqs. 22-27).

The snake is first treated as an unconstrained planar chain with n + 2
coordinates q = (theta_1..theta_n, x, y) (eq. 1). Its kinetic energy (eq. 22)
is K = 1/2 qdot^T M(q) qdot with the generalized inertia matrix of eq. 25,
and Lagrange's equations (eq. 23) read M qddot + B(q, qdot) = Q (eq. 24).
The n no-side-slip constraints e_k_perp . rdot_k = 0 are velocity constraints
A(q) qdot = 0; differentiated once in time they give A qddot = -Adot qdot, and
with multipliers lambda the augmented system of eq. 27,

    [ M  -A^T ] [ qddot  ]   [ Q - B                         ]
    [ A   0   ] [ lambda ] = [ -Adot qdot - beta A qdot      ]

is solved by a triangular (LU) decomposition. (The paper prints A^T in the
lower-left block and "Adot qdot - bdot" on the right: with A the n x (n+2)
constraint matrix the block must be A and the sign is minus; beta is an
optional Baumgarte gain, 0 for the paper.)

Geometry used throughout (0-based link index k; the paper's link k+1):

    CM_k = (x, y) + sum_{j<k} h_j e_j + sum_{1<=j<=k} h_j e_j,

so d CM_k / d theta_j = c_kj e_j_perp with lever arms c_kj (:func:`lever_arms`),
e_j = (cos theta_j, sin theta_j), e_j_perp = (-sin theta_j, cos theta_j).

Every function here is written with plain numpy arithmetic (no einsum, no
LAPACK) so that it also runs on numpy object arrays of a counting scalar type
(:mod:`snake_env.benchmarks.opcount`): the operation counts reported for Table I are
those of this very code.
"""

from __future__ import annotations

import numpy as np

from .forces import effective_joint_torques, wheel_forces
from .kinematics import link_speeds


# ---------------------------------------------------------------- geometry
def lever_arms(half_length: np.ndarray) -> np.ndarray:
    """c (n, n): d CM_k / d theta_j = c[k, j] e_j_perp (m); zero for j > k.

    Link 0's CM is the reference point (x, y), so c[0, 0] = 0; c[k, 0] = h_0,
    c[k, j] = 2 h_j = L_j for 0 < j < k and c[k, k] = h_k. A model constant.
    """
    n = half_length.shape[0]
    c = np.zeros((n, n), dtype=half_length.dtype)
    for k in range(n):
        for j in range(k):
            c[k, j] = half_length[j] if j == 0 else half_length[j] + half_length[j]
        if k > 0:
            c[k, k] = half_length[k]
    return c


def unit_vectors(theta):
    """(e, e_perp), each (..., n, 2): link directions and their normals."""
    cos, sin = np.cos(theta), np.sin(theta)
    return np.stack([cos, sin], axis=-1), np.stack([-sin, cos], axis=-1)


def link_jacobians(c, e_perp):
    """J (..., n, n, 2): J[k, j] = d CM_k / d theta_j = c[k, j] e_j_perp (m).

    The (x, y) columns of every link's Jacobian are the 2 x 2 identity and are
    not stored.
    """
    return c[:, :, None] * e_perp[..., None, :, :]


def cm_velocities(J, qdot, n):
    """rdot_k = (xdot, ydot) + sum_j J[k, j] thetadot_j, (..., n, 2) (m/s)."""
    rdot = np.sum(J * qdot[..., None, :n, None], axis=-2)
    return rdot + qdot[..., None, n:]


def consistent_qdot(model, q, u):
    """qdot (..., n+2) satisfying the constraints: thetadot = omega (eqs. 6-7),
    (xdot, ydot) = V_1 e_1. Plain arithmetic, so it also runs on counters."""
    n = model.n_links
    _, h, _, _, _ = model.parameters(u.dtype)
    theta = q[..., :n]
    phi = theta[..., 1:] - theta[..., :-1]
    _, W = link_speeds(h, np.cos(phi), np.sin(phi), u)
    theta1 = q[..., 0]
    return np.concatenate([W, (u[..., 0] * np.cos(theta1))[..., None], (u[..., 0] * np.sin(theta1))[..., None]], axis=-1)


def udot_from_qddot(q, qdot, qddot):
    """u = (V_1, thetadot_1) differentiated: Vdot_1 = e_1 . (xddot, yddot) +
    thetadot_1 e_1_perp . (xdot, ydot) (d/dt of V_1 = e_1 . rdot_1)."""
    n = q.shape[-1] - 2
    c1, s1 = np.cos(q[..., 0]), np.sin(q[..., 0])
    xd, yd = qdot[..., n], qdot[..., n + 1]
    xdd, ydd = qddot[..., n], qddot[..., n + 1]
    Vdot = c1 * xdd + s1 * ydd + qdot[..., 0] * (c1 * yd - s1 * xd)
    return np.stack([Vdot, qddot[..., 0]], axis=-1)


# ---------------------------------------------------------------- eq. 25
def inertia_matrix(model, q, dtype=None):
    """Generalized inertia matrix M (..., n+2, n+2) of eq. 25.

    M(i, j) = d^2 K / d qdot_i d qdot_j = sum_k m_k J_k^T J_k + I_k (link k's
    rotation row), accumulated link by link from the Jacobians: O(n^3), the
    order the paper counts for this step.
    """
    dtype = q.dtype if dtype is None else dtype
    m, h, inertia, _, _ = model.parameters(dtype)
    n = model.n_links
    _, e_perp = unit_vectors(q[..., :n])
    J = link_jacobians(lever_arms(h), e_perp)
    return _inertia_from_jacobians(m, inertia, J, q.shape[:-1], dtype)


def _inertia_from_jacobians(m, inertia, J, batch, dtype):
    n = m.shape[0]
    M = np.zeros(batch + (n + 2, n + 2), dtype=dtype)
    for k in range(n):
        Jk = J[..., k, : k + 1, :]  # (..., k+1, 2): columns theta_0..theta_k
        gram = Jk[..., :, None, 0] * Jk[..., None, :, 0] + Jk[..., :, None, 1] * Jk[..., None, :, 1]
        M[..., : k + 1, : k + 1] += m[k] * gram
        coupling = m[k] * Jk  # theta-(x, y) block
        M[..., : k + 1, n:] += coupling
        M[..., n:, : k + 1] += np.swapaxes(coupling, -1, -2)
        M[..., k, k] += inertia[k]
    total_mass = np.sum(m)
    M[..., n, n] += total_mass
    M[..., n + 1, n + 1] += total_mass
    return M


# ---------------------------------------------------------------- eq. 24 bias
def bias_vector(model, q, qdot):
    """B(q, qdot) (..., n+2) of eq. 24, from differentiating eq. 22.

    With rddot_k = J_k qddot + Jdot_k qdot, Lagrange's equations of K =
    1/2 sum m_k |J_k qdot|^2 + I_k thetadot_k^2 give B = sum_k m_k J_k^T
    (Jdot_k qdot), and Jdot_k qdot = -sum_j c_kj thetadot_j^2 e_j is the
    centripetal acceleration of CM_k. O(n^2). (The paper instead borrows
    Walker-Orin's O(n) recursion here, see :mod:`.newton_euler`.)
    """
    m, h, _, _, _ = model.parameters(q.dtype)
    n = model.n_links
    e, e_perp = unit_vectors(q[..., :n])
    c = lever_arms(h)
    return _bias_from_geometry(m, c, e, link_jacobians(c, e_perp), qdot, n)


def rotor_inertia_matrix(rotor_inertia, n, dtype=np.float64):
    """The joint motors' rotors in eq. 25's M, (n+2, n+2): the rotor of joint k (reflected inertia
    N^2 J_r,k, kg m^2) adds 1/2 J_r,k (thetadot_{k+1} - thetadot_k)^2 to K, so J_r,k D_k^T D_k with
    D_k = d phi_k / dq. It depends on no coordinate, so it adds nothing to B (MuJoCo's joint armature)."""
    M = np.zeros((n + 2, n + 2), dtype=dtype)
    for k in range(n - 1):
        jr = rotor_inertia[k]
        M[k, k] += jr
        M[k + 1, k + 1] += jr
        M[k, k + 1] -= jr
        M[k + 1, k] -= jr
    return M


def _bias_from_geometry(m, c, e, J, qdot, n):
    w2 = qdot[..., :n] * qdot[..., :n]  # thetadot_j^2
    centripetal = -np.sum(c[:, :, None] * (w2[..., None, :, None] * e[..., None, :, :]), axis=-2)  # (..., n, 2)
    force = m[:, None] * centripetal  # (..., n, 2) m_k * Jdot_k qdot
    B_theta = np.sum(J[..., :, :, 0] * force[..., :, None, 0] + J[..., :, :, 1] * force[..., :, None, 1], axis=-2)
    B_xy = np.sum(force, axis=-2)
    return np.concatenate([B_theta, B_xy], axis=-1)


# ---------------------------------------------------------------- loads
def generalized_forces(model, q, qdot, torques, e=None, J=None):
    """Q (..., n+2): joint torques (+T_k on link k+1, -T_k on link k, eq. 11)
    and the damping loads of :mod:`.forces`, projected on q."""
    m, h, _, c_joint, c_wheel = model.parameters(qdot.dtype)
    n = model.n_links
    T = effective_joint_torques(c_joint, torques, qdot[..., :n])
    zero = np.zeros(T.shape[:-1] + (1,), dtype=T.dtype)
    Q_theta = np.concatenate([zero, T], axis=-1) - np.concatenate([T, zero], axis=-1)
    Q_xy = np.zeros(T.shape[:-1] + (2,), dtype=T.dtype)
    Q = np.concatenate([Q_theta, Q_xy], axis=-1)
    if np.any(c_wheel != 0):  # model constant: skip the wheel terms in the paper's model
        if J is None:
            e, e_perp = unit_vectors(q[..., :n])
            J = link_jacobians(lever_arms(h), e_perp)
        V = np.sum(e * cm_velocities(J, qdot, n), axis=-1)  # speed along each link (m/s)
        f = wheel_forces(c_wheel, V)[..., None] * e  # (..., n, 2) (N)
        Q_theta = np.sum(J[..., 0] * f[..., :, None, 0] + J[..., 1] * f[..., :, None, 1], axis=-2)
        Q = Q + np.concatenate([Q_theta, np.sum(f, axis=-2)], axis=-1)
    return Q


def power(model, q, qdot, torques):
    """Power of all loads Q . qdot (W): actuators plus damping."""
    return np.sum(generalized_forces(model, q, qdot, torques) * qdot, axis=-1)


# ---------------------------------------------------------------- constraints
def constraint_matrix(c, e_perp):
    """A (..., n, n+2): row k is e_k_perp . d CM_k / dq (eq. 26).

    A[k, theta_j] = c_kj cos(theta_k - theta_j), the cosine formed as
    e_k_perp . e_j_perp; A[k, (x, y)] = e_k_perp.
    """
    cos_kj = e_perp[..., :, None, 0] * e_perp[..., None, :, 0] + e_perp[..., :, None, 1] * e_perp[..., None, :, 1]
    return np.concatenate([c * cos_kj, e_perp], axis=-1)


def constraint_matrix_rate(c, e, e_perp, qdot, n):
    """Adot (..., n, n+2), the time derivative of A along qdot (eq. 27).

    Adot[k, theta_j] = -c_kj sin(theta_k - theta_j) (thetadot_k - thetadot_j),
    sin formed as e_k . e_j_perp; Adot[k, (x, y)] = -thetadot_k e_k.
    """
    sin_kj = e[..., :, None, 0] * e_perp[..., None, :, 0] + e[..., :, None, 1] * e_perp[..., None, :, 1]
    w = qdot[..., :n]
    rel = w[..., :, None] - w[..., None, :]
    return np.concatenate([-(c * (sin_kj * rel)), -(w[..., :, None] * e)], axis=-1)


def matvec(A, x):
    return np.sum(A * x[..., None, :], axis=-1)


def augmented_system(M, A, rhs_dynamics, rhs_constraints):
    """The (2n+2)-square matrix and right side of eq. 27."""
    top = np.concatenate([M, -np.swapaxes(A, -1, -2)], axis=-1)
    zeros = np.zeros(A.shape[:-1] + (A.shape[-2],), dtype=A.dtype)
    bottom = np.concatenate([A, zeros], axis=-1)
    return np.concatenate([top, bottom], axis=-2), np.concatenate([rhs_dynamics, rhs_constraints], axis=-1)


# ---------------------------------------------------------------- eq. 27 solver
def lu_solve(matrix, rhs):
    """Solve matrix x = rhs by Doolittle triangular decomposition, no pivoting.

    Written out (not LAPACK) so it runs on counting scalars too. Pivoting is
    not needed for eq. 27: M is positive definite and A has full row rank, so
    every leading block is non-singular (the Schur complement -A M^-1 A^T is
    negative definite). Batched over leading axes.
    """
    a = np.array(matrix, copy=True)
    b = np.array(rhs, copy=True)
    size = a.shape[-1]
    for k in range(size - 1):
        factors = a[..., k + 1:, k] / a[..., k, k, None]
        a[..., k + 1:, k + 1:] -= factors[..., :, None] * a[..., None, k, k + 1:]
        b[..., k + 1:] -= factors * b[..., k, None]
    x = np.empty_like(b)
    x[..., size - 1] = b[..., size - 1] / a[..., size - 1, size - 1]
    for k in range(size - 2, -1, -1):
        x[..., k] = (b[..., k] - np.sum(a[..., k, k + 1:] * x[..., k + 1:], axis=-1)) / a[..., k, k]
    return x


# ---------------------------------------------------------------- entry points
def qddot(model, q, qdot, torques, baumgarte: float = 0.0, with_multipliers: bool = False, rotor_inertia=None):
    """Coordinate accelerations (..., n+2) from eq. 27, for any (q, qdot).

    ``baumgarte`` (1/s) adds -beta A qdot to the constraint row, pulling a
    drifted velocity back onto A qdot = 0 (0 = the paper's eq. 27).
    With ``with_multipliers`` also returns lambda (..., n) (N).
    ``rotor_inertia`` (n-1,) (kg m^2): the joint motors' reflected rotor inertias
    (:func:`rotor_inertia_matrix`); None: massless rotors (the paper).
    """
    m, h, inertia, _, _ = model.parameters(qdot.dtype)
    n = model.n_links
    e, e_perp = unit_vectors(q[..., :n])
    c = lever_arms(h)
    J = link_jacobians(c, e_perp)
    batch = np.broadcast_shapes(q.shape[:-1], qdot.shape[:-1])
    M = _inertia_from_jacobians(m, inertia, J, batch, qdot.dtype)
    B = _bias_from_geometry(m, c, e, J, qdot, n)
    return solve_multipliers(model, q, qdot, torques, M, B, c, e, e_perp, J, baumgarte, with_multipliers,
                             rotor_inertia)


def solve_multipliers(model, q, qdot, torques, M, B, c, e, e_perp, J, baumgarte=0.0, with_multipliers=False,
                      rotor_inertia=None):
    """Shared constraint treatment (eqs. 26-27) for Lagrange and Newton-Euler (the rotors' inertia, if
    given, added to M here)."""
    n = model.n_links
    if rotor_inertia is not None:
        M = M + rotor_inertia_matrix(np.asarray(rotor_inertia, dtype=qdot.dtype), n, qdot.dtype)
    A = constraint_matrix(c, e_perp)
    Adot = constraint_matrix_rate(c, e, e_perp, qdot, n)
    Q = generalized_forces(model, q, qdot, torques, e, J)
    rhs_c = -matvec(Adot, qdot)
    if baumgarte:
        rhs_c = rhs_c - np.asarray(baumgarte, dtype=qdot.dtype) * matvec(A, qdot)
    system, rhs = augmented_system(M, A, Q - B, rhs_c)
    x = lu_solve(system, rhs)
    if with_multipliers:
        return x[..., : n + 2], x[..., n + 2:]
    return x[..., : n + 2]


def udot(model, q, u, torques):
    """Generalized accelerations (..., 2) by Lagrange's multipliers (eq. 27).

    qdot is the constraint-consistent one of (q, u); q, u, torques come
    validated and broadcast from :meth:`SnakeModel.udot`.
    """
    qd = consistent_qdot(model, q, u)
    return udot_from_qddot(q, qd, qddot(model, q, qd, torques))
