"""Steered serpenoid baselines for the path, command and reach tasks.

The cascaded controller of Liljebäck, Pettersen, Stavdahl and Gravdahl
("Path following control of planar snake robots", 2011): an inner loop makes
the joints track a serpenoid curve
    phi_i^ref(t) = alpha sin(Phi(t) + (i-1) beta) + gamma,   dPhi/dt = omega,
with a joint PD (the gait of ``configs/serpenoid.yaml``, family "pd"), and an
outer loop steers the snake by the joint offset gamma, which turns it
(measured on Snake5: gamma = +0.1 rad turns it left at ~0.9 rad/s):
- :class:`LineOfSightController` (path task): the line-of-sight heading
  theta_ref = psi - arctan(e / Delta) (psi the path tangent, e the cross-track
  error, Delta the look-ahead distance), gamma = k_theta (theta_ref - theta_bar),
  theta_bar the mean link angle;
- :class:`SteeringController` (command task): theta_ref integrates the
  commanded yaw rate, gamma = w_cmd / G + k_theta (theta_ref - theta_bar) with
  G the measured turning gain (rad/s per rad of offset), and the frequency is
  scaled by v_cmd / v_gait (with no-slip wheels the speed is proportional to
  the gait frequency for one body shape);
- :class:`GoalSeekingController` (reach task): pure pursuit of the goal by the
  centre of mass, driving forwards or (phase running backwards) backwards,
  whichever faces the goal; a goal inside a minimum turning circle cannot be
  reached by turning, so the snake first backs away from it with the body
  straight (a three-point turn).
gamma is clipped to +-``max_offset``. All read only the observation
(documented layouts of the tasks), no gymnasium import; actions are torques
in units of ``max_torque``, batched over a leading axis.

:func:`make_baseline` builds a task's baseline with the settings of
``baselines.yaml`` (:func:`snake_env.configfiles.config_path`) for its number of links (found by
:mod:`snake_env.agents.baseline_search`); a task and n without an entry use the
constructor defaults, tuned on Snake5.
"""

from __future__ import annotations

import math

import numpy as np
import yaml

from snake_env.configfiles import config_path

from .serpenoid import SerpenoidParams, joint_slices

TURN_GAIN = 9.0  # rad/s of yaw rate per rad of joint offset, measured on Snake5 with its searched gait
SETTINGS_FILE = "baselines.yaml"  # resolved by snake_env.configfiles.config_path


def _check_positive(**values) -> None:
    """One-line ValueError naming the first argument that is not a finite number > 0."""
    for name, value in values.items():
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a finite number > 0, got {value!r}")


def wrap(angle):
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def mean_link_angle(obs: np.ndarray, n_links: int, include_position: bool) -> np.ndarray:
    """theta_bar (rad, wrapped) from the physics observation: theta_1 from cos/sin, theta_k by summing the joint angles."""
    start = 2 if include_position else 0
    phi = obs[:, start:start + n_links - 1]
    heading = obs[:, start + n_links - 1:start + n_links + 1]
    theta1 = np.arctan2(heading[:, 1], heading[:, 0])
    offsets = np.concatenate([np.zeros((obs.shape[0], 1)), np.cumsum(phi, axis=1)], axis=1)
    return wrap(theta1 + offsets.mean(axis=1))


