"""Residual modes: residual RL (Silver et al. 2018; Johannink et al. 2019) on the task's baseline
controller, the one ``snake-eval --baseline`` runs (:meth:`snake_env.tasks.Task.make_baseline`),
either on its joint torques (``serpenoid_residual``) or on the outer loop of its serpenoid cascade
(``steering_residual``); each a batched mode and its single and vector wrappers (:mod:`.base`).
The zero action is the baseline; sin and cos of the baseline gait's phase are appended to the
observation (to the ``observation`` entry of a Dict observation)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from snake_env.controllers import StraightGait, gait_for_links

from .base import (BatchedMode, SingleEnvWrapper, VectorEnvWrapper, append, controller_kwargs, env_geometry, number,
                   with_phase)

STEERING_ACTIONS = ("offset", "speed")
# what steering_residual corrects: the task's baseline (snake-eval --baseline), or the searched gait
# run straight, which reads no goal (so HER may relabel the goals of its transitions)
STEERING_BASELINES = ("task", "gait")


def _task_baseline(env, gait, num_envs: int):
    """The baseline controller of the residual wrappers: the task's own
    (:meth:`snake_env.tasks.Task.make_baseline`, the one ``snake-eval --baseline`` runs)."""
    base = env.unwrapped
    if not hasattr(base, "task"):
        raise ValueError(f"a residual wrapper needs a snake_env env with a task, got {base!r}")
    return base.task.make_baseline(base.config, num_envs=num_envs, gait=gait)


def _mode_size(controller, observe_mode) -> int:
    """Entries the baseline's hidden mode adds to the observation (``observe_mode``), 0 without it."""
    if not isinstance(observe_mode, bool):
        raise ValueError(f"observe_mode must be true or false, got {observe_mode!r}")
    if not observe_mode:
        return 0
    if not hasattr(controller, "mode"):
        raise ValueError(f"observe_mode needs a baseline with a hidden mode (the reach task's goal seeking); "
                         f"{type(controller).__name__} has none")
    return controller.mode_size


class _BaselineResidual(BatchedMode):
    """A residual on a batched baseline ``controller`` (one gait clock per row, restarted with the
    row's episode); observation + sin, cos of the gait's phase (+ its hidden mode, ``observe_mode``)."""

    attributes = ("controller", "observe_mode")
    acts = True

    def __init__(self, controller, observe_mode: bool):
        self.controller = controller
        mode_size = _mode_size(controller, observe_mode)
        self.observe_mode = mode_size > 0
        self.extra = 2 + mode_size

    def restart(self, mask=None) -> None:
        self.controller.reset(mask)

    def observe(self, obs, rows=slice(None)):
        obs = with_phase(obs, self.controller.phase[rows])
        return append(obs, self.controller.mode()[rows]) if self.observe_mode else obs


class _TorqueResidual(_BaselineResidual):
    """Env action = baseline torque + ``scale`` max_torque x action (the joint-torque residual)."""

    attributes = (*_BaselineResidual.attributes, "scale")

    def __init__(self, env, num_envs: int, scale, gait, observe_mode):
        self.scale = number("scale", scale, "fraction of max_torque", strict=True)
        if self.scale > 2.0:
            raise ValueError(f"scale must be in (0, 2] (fraction of max_torque), got {scale!r}")
        super().__init__(_task_baseline(env, gait, num_envs), observe_mode)

    def act(self, obs, action):
        base = self.controller.act(obs)  # advances the gait's clock by dt
        correction = self.scale * np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        return np.clip(base + correction, -1.0, 1.0).astype(np.float32)


class _SteeringResidual(_BaselineResidual):
    """Env action = the baseline's cascade with its guidance corrected: the gait offset gamma
    plus ``offset_scale`` rad x action[0], the gait frequency times 1 + ``speed_range`` x action[1]
    (its sign, the direction of travel, stays the baseline's)."""

    def __init__(self, env, num_envs: int, offset_scale, speed_range, baseline, observe_mode):
        self.offset_scale = number("offset_scale", offset_scale, "rad", strict=True)
        self.speed_range = number("speed_range", speed_range, "fraction of the gait frequency")
        if self.offset_scale > 1.0 or self.speed_range > 1.0:
            raise ValueError(f"offset_scale must be in (0, 1] rad and speed_range in [0, 1], got "
                             f"{offset_scale!r}, {speed_range!r}")
        if baseline not in STEERING_BASELINES:
            raise ValueError(f"baseline must be one of {list(STEERING_BASELINES)}, got {baseline!r}")
        if baseline == "gait":
            geometry = env_geometry(env)
            previous = env.unwrapped.config.versions_back
            controller = StraightGait(gait_for_links(geometry["n_links"], None, previous)[0], num_envs=num_envs,
                                      **controller_kwargs(geometry))
        else:
            controller = _task_baseline(env, None, num_envs)
            if not hasattr(controller, "guidance"):
                raise ValueError(f"steering_residual needs a task whose baseline steers the gait (path, command, "
                                 f"reach) or baseline: gait; the {env.unwrapped.task.name} task's baseline "
                                 f"{type(controller).__name__} has no steering")
        super().__init__(controller, observe_mode)
        self.action_space = spaces.Box(-1.0, 1.0, (len(STEERING_ACTIONS),), np.float32)

    def act(self, obs, action):
        physics, offset, freq_scale, _ = self.controller.guidance(obs)
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0).reshape(-1, len(STEERING_ACTIONS))
        return self.controller.gait_action(physics, offset + self.offset_scale * a[:, 0],
                                           freq_scale * (1.0 + self.speed_range * a[:, 1]))


