"""The snake model: parameters and precomputed constants, no algorithms.

Pinocchio-style split: :class:`SnakeModel` holds what does not change during a
simulation (masses, lengths, inertias, damping); formulations are free
functions ``udot(model, q, u, torques)`` in their own modules, selected by name.
"""

from __future__ import annotations

import numpy as np

from . import kane, kane_paper, lagrange, newton_euler
from .forces import generalized_power, torque_power
from .kinematics import cm_positions, joint_angles, link_speeds
from .validation import check_n_links, per_link_parameter, result_dtype, state_array
from .wheel_reactions import lateral_forces

# m/s^2: standard gravity; the wheels' normal load m_k g on the plane the snake moves on (their grip mu m_k g)
# and the cost of transport's weight
GRAVITY = 9.81

# Paper Table II defaults.
DEFAULT_MASS = 1.0  # kg
DEFAULT_LENGTH = 0.2  # m
DEFAULT_INERTIA = 0.005  # kg m^2


# Formulation name -> udot(model, q, u, torques) (Pinocchio style: free functions).
FORMULATIONS = {
    "kane": kane.udot,
    "kane_paper": kane_paper.udot,
    "lagrange": lagrange.udot,
    "newton_euler": newton_euler.udot,
}
METHODS = tuple(FORMULATIONS)


