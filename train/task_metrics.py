"""Per-episode task metrics for ``snake-eval``, computed from the env's step info.

Every task: the cost of transport
    CoT = sum_steps actuator_power * dt / (m_total g * distance travelled)   (dimensionless),
actuator_power = sum_k |T_k dphi_k| / dt (W, see ``snake_env.tasks.base.actuator_power``),
the distance being the length of the CM's path (m); nan when the CM did not move.
Task metrics: reach: success (within the env's distance_threshold at some step;
the episode ends there by default) and final goal distance (m); path: mean
|cross-track error| (m) and along-track speed (m/s); command: mean |speed error|
(m/s) and |yaw-rate error| (rad/s).
"""

from __future__ import annotations

import math

import numpy as np

# task name -> {metric: (info key, reduction)}
TASK_METRICS = {
    "forward": {},
    "reach": {"success": ("is_success", "any"), "final_goal_distance": ("goal_distance", "last")},
    "path": {"mean_cross_track_error": ("cross_track_error", "mean_abs"), "mean_path_speed": ("path_speed", "mean")},
    "command": {"mean_speed_error": ("speed_error", "mean_abs"), "mean_yaw_rate_error": ("yaw_rate_error", "mean_abs")},
}
REDUCTIONS = {
    "any": lambda v: float(np.any(v)),
    "last": lambda v: float(v[-1]),
    "mean": lambda v: float(np.mean(v)),
    "mean_abs": lambda v: float(np.mean(np.abs(v))),
}


class EpisodeRecorder:
    """Collects the step info of one episode; :meth:`metrics` reduces it."""

    def __init__(self, task: str, dt: float, weight: float, reset_info: dict):
        if task not in TASK_METRICS:
            raise ValueError(f"task must be one of {sorted(TASK_METRICS)}, got {task!r}")
        self.task = task
        self.dt = float(dt)
        self.weight = float(weight)  # m_total g (N)
        self.positions = [(reset_info["x_position"], reset_info["y_position"])]
        self.energy = 0.0  # J of actuator work, sum |T dphi|
        self.values = {key: [] for key, _ in TASK_METRICS[task].values()}

    def add(self, info: dict) -> None:
        self.positions.append((info["x_position"], info["y_position"]))
        self.energy += float(info["actuator_power"]) * self.dt
        for key in self.values:
            self.values[key].append(float(info[key]))

    def metrics(self) -> dict:
        xy = np.asarray(self.positions)
        travelled = float(np.sum(np.hypot(*np.diff(xy, axis=0).T))) if len(xy) > 1 else 0.0
        cot = self.energy / (self.weight * travelled) if travelled > 1e-9 else math.nan
        out = {"actuator_energy": self.energy, "path_length": travelled, "cost_of_transport": cot}
        for name, (key, reduction) in TASK_METRICS[self.task].items():
            out[name] = REDUCTIONS[reduction](np.asarray(self.values[key])) if self.values[key] else math.nan
        return out


def summary_keys(task: str) -> list[str]:
    return ["cost_of_transport", *TASK_METRICS[task]]


def summarize_task(task: str, results: list[dict]) -> dict:
    """Means over episodes (``success`` becomes ``success_rate``); nan episodes are left out of a mean."""
    out = {}
    for key in summary_keys(task):
        values = np.array([r[key] for r in results], dtype=np.float64)
        finite = values[np.isfinite(values)]
        name = "success_rate" if key == "success" else f"mean_{key}" if not key.startswith("mean_") else key
        out[name] = float(finite.mean()) if finite.size else None
    return out
