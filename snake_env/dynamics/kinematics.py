"""Velocity kinematics of the wheeled snake (paper eqs. 1-7).

Each link's CM speed V_k (along the link, eq. 4) and angular rate omega_k
follow from the two generalized speeds u = (V_1, thetadot_1) (eq. 2) through
the forward recursion of eqs. 6-7:

    V_{i+1}     =  V_i C_i + omega_i h_i S_i                       (6)
    omega_{i+1} = (V_i S_i - omega_i h_i C_i) / h_{i+1}            (7)

with C_i = cos(phi_i), S_i = sin(phi_i), phi_i = theta_{i+1} - theta_i.
"""

from __future__ import annotations

import numpy as np


def joint_angles(theta: np.ndarray) -> np.ndarray:
    """phi_i = theta_{i+1} - theta_i, shape (..., n-1) (rad)."""
    return theta[..., 1:] - theta[..., :-1]


def link_speeds(half_length: np.ndarray, cos_phi: np.ndarray, sin_phi: np.ndarray, u: np.ndarray):
    """Eqs. 6-7: (V, omega), each (..., n), from u (..., 2)."""
    n = half_length.shape[0]
    batch = np.broadcast_shapes(cos_phi.shape[:-1], u.shape[:-1])
    V = np.empty(batch + (n,), dtype=u.dtype)
    W = np.empty(batch + (n,), dtype=u.dtype)
    V[..., 0] = u[..., 0]
    W[..., 0] = u[..., 1]
    for i in range(n - 1):
        C, S = cos_phi[..., i], sin_phi[..., i]
        V[..., i + 1] = V[..., i] * C + W[..., i] * (half_length[i] * S)
        W[..., i + 1] = (V[..., i] * S - W[..., i] * (half_length[i] * C)) / half_length[i + 1]
    return V, W


def cm_positions(theta: np.ndarray, xy: np.ndarray, half_length: np.ndarray) -> np.ndarray:
    """CM of every link, (..., n, 2) (m): CM_{k+1} = CM_k + h_k e_k + h_{k+1} e_{k+1} (eq. 3 integrated)."""
    e = np.stack([np.cos(theta), np.sin(theta)], axis=-1)  # (..., n, 2)
    half = e * half_length[:, None]
    steps = half[..., :-1, :] + half[..., 1:, :]
    offsets = np.concatenate([np.zeros_like(steps[..., :1, :]), np.cumsum(steps, axis=-2)], axis=-2)
    return xy[..., None, :] + offsets