class SteeredSerpenoid:
    """The inner loop: a PD-tracked serpenoid whose phase is integrated (so the
    frequency may change) and whose offset gamma steers."""

    tunable: tuple[str, ...] = ()  # the constructor settings a baselines.yaml entry may give per n

    def __init__(self, params: SerpenoidParams, n_links: int, max_torque: float, dt: float, num_envs: int = 1,
                 include_position: bool = False, gain: float = 0.3, lookahead: float = 0.6,
                 max_offset: float = 0.15):
        if params.family != "pd":
            raise ValueError(f"the steered serpenoid needs a 'pd' gait (joint references), got family {params.family!r}")
        _check_positive(max_torque=max_torque, dt=dt, lookahead=lookahead, max_offset=max_offset)
        self.params = params
        self.n_links = n_links
        self.max_torque = float(max_torque)
        self.dt = float(dt)
        self.num_envs = num_envs
        self.include_position = include_position
        self.gain = float(gain)
        self.lookahead = float(lookahead)
        self.max_offset = float(max_offset)
        self.phi_slice, self.rate_slice = joint_slices(n_links, include_position)
        self.physics_size = 2 * n_links + 2 + (2 if include_position else 0)
        self.phase = np.zeros(num_envs)

    def reset(self, mask=None) -> None:
        self.phase[(slice(None) if mask is None else np.asarray(mask, bool))] = 0.0

    def gait_action(self, obs: np.ndarray, offset: np.ndarray, freq_scale: np.ndarray) -> np.ndarray:
        p = self.params
        omega = p.frequency * freq_scale
        index = np.arange(self.n_links - 1)
        angle = self.phase[:, None] + index[None, :] * p.phase_lag
        ref = p.amplitude * np.sin(angle) + offset[:, None]
        ref_rate = p.amplitude * omega[:, None] * np.cos(angle)
        phi, phidot = obs[:, self.phi_slice], obs[:, self.rate_slice]
        torque = p.kp * (ref - phi) + p.kd * (ref_rate - phidot)
        self.phase += omega * self.dt
        return np.clip(torque / self.max_torque, -1.0, 1.0).astype(np.float32)

    def guidance(self, obs) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
        """The outer loop: (physics observation (B, ...), offset gamma (B,) rad, signed gait frequency
        scale (B,), whether ``obs`` was a single observation); advances the guidance's own state."""
        raise NotImplementedError

    def act(self, obs) -> np.ndarray:
        """Joint torques / max_torque of the cascade: :meth:`guidance`, then the PD serpenoid."""
        physics, offset, freq_scale, single = self.guidance(obs)
        action = self.gait_action(physics, offset, freq_scale)
        return action[0] if single else action

    def _batch(self, obs):
        if isinstance(obs, dict):
            raise ValueError("this controller reads a Box observation, got a Dict (the reach task's baseline is "
                             "GoalSeekingController)")
        obs = np.asarray(obs, dtype=np.float64)
        single = obs.ndim == 1
        obs = np.atleast_2d(obs)
        if obs.shape != (self.num_envs, self.physics_size + 4):
            raise ValueError(f"obs must have shape ({self.num_envs}, {self.physics_size + 4}) (physics observation "
                             f"+ 4 task entries), got {obs.shape}")
        return obs, single


class StraightGait(SteeredSerpenoid):
    """The searched serpenoid run straight (gamma = 0, the gait's own frequency): guidance that reads
    no goal, command or path, so a policy that corrects it (``steering_residual: {baseline: gait}``)
    may have its goals relabelled by HER. Reads the physics observation (or a Dict's ``observation``)."""

    def guidance(self, obs):
        raw = np.asarray(obs["observation"] if isinstance(obs, dict) else obs, dtype=np.float64)
        physics = np.atleast_2d(raw)
        if physics.shape[0] != self.num_envs or physics.shape[1] < self.physics_size:
            raise ValueError(f"observation must have shape ({self.num_envs}, >= {self.physics_size}), got "
                             f"{physics.shape}")
        return physics, np.zeros(self.num_envs), np.ones(self.num_envs), raw.ndim == 1


class LineOfSightController(SteeredSerpenoid):
    """Path task: gamma = kappa v / G + k_theta (theta_ref - theta_bar), theta_ref = psi - arctan(e / Delta).

    The gait runs at ``speed_scale`` times its frequency (v ~ speed_scale * gait_speed);
    the curvature feed-forward kappa v / G (G = :data:`TURN_GAIN`) is zero on a line,
    where this is Liljebäck's LOS law. The path observation ends with e (m), cos and
    sin of (psi - theta_bar), curvature kappa (1/m)."""

    tunable = ("gain", "lookahead", "max_offset", "speed_scale")  # what the settings file may set per n

    def __init__(self, params, n_links, max_torque, dt, gait_speed: float, num_envs: int = 1,
                 include_position: bool = False, gain: float = 0.1, lookahead: float = 3.0,
                 max_offset: float = 0.25, speed_scale: float = 1.0):
        super().__init__(params, n_links, max_torque, dt, num_envs, include_position, gain, lookahead, max_offset)
        _check_positive(gait_speed=gait_speed, speed_scale=speed_scale)
        self.speed = float(gait_speed) * float(speed_scale)
        self.speed_scale = float(speed_scale)

    def guidance(self, obs):
        obs, single = self._batch(obs)
        error, curvature = obs[:, -4], obs[:, -1]
        relative = np.arctan2(obs[:, -2], obs[:, -3])  # psi - theta_bar
        heading_error = wrap(relative - np.arctan(error / self.lookahead))  # theta_ref - theta_bar
        offset = np.clip(curvature * self.speed / TURN_GAIN + self.gain * heading_error,
                         -self.max_offset, self.max_offset)
        return obs, offset, np.full(self.num_envs, self.speed_scale), single


