"""The wheels' lateral (constraint) forces in O(n): eq. 27's multipliers without eq. 27.

The no-side-slip constraint of wheel k holds the CM velocity of link k along
e_k; the wheel pushes the link sideways with a force lambda_k e_k_perp (N),
the multiplier lambda_k of eq. 27 (same sign: its generalized force is A^T
lambda). Once udot is known (eq. 8, O(n) Kane sweep), every link's motion is
known and the Newton–Euler equations of the links give the multipliers and the
joint reaction forces in one backward sweep, tail to head.

Link k (0-based) has CM acceleration a_k = Vdot_k e_k + V_k omega_k e_k_perp
(its velocity is V_k e_k), angular acceleration alpha_k = omegadot_k, the
rolling resistance f_k e_k (f_k = -c_w,k V_k), the wheel force lambda_k
e_k_perp, the joint torques +T_{k-1} and -T_k (eq. 11; T the effective
torque: actuator, joint damping and, in the env, the limit barrier), and the
pin force F_k from link k+1 at joint k (CM_k + h_k e_k), -F_{k-1} from link k-1
at joint k-1 (CM_k - h_k e_k). With F_{n-1} = 0:

    Newton:  F_{k-1} = F_k + f_k e_k + lambda_k e_k_perp - m_k a_k
    Euler:   I_k alpha_k = T_{k-1} - T_k + h_k e_k x (F_k + F_{k-1})
    =>       lambda_k = (I_k alpha_k - T_{k-1} + T_k) / h_k - 2 e_k x F_k + m_k V_k omega_k

(x the planar cross product; e_k x e_k_perp = 1, e_k x a_k = V_k omega_k).
The head's Newton equation is one more than the unknowns need: the pin force
it leaves, F_{-1}, is zero exactly when udot solves eq. 8, which
:func:`lateral_forces` returns as a residual check.
"""

from __future__ import annotations

import numpy as np

from .forces import effective_joint_torques, wheel_forces
from .kane import forward_sweep, udot_sweep
from .kinematics import joint_angles


def lateral_forces(model, q, u, torques, return_residual: bool = False):
    """lambda (..., n) (N): the wheels' lateral forces along e_k_perp for actuator torques ``torques``
    (..., n-1) (N m) in state (q, u); joint damping and rolling resistance of ``model`` included.
    With ``return_residual`` also the head's leftover pin force F_{-1} (..., 2) (N), zero up to rounding."""
    m, h, inertia, c_joint, c_wheel = model.parameters(u.dtype)
    n = model.n_links
    theta = q[..., :n]
    phi = joint_angles(theta)
    P, Q = forward_sweep(h, np.cos(phi), np.sin(phi), u)
    udot = udot_sweep(model, q, u, torques)
    V, W = P[..., 2, :], Q[..., 2, :]
    Vdot = P[..., 0, :] * udot[..., 0, None] + P[..., 1, :] * udot[..., 1, None] + P[..., 3, :]
    alpha = Q[..., 0, :] * udot[..., 0, None] + Q[..., 1, :] * udot[..., 1, None] + Q[..., 3, :]
    T = effective_joint_torques(c_joint, torques, W)
    f = wheel_forces(c_wheel, V)
    cos, sin = np.cos(theta), np.sin(theta)
    lam = np.zeros(np.broadcast_shapes(q.shape[:-1], u.shape[:-1]) + (n,), dtype=u.dtype)
    Fx = np.zeros(lam.shape[:-1], dtype=u.dtype)  # F_k, the pin force of link k+1 on link k (N)
    Fy = np.zeros_like(Fx)
    for k in range(n - 1, -1, -1):
        T_in = T[..., k - 1] if k > 0 else 0.0  # +T_{k-1} from joint k-1
        T_out = T[..., k] if k < n - 1 else 0.0  # -T_k from joint k
        e_cross_F = cos[..., k] * Fy - sin[..., k] * Fx
        lam[..., k] = ((inertia[k] * alpha[..., k] - T_in + T_out) / h[k] - 2.0 * e_cross_F
                       + m[k] * V[..., k] * W[..., k])
        # Newton: F_{k-1} = F_k + f_k e_k + lambda_k e_perp - m_k (Vdot_k e_k + V_k omega_k e_perp)
        along = f[..., k] - m[k] * Vdot[..., k]
        across = lam[..., k] - m[k] * V[..., k] * W[..., k]
        Fx = Fx + along * cos[..., k] - across * sin[..., k]
        Fy = Fy + along * sin[..., k] + across * cos[..., k]
    if return_residual:
        return lam, np.stack([Fx, Fy], axis=-1)
    return lam
