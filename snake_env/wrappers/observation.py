"""Observation modes: a clock (``phase_observation``), the wheels' share of their grip
(``wheel_grip_observation``) and the goal in the snake's heading frame (``goal_frame``); each a batched
mode and its single and vector wrappers (:mod:`.base`)."""

from __future__ import annotations

import numbers
from collections.abc import Sequence

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from .base import BatchedMode, SingleEnvWrapper, VectorEnvWrapper, append, env_geometry, number, selected


def _frequencies(frequencies) -> np.ndarray:
    if isinstance(frequencies, numbers.Real) and not isinstance(frequencies, bool):
        frequencies = [frequencies]
    if not isinstance(frequencies, Sequence) or isinstance(frequencies, str) or not frequencies:
        raise ValueError(f"frequencies must be a number or a non-empty list of numbers > 0 (rad/s), got {frequencies!r}")
    return np.array([number("frequencies", f, "rad/s", strict=True) for f in frequencies])


def _phase_features(time: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """(..., 2 k) = [sin(w_1 t), cos(w_1 t), ..., sin(w_k t), cos(w_k t)]."""
    angle = np.asarray(time, dtype=np.float64)[..., None] * omega
    return np.stack([np.sin(angle), np.cos(angle)], axis=-1).reshape(*angle.shape[:-1], 2 * omega.size)


class _PhaseClock(BatchedMode):
    """One clock per row: t = (env steps since the episode's reset) dt (s); appends
    sin(w t), cos(w t) per frequency w (rad/s)."""

    attributes = ("omega", "dt")

    def __init__(self, env, num_envs: int, frequencies):
        self.omega = _frequencies(frequencies)
        self.dt = env_geometry(env)["dt"]
        self.extra = 2 * self.omega.size
        self.steps = np.zeros(num_envs, np.int64)

    def restart(self, mask=None) -> None:
        self.steps[selected(mask)] = 0

    def stepped(self) -> None:
        self.steps += 1

    def observe(self, obs, rows=slice(None)):
        return append(obs, _phase_features(self.steps[rows] * self.dt, self.omega))


class PhaseObservation(SingleEnvWrapper):
    """Appends ``sin(w t), cos(w t)`` per frequency ``w`` (rad/s) to the
    observation; ``t`` (s) counts env steps since the reset times the env's dt.

    A serpenoid gait is driven by such a clock; a Markov policy without one must build its own
    oscillator from state feedback. With ``joint_target`` (:class:`JointTargetAction`), a policy
    *linear* in these two features is exactly a serpenoid curve,
    ``alpha sin(w t + i beta) = alpha (cos(i beta) sin(w t) + sin(i beta) cos(w t))``.

    Args:
        frequencies: one frequency or a list (rad/s), default 25.0 (4 env steps of 0.04 s per
            period at 40 rad/s).
    """

    def __init__(self, env: gym.Env, frequencies=25.0):
        super().__init__(env, _PhaseClock(env, 1, frequencies), frequencies=frequencies)


class PhaseObservationVector(VectorEnvWrapper):
    """:class:`PhaseObservation` for a batched vector env: one clock per sub-env,
    restarted with the sub-env's (auto)reset; ``info["final_obs"]`` (same-step
    autoreset) carries the phase of the episode's last step."""

    def __init__(self, env, frequencies=25.0):
        super().__init__(env, _PhaseClock(env, env.num_envs, frequencies))


class _WheelGrip(BatchedMode):
    """Per row, each wheel's lateral force at the last step's end over its grip, F_k / (mu m_k g), read from
    the step's ``info["wheel_lateral_force"]``; zero after a reset."""

    attributes = ("grip",)
    bound = np.inf  # a no-slip wheel's force may exceed its grip (the motion's own excess); a sliding one's cannot

    def __init__(self, env, num_envs: int):
        grip = getattr(env.unwrapped, "wheel_grip", None)
        if grip is None:
            raise ValueError("wheel_grip_observation needs wheels with a grip: wheel_friction must be a number > 0 "
                             "(the default from v3), got wheel_friction=None")
        self.grip = grip  # (B, n) N, updated in place by a randomized env's resets
        self.extra = grip.shape[1]
        self.usage = np.zeros((num_envs, self.extra))

    def restart(self, mask=None) -> None:
        self.usage[selected(mask)] = 0.0

    def seen(self, info: dict) -> None:
        force = np.asarray(info["wheel_lateral_force"], np.float64).reshape(self.usage.shape)
        np.divide(force, self.grip, out=self.usage)

    def observe(self, obs, rows=slice(None)):
        return append(obs, self.usage[rows])


class WheelGripObservation(SingleEnvWrapper):
    """Appends each wheel's share of its grip, ``F_k / (mu m_k g)``, to the observation: its lateral force
    at the last step's end (``info["wheel_lateral_force"]``, N) over the most the floor gives it (N); 0 after a
    reset.

    On the sliding wheels (v4) a wheel at +-1 slides, and one near it is about to: the observation says how
    close each wheel is to the friction cone's edge, which the joint angles and rates alone do not (while wheels
    slide, the body's lateral velocity is not in the observation). It is meant for policies asked to keep
    within the grip (``slip_cost_weight``, :class:`snake_env.train.callbacks.SlipCostLagrangian`). On the
    no-slip wheels (v3) a share can exceed 1: the motion asks more than the grip. Needs ``wheel_friction``.
    """

    def __init__(self, env: gym.Env):
        super().__init__(env, _WheelGrip(env, 1))


class WheelGripObservationVector(VectorEnvWrapper):
    """:class:`WheelGripObservation` for a batched vector env (one row per sub-env, zeroed by its
    (auto)reset; ``info["final_obs"]`` of same-step autoreset carries the episode's last shares)."""

    def __init__(self, env):
        super().__init__(env, _WheelGrip(env, env.num_envs))


def _goal_frame_geometry(env) -> dict:
    """:func:`.base.env_geometry` of a goal task's env (single or vector); a one-line ValueError for
    any other observation space. ``train/extractors.py`` reads the goal-frame layout from it."""
    g = env_geometry(env)
    space = env.observation_space if not hasattr(env, "single_observation_space") else env.single_observation_space
    if not isinstance(space, spaces.Dict) or not {"observation", "achieved_goal", "desired_goal"} <= set(space.spaces):
        raise ValueError("goal_frame needs a goal task (Dict observation with observation, achieved_goal, "
                         f"desired_goal), e.g. snake_env/SnakeReach5-v1; got {space}")
    return g


def _with_goal_frame(obs, g: dict):
    """obs with R(-theta_bar) (desired_goal - achieved_goal) (m) appended to its ``observation`` entry;
    theta_bar = theta_1 + (1/n) sum_j (n - j) phi_j, since theta_k = theta_1 + sum_{j<k} phi_j."""
    o = np.asarray(obs["observation"])
    n, phi = g["n_links"], g["phi"]
    theta_1 = np.arctan2(o[..., phi.stop + 1], o[..., phi.stop])
    theta_bar = theta_1 + o[..., phi].astype(np.float64) @ ((n - np.arange(1, n)) / n)
    delta = np.asarray(obs["desired_goal"], np.float64) - np.asarray(obs["achieved_goal"], np.float64)
    cos, sin = np.cos(theta_bar), np.sin(theta_bar)
    ahead = cos * delta[..., 0] + sin * delta[..., 1]
    left = -sin * delta[..., 0] + cos * delta[..., 1]
    extra = np.stack([ahead, left], axis=-1).astype(o.dtype)
    return {**obs, "observation": np.concatenate([o, extra], axis=-1)}


class _GoalFrame(BatchedMode):
    """Appends the goal in the heading frame (:func:`_with_goal_frame`); no state."""

    attributes = ("_geometry",)
    extra = 2
    bound = np.inf

    def __init__(self, env):
        self._geometry = _goal_frame_geometry(env)

    def observe(self, obs, rows=slice(None)):
        return _with_goal_frame(obs, self._geometry)


class GoalFrameObservation(SingleEnvWrapper):
    """Goal tasks: the goal relative to the CM in the heading frame (m) appended to ``observation``.

    The appended pair is ``R(-theta_bar) (desired_goal - achieved_goal)`` (m; x ahead, y to the
    left), theta_bar the mean link angle, computed from the observation (theta_1 from its heading
    entries plus the joint angles). It is the goal's bearing, which an MLP would otherwise have to
    compute from world coordinates (a rotation by the heading). It is derived from
    ``desired_goal``, so HER's relabelled goals would leave it stale: on-policy only (the
    ``goal_frame`` features extractor of ``snake_env.train.extractors`` computes it inside the
    policy instead, from whatever goal the batch holds).
    """

    def __init__(self, env: gym.Env):
        super().__init__(env, _GoalFrame(env))


class GoalFrameObservationVector(VectorEnvWrapper):
    """:class:`GoalFrameObservation` for a batched vector env (one row per sub-env), also on the
    ``final_obs`` of same-step autoreset (which gymnasium's VectorObservationWrapper refuses)."""

    def __init__(self, env):
        super().__init__(env, _GoalFrame(env))