class SteeringController(SteeredSerpenoid):
    """Command task: heading reference integrated from w_cmd, frequency scaled by v_cmd / ``gait_speed``.

    The command observation ends with v_cmd (m/s), w_cmd (rad/s), filtered v, w."""

    tunable = ("gain", "max_offset")

    def __init__(self, params, n_links, max_torque, dt, gait_speed: float, num_envs: int = 1,
                 include_position: bool = False, gain: float = 0.3, max_offset: float = 0.15):
        super().__init__(params, n_links, max_torque, dt, num_envs, include_position, gain, 1.0, max_offset)
        _check_positive(gait_speed=gait_speed)
        self.gait_speed = float(gait_speed)
        self.heading_ref = np.full(num_envs, np.nan)

    def reset(self, mask=None) -> None:
        super().reset(mask)
        self.heading_ref[(slice(None) if mask is None else np.asarray(mask, bool))] = np.nan

    def guidance(self, obs):
        obs, single = self._batch(obs)
        heading = mean_link_angle(obs, self.n_links, self.include_position)
        start = np.isnan(self.heading_ref)
        self.heading_ref[start] = heading[start]
        v_cmd, w_cmd = obs[:, -4], obs[:, -3]
        error = wrap(self.heading_ref - heading)
        offset = np.clip(w_cmd / TURN_GAIN + self.gain * error, -self.max_offset, self.max_offset)
        self.heading_ref = wrap(self.heading_ref + w_cmd * self.dt)
        return obs, offset, np.clip(v_cmd / self.gait_speed, 0.0, 2.0), single


class GoalSeekingController(SteeredSerpenoid):
    """Reach task: steer the centre of mass (CM) to the goal, forwards or backwards.

    With the goal at (x_b, y_b) in the body frame (x_b along theta_bar), the gait
    runs forwards if x_b >= 0 and backwards otherwise (the serpenoid's phase
    integrated with -omega: with no-slip wheels the motion reverses), and
    gamma = s k_theta (bearing) steers, s = +-1 the direction of travel (a
    backwards-moving snake turns the other way for the same offset; the bearing is
    taken from the tail when going backwards). The minimum turning radius is
    R = gait_speed / (G max_offset) (G = ``turn_gain``, default :data:`TURN_GAIN`); a goal inside the
    turning circle on its side, x_b^2 + (|y_b| - R)^2 < R^2, is reached by no
    turn, so the snake backs away from it with gamma = 0 until the goal is
    ``hysteresis`` R from that circle's centre. (Turning while backing away, towards
    or away from the goal, reached fewer goals: 60-70% against 86% on SnakeReach5.)
    Reads the reach task's Dict observation (``observation``, ``achieved_goal`` =
    CM (m), ``desired_goal`` (m)).
    """

    tunable = ("gain", "max_offset", "hysteresis", "turn_gain")

    def __init__(self, params, n_links, max_torque, dt, gait_speed: float, num_envs: int = 1,
                 include_position: bool = False, gain: float = 0.5, max_offset: float = 0.3,
                 hysteresis: float = 1.2, turn_gain: float = TURN_GAIN):
        super().__init__(params, n_links, max_torque, dt, num_envs, include_position, gain, 1.0, max_offset)
        _check_positive(gait_speed=gait_speed, hysteresis=hysteresis, turn_gain=turn_gain)
        if hysteresis < 1.0:
            raise ValueError(f"hysteresis must be >= 1 (turning radii), got {hysteresis!r}")
        self.turn_gain = float(turn_gain)  # G (rad/s per rad of offset)
        self.turn_radius = float(gait_speed) / (self.turn_gain * self.max_offset)  # m
        self.hysteresis = float(hysteresis)
        self.backing_away = np.zeros(num_envs, bool)
        self.direction = np.zeros(num_envs)  # +1 head first, -1 tail first, 0 before the first act

    mode_size = 2

    def mode(self) -> np.ndarray:
        """(num_envs, 2): backing away (0/1) and the direction of travel of the last act. With the
        observation they determine the next action; the hysteresis makes them state, not observation."""
        return np.stack([self.backing_away.astype(np.float64), self.direction], axis=-1)

    def reset(self, mask=None) -> None:
        super().reset(mask)
        rows = slice(None) if mask is None else np.asarray(mask, bool)
        self.backing_away[rows] = False
        self.direction[rows] = 0.0

    def _goal_batch(self, obs):
        if not isinstance(obs, dict) or not {"observation", "achieved_goal", "desired_goal"} <= set(obs):
            raise ValueError("GoalSeekingController reads the reach task's Dict observation with keys "
                             "observation, achieved_goal, desired_goal")
        physics = np.asarray(obs["observation"], dtype=np.float64)
        single = physics.ndim == 1
        physics = np.atleast_2d(physics)
        cm = np.atleast_2d(np.asarray(obs["achieved_goal"], dtype=np.float64))
        goal = np.atleast_2d(np.asarray(obs["desired_goal"], dtype=np.float64))
        if physics.shape != (self.num_envs, self.physics_size) or not cm.shape == goal.shape == (self.num_envs, 2):
            raise ValueError(f"observation must have shape ({self.num_envs}, {self.physics_size}) and the goals "
                             f"({self.num_envs}, 2), got {physics.shape}, {cm.shape}, {goal.shape}")
        return physics, cm, goal, single

    def guidance(self, obs):
        physics, cm, goal, single = self._goal_batch(obs)
        heading = mean_link_angle(physics, self.n_links, self.include_position)
        to_goal = goal - cm
        cos, sin = np.cos(heading), np.sin(heading)
        ahead = cos * to_goal[:, 0] + sin * to_goal[:, 1]   # x_b (m)
        left = -sin * to_goal[:, 0] + cos * to_goal[:, 1]   # y_b (m)
        # squared distance of the goal from the centre of the turning circle on its side, in R^2
        circle = (ahead ** 2 + (np.abs(left) - self.turn_radius) ** 2) / self.turn_radius ** 2
        self.backing_away = np.where(self.backing_away, circle < self.hysteresis ** 2, circle < 1.0)
        direction = np.where(ahead >= 0.0, 1.0, -1.0)  # towards the goal, head first or tail first
        # the goal's bearing from the leading end; turning towards it needs a yaw rate of its sign, and
        # the yaw rate is G gamma times the signed gait speed, so gamma's sign follows the direction
        bearing = wrap(np.arctan2(left, ahead) + np.where(direction > 0, 0.0, math.pi))
        offset = np.clip(direction * self.gain * bearing, -self.max_offset, self.max_offset)
        # backing away straight: turning while backing away (either way) reached fewer goals
        direction = np.where(self.backing_away, -direction, direction)
        offset = np.where(self.backing_away, 0.0, offset)
        self.direction = direction
        return physics, offset, direction, single


