"""Applied and dissipative loads, shared by every formulation.

Joint torque T_k acts +T_k on link k+1 and -T_k on link k (paper eq. 11).
Two viscous loads extend the paper's model (both zero by default):

* joint damping c_j (N m s/rad): an extra joint torque -c_j (omega_{k+1} - omega_k);
* wheel rolling resistance c_w (N s/m): a force -c_w V_k along link k at its CM.

They enter the generalized forces through the same partial velocities as the
joint torques, so every formulation treats them identically and the
work-energy balance becomes a dissipation balance.
"""

from __future__ import annotations

import numpy as np


def effective_joint_torques(joint_damping: np.ndarray, torques: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """T_k - c_j,k * phidot_k, (..., n-1) (N m)."""
    return torques - joint_damping * (omega[..., 1:] - omega[..., :-1])


def wheel_forces(wheel_damping: np.ndarray, V: np.ndarray) -> np.ndarray:
    """Rolling-resistance force along each link, -c_w,k V_k, (..., n) (N)."""
    return -wheel_damping * V


def generalized_power(joint_damping, wheel_damping, torques, V, omega) -> np.ndarray:
    """Power of all applied loads (W): sum T_eff,k phidot_k + sum f_k V_k.

    Kinetic energy changes at exactly this rate in the continuous model, so
    S(t) = K(t) - integral of this power is constant (paper section VI.3).
    """
    phidot = omega[..., 1:] - omega[..., :-1]
    joint = np.sum(effective_joint_torques(joint_damping, torques, omega) * phidot, axis=-1)
    wheel = np.sum(wheel_forces(wheel_damping, V) * V, axis=-1)
    return joint + wheel


def torque_power(torques, omega) -> np.ndarray:
    """Power of the actuator torques alone (W): sum T_k (omega_{k+1} - omega_k)."""
    return np.sum(torques * (omega[..., 1:] - omega[..., :-1]), axis=-1)
