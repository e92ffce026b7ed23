"""Per-episode gait metrics for ``snake-eval``: what a policy does with its joints, so that a
gait a robot could not run shows at a glance.

From the joint state sampled once per env step (dt s) over an episode of L steps
(:meth:`snake_env.envs.SnakeEnv.joint_state`):

- ``dominant_joint_frequency`` (Hz): the peak, DC left out, of the power spectrum of the
  joint angles phi_k(t) (each minus its mean), summed over the joints; resolution
  1 / (L dt), at most the control's Nyquist frequency 1 / (2 dt) (12.5 Hz at dt = 0.04 s);
  nan for fewer than 4 steps. A policy that flips its torques every step peaks there.
- ``peak_joint_rate`` (rad/s): max |phidot_k| over the joints and the step ends (a lower
  bound of the peak inside the steps). A geared servo of the class snake robots are built
  from turns about 3 rad/s without load.
- ``torque_sign_flip_share``: for each joint the share of consecutive steps whose held
  torques have opposite signs; the largest over the joints (1.0: bang-bang chatter).
- ``mean_power``, ``peak_power`` (W): of ``info["actuator_power"]``, the motors' delivered power
  sum_k |s A_k phidot_k| (``snake_env.tasks.base.common_step_values``).
- ``median_grip_demand``, ``peak_grip_demand``: the wheels' lateral force over their load,
  |lambda_k| / (m_k g) (``info["wheel_lateral_force"]``, eq. 27's multipliers), over all
  wheel-steps; ``outside_friction_cone_share``: the share of wheel-steps with |lambda_k| above
  mu m_k g (``snake_env.physics.config.sliding``: a wheel the traction limit holds at mu m_k g, up to
  rounding, is inside), mu the env's ``wheel_friction`` or, for unlimited grip, :data:`REFERENCE_FRICTION`.
  A rubber wheel holds about its load (mu 0.8-1); the no-slip model is exact only inside the cone.
- ``wheel_slip_share``: the share of wheel-steps the env flags in ``info["wheel_slip"]``: on the no-slip
  wheels, those outside the cone (the same count); on sliding wheels (``wheel_model="sliding"``), whose force
  never exceeds the grip, those that slide. nan where the env reports no ``wheel_slip`` (unlimited grip).
"""

from __future__ import annotations

import math

import numpy as np

from snake_env.physics.config import DEFAULT_WHEEL_FRICTION, sliding

GAIT_METRICS = ("dominant_joint_frequency", "peak_joint_rate", "torque_sign_flip_share", "mean_power", "peak_power",
                "median_grip_demand", "peak_grip_demand", "outside_friction_cone_share", "wheel_slip_share")
# how the episode values of a gait metric combine over episodes in snake-eval's summary
SUMMARY = {"dominant_joint_frequency": "mean", "peak_joint_rate": "max", "torque_sign_flip_share": "mean",
           "mean_power": "mean", "peak_power": "max", "median_grip_demand": "mean", "peak_grip_demand": "max",
           "outside_friction_cone_share": "mean", "wheel_slip_share": "mean"}
# mu of the cone share when the env's wheels grip without limit: the default wheels' (rubber on concrete), so a
# v2 (unlimited grip) run and a v3 run are held to the same cone
REFERENCE_FRICTION = DEFAULT_WHEEL_FRICTION
MIN_STEPS = 4


def dominant_frequency(angles: np.ndarray, dt: float) -> float:
    """Peak frequency (Hz, DC excluded) of the summed power spectra of the columns of ``angles`` (L, k)."""
    angles = np.asarray(angles, dtype=np.float64)
    if angles.shape[0] < MIN_STEPS:
        return math.nan
    centred = angles - angles.mean(axis=0)
    power = np.sum(np.abs(np.fft.rfft(centred, axis=0)) ** 2, axis=1)
    if not np.any(power[1:] > 0.0):
        return 0.0  # a body that never bends has no gait frequency
    frequencies = np.fft.rfftfreq(angles.shape[0], d=dt)
    return float(frequencies[1 + int(np.argmax(power[1:]))])