def load_baseline_settings(path=None) -> dict:
    """``{task: {n_links: {"settings": {...}, "search": {...}}}}`` from the settings file; {} if it does not exist."""
    path = config_path(SETTINGS_FILE, path)
    data = (yaml.safe_load(path.read_text()) if path.is_file() else None) or {}
    if not isinstance(data, dict) or not all(isinstance(v, dict) for v in data.values()):
        raise ValueError(f"{path} must map a task name to {{n_links: {{settings: {{name: value}}}}}}")
    return data


def baseline_settings(task: str, controller: type[SteeredSerpenoid], n_links: int, path=None) -> dict:
    """The settings of the ``task``'s baseline (a ``controller``) for ``n_links`` links from the settings file
    (the ``settings`` of ``{task: {n: {settings: {name: value}}}}``); {} when there is no entry (the
    constructor defaults). Only the controller's ``tunable`` settings may appear."""
    path = config_path(SETTINGS_FILE, path)
    entry = load_baseline_settings(path).get(task, {}).get(int(n_links))
    if entry is None:
        return {}
    entry = entry.get("settings") if isinstance(entry, dict) else None
    if not isinstance(entry, dict):
        raise ValueError(f"{path}: {task} n_links={n_links} needs a mapping 'settings' of setting: value")
    unknown = sorted(set(entry) - set(controller.tunable))
    if unknown:
        raise ValueError(f"{path}: {task} n_links={n_links} has unknown setting {unknown[0]!r}; allowed: "
                         f"{list(controller.tunable)}")
    for name, value in entry.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{path}: {task} n_links={n_links} setting {name!r} must be a number, got {value!r}")
    return {name: float(value) for name, value in entry.items()}


def make_baseline(controller: type[SteeredSerpenoid], task: str, params: SerpenoidParams, gait_speed: float,
                  n_links: int, max_torque: float, dt: float, num_envs: int = 1, include_position: bool = False,
                  settings_path=None):
    """The ``task``'s baseline, a ``controller``, with its settings for ``n_links`` (:func:`baseline_settings`)."""
    settings = baseline_settings(task, controller, n_links, settings_path)
    return controller(params, n_links, max_torque, dt, gait_speed=float(gait_speed), num_envs=num_envs,
                      include_position=include_position, **settings)