class SnakeModel:
    """An n-link wheeled snake (paper section II).

    Args:
        n_links: number of links n >= 2.
        mass: link masses m_k (kg), scalar or length n.
        length: link lengths L_k (m), scalar or length n; h_k = L_k / 2.
        inertia: central moments of inertia I_k (kg m^2), scalar or length n.
        joint_damping: viscous joint damping c_j (N m s/rad), scalar or length n-1; 0 = the paper.
        wheel_damping: viscous wheel rolling resistance c_w (N s/m), scalar or length n; 0 = the paper.

    State: q = (theta_1..theta_n, x, y) (rad, m; eq. 1), u = (V_1, thetadot_1)
    (m/s, rad/s; eq. 2), torques T_1..T_{n-1} (N m). Every method accepts
    leading batch dimensions and keeps float32 when all inputs are float32.
    """

    def __init__(self, n_links: int = 5, mass=DEFAULT_MASS, length=DEFAULT_LENGTH, inertia=DEFAULT_INERTIA,
                 joint_damping=0.0, wheel_damping=0.0):
        n = check_n_links(n_links)
        self.n_links = n
        self.mass = per_link_parameter("mass", mass, n, "kg")
        self.length = per_link_parameter("length", length, n, "m")
        self.inertia = per_link_parameter("inertia", inertia, n, "kg m^2")
        self.joint_damping = per_link_parameter("joint_damping", joint_damping, n - 1, "N m s/rad", allow_zero=True)
        self.wheel_damping = per_link_parameter("wheel_damping", wheel_damping, n, "N s/m", allow_zero=True)
        self.half_length = self.length / 2.0
        self.half_length.setflags(write=False)
        self._cache = {}

    # ------------------------------------------------------------------ shapes
    @property
    def nq(self) -> int:
        """Number of generalized coordinates, n + 2."""
        return self.n_links + 2

    @property
    def n_joints(self) -> int:
        return self.n_links - 1

    def parameters(self, dtype=np.float64):
        """(mass, half_length, inertia, joint_damping, wheel_damping) in ``dtype``, cached."""
        dtype = np.dtype(dtype)
        if dtype not in self._cache:
            self._cache[dtype] = tuple(
                a.astype(dtype) for a in (self.mass, self.half_length, self.inertia, self.joint_damping, self.wheel_damping)
            )
        return self._cache[dtype]

    def __repr__(self) -> str:
        return (f"SnakeModel(n_links={self.n_links}, mass={self.mass.tolist()}, length={self.length.tolist()}, "
                f"inertia={self.inertia.tolist()}, joint_damping={self.joint_damping.tolist()}, "
                f"wheel_damping={self.wheel_damping.tolist()})")

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_cache"] = {}
        return state

    # ------------------------------------------------------------------ inputs
    def _state(self, q, u, torques=None):
        q = state_array("q", q, self.nq)
        u = state_array("u", u, 2)
        arrays = [q, u]
        if torques is not None:
            torques = state_array("torques", torques, self.n_joints)
            arrays.append(torques)
        dtype = result_dtype(*arrays)
        try:
            batch = np.broadcast_shapes(*(a.shape[:-1] for a in arrays))
        except ValueError:
            shapes = ", ".join(f"{name} {a.shape}" for name, a in zip(("q", "u", "torques"), arrays))
            raise ValueError(f"q, u and torques must have broadcastable leading (batch) dimensions, got {shapes}") from None
        out = [np.broadcast_to(a.astype(dtype, copy=False), batch + a.shape[-1:]) for a in arrays]
        return out if torques is not None else out + [None]

    # ------------------------------------------------------------------ kinematics
    def link_velocities(self, q, u):
        """(V, omega), each (..., n): eqs. 6-7 (m/s, rad/s)."""
        q, u, _ = self._state(q, u)
        _, h, _, _, _ = self.parameters(u.dtype)
        phi = joint_angles(q[..., : self.n_links])
        return link_speeds(h, np.cos(phi), np.sin(phi), u)

    def qdot(self, q, u):
        """Time derivative of q, (..., n+2): thetadot_k = omega_k, (xdot, ydot) = V_1 e_1."""
        q, u, _ = self._state(q, u)
        _, W = self.link_velocities(q, u)
        theta1 = q[..., 0]
        return np.concatenate([W, (u[..., 0] * np.cos(theta1))[..., None], (u[..., 0] * np.sin(theta1))[..., None]], axis=-1)

    def kinetic_energy(self, q, u):
        """K = 1/2 sum m_k V_k^2 + I_k omega_k^2 (J), eq. 22 under the constraints."""
        q, u, _ = self._state(q, u)
        m, _, inertia, _, _ = self.parameters(u.dtype)
        V, W = self.link_velocities(q, u)
        return 0.5 * np.sum(m * V * V + inertia * W * W, axis=-1)

    def joint_power(self, q, u, torques):
        """Power of the actuator torques, sum T_k (omega_{k+1} - omega_k) (W)."""
        q, u, torques = self._state(q, u, torques)
        _, W = self.link_velocities(q, u)
        return torque_power(torques, W)

    def power(self, q, u, torques):
        """Power of all loads, actuators plus damping (W): dK/dt in the continuous model."""
        q, u, torques = self._state(q, u, torques)
        _, _, _, c_joint, c_wheel = self.parameters(u.dtype)
        V, W = self.link_velocities(q, u)
        return generalized_power(c_joint, c_wheel, torques, V, W)

    def cm_positions(self, q):
        """CM of every link, (..., n, 2) (m)."""
        q = state_array("q", q, self.nq)
        return cm_positions(q[..., : self.n_links], q[..., self.n_links:], self.parameters(q.dtype)[1])

    def center_of_mass(self, q):
        """Mass-weighted CM of the whole snake, (..., 2) (m)."""
        pos = self.cm_positions(q)
        m = self.parameters(pos.dtype)[0]
        return np.sum(pos * m[:, None], axis=-2) / np.sum(m)

    # ------------------------------------------------------------------ dynamics
    def udot(self, q, u, torques, method: str = "kane"):
        """Generalized accelerations (..., 2) (m/s^2, rad/s^2) from eq. 8.

        method: "kane" (O(n), default), "kane_paper" (the paper's O(n^2)
        recursion), "lagrange" (eq. 27 multipliers) or "newton_euler"
        (Walker-Orin with multipliers).
        """
        if method not in FORMULATIONS:
            raise ValueError(f"method must be one of {list(METHODS)}, got {method!r}")
        q, u, torques = self._state(q, u, torques)
        return FORMULATIONS[method](self, q, u, torques)

    def wheel_lateral_forces(self, q, u, torques):
        """The wheels' lateral forces lambda (..., n) (N, along each link's normal e_k_perp): eq. 27's
        multipliers, by the O(n) backward sweep of :mod:`snake_env.dynamics.wheel_reactions`."""
        q, u, torques = self._state(q, u, torques)
        return lateral_forces(self, q, u, torques)