def sign_flip_share(torques: np.ndarray) -> float:
    """The largest share, over the columns of ``torques`` (L, k), of consecutive rows of opposite signs."""
    torques = np.asarray(torques, dtype=np.float64)
    if torques.shape[0] < 2 or torques.shape[1] == 0:
        return math.nan
    flips = np.sign(torques[1:]) * np.sign(torques[:-1]) < 0.0
    return float(flips.mean(axis=0).max())


class GaitRecorder:
    """Joint angles, rates, torques and actuator power of one episode, one sample per env step."""

    def __init__(self, dt: float, wheel_load=None, wheel_friction: float | None = None):
        """``wheel_load``: m_k g (N) of every wheel, for the grip metrics; ``wheel_friction``: the env's mu."""
        self.dt = float(dt)
        self.wheel_load = None if wheel_load is None else np.asarray(wheel_load, np.float64)
        self.friction = REFERENCE_FRICTION if wheel_friction is None else float(wheel_friction)
        self.angles, self.rates, self.torques, self.power, self.grip, self.slip = [], [], [], [], [], []

    def add(self, joint_state, actuator_power: float, wheel_lateral_force=None, wheel_slip=None) -> None:
        """``joint_state``: (phi (rad), phidot (rad/s), torque (N m)) after the step; ``wheel_lateral_force``
        (N, per wheel) of the step when the recorder knows the wheel loads; ``wheel_slip`` (bool, per wheel) the
        step's info flags, if the env reports them."""
        if wheel_slip is not None:
            self.slip.append(np.asarray(wheel_slip, dtype=bool))
        phi, phidot, torque = joint_state
        self.angles.append(np.array(phi, dtype=np.float64))
        self.rates.append(np.array(phidot, dtype=np.float64))
        self.torques.append(np.array(torque, dtype=np.float64))
        self.power.append(float(actuator_power))
        if self.wheel_load is not None and wheel_lateral_force is not None:
            self.grip.append(np.abs(np.asarray(wheel_lateral_force, np.float64)) / self.wheel_load)

    def metrics(self) -> dict:
        if not self.angles:
            return {key: math.nan for key in GAIT_METRICS}
        rates = np.abs(np.asarray(self.rates))
        return {
            "dominant_joint_frequency": dominant_frequency(np.asarray(self.angles), self.dt),
            "peak_joint_rate": float(rates.max()) if rates.size else math.nan,
            "torque_sign_flip_share": sign_flip_share(np.asarray(self.torques)),
            "mean_power": float(np.mean(self.power)),
            "peak_power": float(np.max(self.power)),
            **self._grip_metrics(),
            "wheel_slip_share": float(np.mean(np.concatenate(self.slip))) if self.slip else math.nan,
        }

    def _grip_metrics(self) -> dict:
        if not self.grip:
            return {key: math.nan for key in ("median_grip_demand", "peak_grip_demand", "outside_friction_cone_share")}
        demand = np.concatenate(self.grip)  # |lambda| / (m g) of every wheel-step
        return {"median_grip_demand": float(np.median(demand)), "peak_grip_demand": float(demand.max()),
                "outside_friction_cone_share": float(np.mean(sliding(demand, self.friction)))}


def summarize_gait(results: list[dict]) -> dict:
    """Gait metrics over episodes: means, and the largest peak (``max_peak_*``); nan episodes left out."""
    out = {}
    for key, how in SUMMARY.items():
        values = np.array([r[key] for r in results if r.get(key) is not None], dtype=np.float64)
        finite = values[np.isfinite(values)]
        name = f"{how}_{key}" if not key.startswith("mean_") else key
        out[name] = (float(finite.mean() if how == "mean" else finite.max()) if finite.size else None)
    return out