class SerpenoidResidualAction(SingleEnvWrapper):
    """Action = correction (fraction ``scale`` of max_torque per unit) added to the task's
    baseline controller's action; observation + sin, cos of the baseline gait's phase.

    The baseline is the one ``snake-eval --baseline`` runs (forward: the searched serpenoid of
    ``configs/serpenoid.yaml``; path: line-of-sight guidance; command: the steered serpenoid;
    reach: goal seeking); the env action is ``clip(baseline(obs) + scale * action, -1, 1)``, so the
    zero action is the baseline and the policy learns a state-feedback correction of it. A policy
    trained this way starts at the baseline: report it as such. The baseline reads the goal, so
    HER's relabelled goals would pair a correction with a baseline action it was not added to: use
    it with on-policy algorithms on the reach task.

    Args:
        scale: torque of a unit action, as a fraction of max_torque, in (0, 2]; default 0.3.
        gait: forward task only: env id of a ``serpenoid.yaml`` entry (default: the newest
            ``snake_env/Snake{n}-v*`` of this env's n, a registered forward id's own). The path,
            command and reach baselines steer that gait too.
        observe_mode: reach task only: also append the baseline's hidden mode (backing away
            0/1, direction of travel +-1, 0 before the first step), without which the
            baseline's next action is not a function of the observation; default false.
    """

    def __init__(self, env: gym.Env, scale: float = 0.3, gait: str | None = None, observe_mode: bool = False):
        super().__init__(env, _TorqueResidual(env, 1, scale, gait, observe_mode), scale=scale, gait=gait,
                         observe_mode=observe_mode)


class SerpenoidResidualActionVector(VectorEnvWrapper):
    """:class:`SerpenoidResidualAction` for a batched vector env: one gait clock per sub-env,
    restarted with the sub-env's (auto)reset."""

    def __init__(self, env, scale: float = 0.3, gait: str | None = None, observe_mode: bool = False):
        super().__init__(env, _TorqueResidual(env, env.num_envs, scale, gait, observe_mode))


class SteeringResidualAction(SingleEnvWrapper):
    """Action (2,) in [-1, 1] = correction to the task baseline's steering, the outer loop of
    its cascade (Liljebäck et al. 2011): the gait offset gamma plus ``offset_scale`` rad x
    action[0], the gait frequency times 1 + ``speed_range`` x action[1]; the inner loop, the
    PD-tracked serpenoid, turns them into joint torques. The zero action is the baseline.
    Exploration noise then perturbs the heading, not the gait. Observation + sin, cos of the
    gait's phase. Path, command and reach tasks; with ``baseline: "gait"`` also the forward task.

    Args:
        offset_scale: offset of a unit action (rad), in (0, 1]; default 0.15.
        speed_range: relative frequency change of a unit action, in [0, 1]; default 0.5.
        baseline: ``"task"`` (default), the task's baseline of ``snake-eval --baseline``; or
            ``"gait"``, the searched serpenoid of this n run straight (gamma = 0), which reads no
            goal: the one that combines with HER on the reach task (any task, also forward).
        observe_mode: reach task's baseline only: as for :class:`SerpenoidResidualAction`.
    """

    def __init__(self, env: gym.Env, offset_scale: float = 0.15, speed_range: float = 0.5, baseline: str = "task",
                 observe_mode: bool = False):
        super().__init__(env, _SteeringResidual(env, 1, offset_scale, speed_range, baseline, observe_mode),
                         offset_scale=offset_scale, speed_range=speed_range, baseline=baseline,
                         observe_mode=observe_mode)


class SteeringResidualActionVector(VectorEnvWrapper):
    """:class:`SteeringResidualAction` for a batched vector env."""

    def __init__(self, env, offset_scale: float = 0.15, speed_range: float = 0.5, baseline: str = "task",
                 observe_mode: bool = False):
        super().__init__(env, _SteeringResidual(env, env.num_envs, offset_scale, speed_range, baseline, observe_mode))
