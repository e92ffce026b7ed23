"""A serpenoid central pattern generator (CPG) whose parameters are the action, as in CPG-RL
(Bellegarda and Ijspeert, 2022), tracked by the joint PD of :mod:`.joint_pd`.

The action u in [-1, 1]^4, in the order of :data:`CPG_PARAMETERS`, maps linearly to

    amplitude alpha = (u_0 + 1) / 2 max_amplitude      (rad)
    frequency omega = (u_1 + 1) / 2 max_frequency      (rad/s)
    phase lag beta  = u_2 pi                           (rad)
    offset    gamma = u_3 max_offset                   (rad)

of one serpenoid wave. The oscillator's phase is integrated over each env step,
psi <- (psi + omega dt) mod 2 pi, and joint i = 1..n-1 tracks

    phi_i^ref    = alpha sin(psi + (i-1) beta) + gamma,
    phidot_i^ref = alpha omega cos(psi + (i-1) beta),

so a constant action is the ``pd`` serpenoid of :mod:`.serpenoid` (Hirose's curve
alpha sin(omega t + (i-1) beta) + gamma) with the same gains, and a policy that sets the action
every step modulates it from state feedback. Batched over any leading axes; no Gymnasium import.
"""

from __future__ import annotations

import math

import numpy as np

from .joint_pd import JointPD

CPG_PARAMETERS = ("amplitude", "frequency", "phase_lag", "offset")


class SerpenoidCPG(JointPD):
    """The CPG of the module docstring, its reference tracked by a :class:`JointPD`.

    Args (besides :class:`JointPD`'s):
        dt: env step (s), over which the phase advances by omega dt.
        max_amplitude: rad; max_frequency: rad/s; max_offset: rad (the ranges above).
    """

    def __init__(self, n_links: int, max_torque: float, dt: float, max_amplitude: float, max_frequency: float,
                 max_offset: float, kp: float, kd: float, include_position: bool = False):
        super().__init__(n_links, max_torque, kp, kd, include_position)
        self.n_joints = n_links - 1
        self.dt = float(dt)
        self.max_amplitude = float(max_amplitude)
        self.max_frequency = float(max_frequency)
        self.max_offset = float(max_offset)

    def decode(self, action) -> dict[str, np.ndarray]:
        """Oscillator parameters (each of shape (...,)) of actions (..., 4)."""
        u = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        half = 0.5 * (u + 1.0)  # in [0, 1]
        return {"amplitude": half[..., 0] * self.max_amplitude,
                "frequency": half[..., 1] * self.max_frequency,
                "phase_lag": u[..., 2] * math.pi,
                "offset": u[..., 3] * self.max_offset}

    def encode(self, amplitude, frequency, phase_lag, offset=0.0) -> np.ndarray:
        """The action (float64, 4) whose :meth:`decode` gives these parameters (a serpenoid as a CPG action)."""
        values = [2.0 * amplitude / self.max_amplitude - 1.0, 2.0 * frequency / self.max_frequency - 1.0,
                  phase_lag / math.pi, offset / self.max_offset if self.max_offset else 0.0]
        action = np.array(values)
        if not np.all(np.abs(action) <= 1.0 + 1e-12):
            raise ValueError(f"parameters outside the CPG's ranges: {dict(zip(CPG_PARAMETERS, values))}")
        return np.clip(action, -1.0, 1.0)

    def torque_action(self, action, obs, phase) -> tuple[np.ndarray, np.ndarray]:
        """(env action = PD torque / max_torque in [-1, 1] (float32), phase psi after the step (rad))
        for the CPG ``action`` at phase ``phase`` (rad)."""
        p = self.decode(action)
        angle = np.asarray(phase, dtype=np.float64)[..., None] + np.arange(self.n_joints) * p["phase_lag"][..., None]
        amplitude = p["amplitude"][..., None]
        reference = amplitude * np.sin(angle) + p["offset"][..., None]
        reference_rate = amplitude * p["frequency"][..., None] * np.cos(angle)
        next_phase = np.mod(phase + p["frequency"] * self.dt, 2.0 * math.pi)
        return self.track(reference, reference_rate, obs), next_phase
