"""Joint PD: the inner loop that turns joint-angle references into env actions.

Per joint i = 1..n-1,

    T_i = kp (phi_i^ref - phi_i) + kd (phidot_i^ref - phidot_i)    (N m),

with kp in N m/rad and kd in N m s/rad, saturated at the env's torque limit and sent as the
env action T_i / max_torque in [-1, 1]. The PD runs at the env-step rate: one torque per env
step (dt, s), held over the integrator's sub-steps (the env's action contract), so a very
stiff PD overshoots. The serpenoid ``pd`` family (:mod:`.serpenoid`) is this PD with the
serpenoid curve as reference; :mod:`.cpg` generates the reference from an oscillator.

Observations are plain arrays in the envs' documented layout (:func:`.serpenoid.joint_slices`),
batched over any leading axes; no Gymnasium import. The callers (the ``joint_target`` and
``cpg`` wrappers) validate the gains against their config keys.
"""

from __future__ import annotations

import numpy as np

from .serpenoid import joint_slices

# how TargetAnglePD estimates phidot^ref: the target's change over the last env step / dt, or 0
REFERENCE_RATES = ("difference", "zero")


def check_reference_rate(reference_rate) -> str:
    """``reference_rate`` if it is one of :data:`REFERENCE_RATES`; a one-line ValueError otherwise."""
    if reference_rate not in REFERENCE_RATES:
        raise ValueError(f"reference_rate must be one of {list(REFERENCE_RATES)}, got {reference_rate!r}")
    return reference_rate


class JointPD:
    """The saturated joint PD of the module docstring.

    Args:
        n_links: links n (n - 1 joints).
        max_torque: torque limit (N m); the env action is T / max_torque.
        kp: stiffness (N m/rad).
        kd: damping (N m s/rad).
        include_position: whether the observation starts with the CM position (x, y).
    """

    def __init__(self, n_links: int, max_torque: float, kp: float, kd: float, include_position: bool = False):
        self.kp = float(kp)
        self.kd = float(kd)
        self.max_torque = float(max_torque)
        self.phi, self.rates = joint_slices(n_links, include_position)

    def track(self, reference, reference_rate, obs) -> np.ndarray:
        """Env action (float32, torque / max_torque clipped to [-1, 1]) that tracks ``reference`` (rad)
        and ``reference_rate`` (rad/s) from the joint angles and rates of ``obs``."""
        obs = np.asarray(obs, dtype=np.float64)
        torque = self.kp * (reference - obs[..., self.phi]) + self.kd * (reference_rate - obs[..., self.rates])
        return np.clip(torque / self.max_torque, -1.0, 1.0).astype(np.float32)


class TargetAnglePD(JointPD):
    """The PD tracking target joint angles given as an action in [-1, 1]:
    phi^ref = clip(action, -1, 1) target_range (rad), and phidot^ref = (phi^ref - previous phi^ref) / dt,
    the target's change over the last env step (``reference_rate="difference"``; 0 on an episode's
    first step), or 0 (``reference_rate="zero"``).

    Args (besides :class:`JointPD`'s):
        dt: env step (s).
        target_range: rad of target per unit action.
        reference_rate: one of :data:`REFERENCE_RATES`.
    """

    def __init__(self, n_links: int, max_torque: float, dt: float, kp: float, kd: float, target_range: float,
                 reference_rate: str = "difference", include_position: bool = False):
        super().__init__(n_links, max_torque, kp, kd, include_position)
        self.use_rate = check_reference_rate(reference_rate) == "difference"
        self.dt = float(dt)
        self.target_range = float(target_range)

    def target(self, action) -> np.ndarray:
        """Target joint angles (rad) of an action."""
        return np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0) * self.target_range

    def torque_action(self, action, obs, previous_target=None) -> np.ndarray:
        """Env action (torque / max_torque, in [-1, 1]) of the PD for a target ``action``;
        ``previous_target`` (rad, or None on a first step) gives the reference rate."""
        target = self.target(action)
        rate = 0.0
        if self.use_rate and previous_target is not None:
            rate = (target - previous_target) / self.dt
        return self.track(target, rate, obs)
