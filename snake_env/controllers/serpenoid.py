"""Serpenoid-gait controllers: the hand-designed baseline a learned policy must beat.

Two families, both batched over a leading axis (one parameter set per env of
a vector env, which is how :mod:`snake_env.agents.search` evaluates a population):

* ``pd``: the serpenoid curve (Hirose) as joint references,
  phi_i(t) = alpha sin(omega t + (i-1) beta) + gamma  (rad),  i = 1..n-1,
  tracked by a joint PD, T_i = kp (phi_i^ref - phi_i) + kd (phidot_i^ref - phidot_i),
  saturated at the env's torque limit. With only two degrees of freedom
  (eq. 2: u = (V_1, thetadot_1)) the body follows the head, so for n >= 4 an
  arbitrary reference is not kinematically admissible and the PD fights the
  wheel constraints; the search keeps the better family.
* ``torque``: an open-loop travelling torque wave,
  T_i(t) / max_torque = alpha sin(omega t + (i-1) beta) + gamma,  clipped to [-1, 1].

Actions are env actions: torques divided by ``max_torque`` (N m), in [-1, 1].
No gymnasium import: observations are plain arrays whose layout
(``joint_slices``) matches the env's documented observation.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields

import numpy as np

FAMILIES = ("pd", "torque")


@dataclass(frozen=True)
class SerpenoidParams:
    """One gait.

    Attributes:
        family: "pd" (tracked serpenoid curve) or "torque" (open-loop torque wave).
        amplitude: alpha; rad for "pd", fraction of max_torque for "torque".
        frequency: omega (rad/s).
        phase_lag: beta, phase between neighbouring joints (rad).
        offset: gamma; rad for "pd" (turning), fraction of max_torque for "torque".
        kp: PD stiffness (N m/rad), "pd" only.
        kd: PD damping (N m s/rad), "pd" only.
    """

    family: str
    amplitude: float
    frequency: float
    phase_lag: float
    offset: float = 0.0
    kp: float = 0.0
    kd: float = 0.0

    def __post_init__(self):
        if self.family not in FAMILIES:
            raise ValueError(f"family must be one of {list(FAMILIES)}, got {self.family!r}")
        for f in fields(self):
            if f.name == "family":
                continue
            value = getattr(self, f.name)
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
                raise ValueError(f"{f.name} must be a finite number, got {value!r}")
        if self.amplitude < 0:
            raise ValueError(f"amplitude must be >= 0, got {self.amplitude}")
        if self.frequency < 0:
            raise ValueError(f"frequency must be >= 0 (rad/s), got {self.frequency}")
        if self.kp < 0 or self.kd < 0:
            raise ValueError(f"kp and kd must be >= 0, got kp={self.kp}, kd={self.kd}")
        if self.family == "pd" and self.kp == 0 and self.kd == 0:
            raise ValueError("a 'pd' gait needs kp > 0 or kd > 0 (N m/rad, N m s/rad)")

    def to_dict(self) -> dict:
        return {k: (float(v) if k != "family" else v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, data: dict) -> "SerpenoidParams":
        if not isinstance(data, dict):
            raise ValueError(f"serpenoid parameters must be a mapping, got {data!r}")
        names = [f.name for f in fields(cls)]
        unknown = sorted(set(data) - set(names))
        if unknown:
            raise ValueError(f"unknown serpenoid parameter(s) {unknown}; valid: {names}")
        missing = [n for n in ("family", "amplitude", "frequency", "phase_lag") if n not in data]
        if missing:
            raise ValueError(f"serpenoid parameters miss {missing}")
        values = {k: (v if k == "family" else float(v)) if isinstance(v, (int, float, str)) else v
                  for k, v in data.items()}
        return cls(**values)


def joint_slices(n_links: int, include_position: bool = False) -> tuple[slice, slice]:
    """Slices of the joint angles phi (rad) and joint rates phidot (rad/s) in
    the env observation [x, y]? + phi (n-1) + cos/sin heading + (V_1, thetadot_1) + phidot (n-1)."""
    start = 2 if include_position else 0
    phi = slice(start, start + n_links - 1)
    rates_start = start + (n_links - 1) + 2 + 2
    return phi, slice(rates_start, rates_start + n_links - 1)


def reference(t, n_joints: int, amplitude, frequency, phase_lag, offset):
    """Serpenoid joint references and their rates, shape (B, n_joints) (rad, rad/s).

    All parameters broadcast against ``t`` of shape (B,) (or scalar)."""
    t = np.atleast_1d(np.asarray(t, dtype=np.float64))
    index = np.arange(n_joints)
    a, w, b, g = (np.atleast_1d(np.asarray(v, dtype=np.float64))[:, None] for v in
                  (amplitude, frequency, phase_lag, offset))
    phase = w * t[:, None] + index[None, :] * b
    return a * np.sin(phase) + g, a * w * np.cos(phase)


class SerpenoidController:
    """Batched serpenoid gait: ``act(obs)`` returns env actions (B, n-1) and
    advances each env's clock by ``dt`` (s, one env step).

    ``params`` is one :class:`SerpenoidParams` (shared by every env) or a list
    of them (one per env; families may differ between envs).
    """

    def __init__(self, params, n_links: int, max_torque: float, dt: float, num_envs: int = 1,
                 include_position: bool = False):
        plist = [params] if isinstance(params, SerpenoidParams) else list(params)
        if not plist or not all(isinstance(p, SerpenoidParams) for p in plist):
            raise ValueError("params must be a SerpenoidParams or a non-empty list of them")
        if len(plist) == 1:
            plist = plist * num_envs
        if len(plist) != num_envs:
            raise ValueError(f"params must hold 1 or num_envs={num_envs} gaits, got {len(plist)}")
        if not (isinstance(n_links, int) and n_links >= 2):
            raise ValueError(f"n_links must be an integer >= 2, got {n_links!r}")
        if not (max_torque > 0 and math.isfinite(max_torque)):
            raise ValueError(f"max_torque must be > 0 (N m), got {max_torque!r}")
        if not (dt > 0 and math.isfinite(dt)):
            raise ValueError(f"dt must be > 0 (s), got {dt!r}")
        self.gaits = tuple(plist)
        self.is_pd = np.array([p.family == "pd" for p in plist])
        self.n_links = n_links
        self.max_torque = float(max_torque)
        self.dt = float(dt)
        self.num_envs = num_envs
        self.phi_slice, self.rate_slice = joint_slices(n_links, include_position)
        table = {f.name: np.array([getattr(p, f.name) for p in plist], dtype=np.float64)
                 for f in fields(SerpenoidParams) if f.name != "family"}
        self._p = table
        self.time = np.zeros(num_envs)

    @property
    def params(self) -> SerpenoidParams | None:
        """The gait every env runs, or None when the envs run different gaits."""
        return self.gaits[0] if len(set(self.gaits)) == 1 else None

    @property
    def phase(self) -> np.ndarray:
        """omega t of each env's gait (rad), t the clock (s)."""
        return self._p["frequency"] * self.time

    def reset(self, mask=None) -> None:
        """Restart the clock of every env (or of those where ``mask`` is True)."""
        if mask is None:
            self.time[:] = 0.0
        else:
            self.time[np.asarray(mask, dtype=bool)] = 0.0

    def act(self, obs) -> np.ndarray:
        obs = np.asarray(obs, dtype=np.float64)
        single = obs.ndim == 1
        obs = np.atleast_2d(obs)
        if obs.shape[0] != self.num_envs:
            raise ValueError(f"obs must have {self.num_envs} rows, got shape {obs.shape}")
        p = self._p
        n_joints = self.n_links - 1
        wave, wave_rate = reference(self.time, n_joints, p["amplitude"], p["frequency"], p["phase_lag"], p["offset"])
        action = wave  # "torque": the wave is the action (units of max_torque)
        if self.is_pd.any():
            phi = obs[:, self.phi_slice]
            phidot = obs[:, self.rate_slice]
            # "pd": the wave is the joint reference (rad); the wrapped joint
            # angle is fine here because the soft limits keep |phi| < pi
            torque = p["kp"][:, None] * (wave - phi) + p["kd"][:, None] * (wave_rate - phidot)
            action = np.where(self.is_pd[:, None], torque / self.max_torque, wave)
        self.time += self.dt
        action = np.clip(action, -1.0, 1.0).astype(np.float32)
        return action[0] if single else action
