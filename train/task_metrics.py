"""Per-episode task metrics for ``snake-eval``, computed from the env's step info.

Every task: the cost of transport
    CoT = sum_steps actuator_power * dt / (m_total g * distance travelled)   (dimensionless),
actuator_power (W) the motors' delivered power sum_k |s A_k phidot_k| (``snake_env.tasks.base.common_step_values``),
the distance being the length of the CM's path (m); nan when the CM did not move.
The task's own metrics come from its class (:attr:`snake_env.tasks.Task.episode_metrics`,
``{metric: (info key, reduction)}``): reach: success (within the env's
distance_threshold at some step; the episode ends there by default) and final
goal distance (m); path: mean |cross-track error| (m) and along-track speed
(m/s); command: mean |speed error| (m/s) and |yaw-rate error| (rad/s).
"""

from __future__ import annotations

import math

import numpy as np

from snake_env.train.gait_metrics import GaitRecorder

REDUCTIONS = {
    "any": lambda v: float(np.any(v)),
    "last": lambda v: float(v[-1]),
    "mean": lambda v: float(np.mean(v)),
    "mean_abs": lambda v: float(np.mean(np.abs(v))),
}


class EpisodeRecorder:
    """Collects the step info (and the joint state, for the gait metrics of
    :mod:`snake_env.train.gait_metrics`) of one episode; :meth:`metrics` reduces it."""

    def __init__(self, episode_metrics: dict, dt: float, weight: float, reset_info: dict, wheel_load=None,
                 wheel_friction: float | None = None):
        self.episode_metrics = dict(episode_metrics)  # the task class's {metric: (info key, reduction)}
        self.dt = float(dt)
        self.weight = float(weight)  # m_total g (N)
        self.positions = [(reset_info["x_position"], reset_info["y_position"])]
        self.energy = 0.0  # J of actuator work, sum |T dphi|
        self.values = {key: [] for key, _ in self.episode_metrics.values()}
        self.gait = GaitRecorder(dt, wheel_load, wheel_friction)

    def add(self, info: dict, joint_state=None, wheel_lateral_force=None) -> None:
        """One step's info; ``joint_state`` (phi, phidot, torque) after it adds the gait metrics and
        ``wheel_lateral_force`` (N, per wheel) the grip metrics."""
        self.positions.append((info["x_position"], info["y_position"]))
        if joint_state is not None:
            self.gait.add(joint_state, info["actuator_power"], wheel_lateral_force, info.get("wheel_slip"))
        self.energy += float(info["actuator_power"]) * self.dt
        for key in self.values:
            self.values[key].append(float(info[key]))

    def metrics(self) -> dict:
        xy = np.asarray(self.positions)
        travelled = float(np.sum(np.hypot(*np.diff(xy, axis=0).T))) if len(xy) > 1 else 0.0
        cot = self.energy / (self.weight * travelled) if travelled > 1e-9 else math.nan
        out = {"actuator_energy": self.energy, "path_length": travelled, "cost_of_transport": cot}
        if self.gait.angles:
            out.update(self.gait.metrics())
        for name, (key, reduction) in self.episode_metrics.items():
            out[name] = REDUCTIONS[reduction](np.asarray(self.values[key])) if self.values[key] else math.nan
        return out


def summarize_task(episode_metrics: dict, results: list[dict]) -> dict:
    """Means over episodes of the cost of transport and the task's ``episode_metrics`` (``success``
    becomes ``success_rate``); nan episodes are left out of a mean."""
    out = {}
    for key in ("cost_of_transport", *episode_metrics):
        values = np.array([r[key] for r in results], dtype=np.float64)
        finite = values[np.isfinite(values)]
        name = "success_rate" if key == "success" else f"mean_{key}" if not key.startswith("mean_") else key
        out[name] = float(finite.mean()) if finite.size else None
    return out
