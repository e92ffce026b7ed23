"""Opt-in observation and action modes as Gymnasium wrappers (single and vector env).

The env itself stays a joint-torque env with a clock-free observation (the
mission's default). Two remedies for long snakes are offered on top of it,
each as a ``gymnasium.Wrapper`` for the single env and a
``gymnasium.vector.VectorWrapper`` for the batched vector env, with the same
arguments and the same per-step arithmetic:

* ``phase_observation`` (:class:`PhaseObservation`): appends
  ``sin(w t), cos(w t)`` for each frequency ``w`` (rad/s), ``t`` the time
  since the episode's reset (s). A serpenoid gait is driven by such a clock;
  a Markov policy without one must build its own oscillator from state
  feedback. With ``joint_target`` below, a policy *linear* in these two
  features is exactly a serpenoid curve,
  ``alpha sin(w t + i beta) = alpha (cos(i beta) sin(w t) + sin(i beta) cos(w t))``.
* ``joint_target`` (:class:`JointTargetAction`): the action is a target joint
  angle per joint, ``phi_ref = action * target_range`` (rad), tracked by a
  joint PD ``T = kp (phi_ref - phi) + kd (phidot_ref - phidot)`` saturated at
  the env's ``max_torque``, with the reference rate ``phidot_ref`` the
  target's change over the last env step divided by dt (0 on an episode's
  first step; ``reference_rate="zero"`` drops it). The serpenoid PD uses the
  curve's rate the same way: without it the searched Snake12 gait, fed as
  targets, drops from 0.92 to 0.06 m/s (docs/learning.md). The PD runs at the env-step rate (one torque per 0.04 s env
  step, held over its RK4 sub-steps: the env's own action contract), so a very
  stiff PD overshoots; see docs/learning.md for the measured tracking.

* ``cpg`` (:class:`CPGAction`): the action sets the parameters of a central
  pattern generator, as in CPG-RL (Bellegarda and Ijspeert, 2022): amplitude
  alpha (rad), frequency omega (rad/s), phase lag beta (rad) and offset gamma
  (rad) of one serpenoid wave; the PD gains are kwargs. The wrapper integrates
  the oscillator's phase psi += omega dt and tracks
  ``phi_i^ref = alpha sin(psi + (i-1) beta) + gamma`` with
  ``phidot_i^ref = alpha omega cos(psi + (i-1) beta)`` by the saturated PD, so
  a constant action is exactly the searched ``pd`` serpenoid of
  :mod:`snake_env.controllers.serpenoid` with those gains, and the policy modulates
  it from state feedback; ``sin psi, cos psi`` are appended to the observation.
  The ranges default to the serpenoid search's ``pd`` box
  (``BOXES`` of ``python -m snake_env.agents.search``), so the policy and the baseline
  choose from the same gaits.

* ``serpenoid_residual`` (:class:`SerpenoidResidualAction`): residual RL
  (Silver et al. 2018; Johannink et al. 2019) on the task's baseline
  controller, the one ``snake-eval --baseline`` runs (forward: the searched
  serpenoid of ``configs/serpenoid.yaml``; path: line-of-sight guidance;
  command: the steered serpenoid; reach: goal seeking): the env action is
  ``clip(baseline(obs) + scale * action, -1, 1)``, so the zero action is the
  baseline and the policy learns a state-feedback correction of it; sin and
  cos of the baseline gait's phase are appended to the observation (to the
  ``observation`` entry of a Dict observation). A policy trained this way
  starts at the baseline: report it as such. The baseline reads the goal, so
  HER's relabelled goals would pair a correction with a baseline action it was
  not added to: use it with on-policy algorithms on the reach task.

* ``goal_frame`` (:class:`GoalFrameObservation`): goal tasks only (Dict
  observation): appends the goal relative to the CM in the snake's heading frame,
  ``R(-theta_bar) (desired_goal - achieved_goal)`` (m; x ahead, y to the left), to
  the ``observation`` entry. theta_bar, the mean link angle, is computed from the
  observation (theta_1 from its heading entries plus the joint angles). The goal's
  bearing is what a reaching policy needs and an MLP finds hard to compute from
  world coordinates (a rotation by the heading). It is derived from
  ``desired_goal``, so HER's relabelled goals would leave it stale: on-policy only.

* ``steering_residual`` (:class:`SteeringResidualAction`): a residual on the
  outer loop of a serpenoid cascade (Liljebäck et al. 2011) instead of on the
  torques: the action (2,) shifts the gait offset gamma and scales the gait
  frequency, and the PD serpenoid stays the inner loop. ``baseline: task``
  corrects the path, command or reach baseline; ``baseline: gait`` corrects the
  searched serpenoid run straight, which reads no goal (HER may relabel) and
  also drives the forward task.

The train config selects them with the ``env_wrapper`` key (after RL Zoo's
key of that name), a mapping ``{name: {kwarg: value}}`` applied in order::

    env_wrapper: {joint_target: {kp: 1.0, kd: 0.05}, phase_observation: {frequencies: [25.0]}}

Observation layout read here (the env's documented one): [x, y]? + joint
angles phi (n-1) + cos/sin heading (2) + (V_1, thetadot_1) + joint rates (n-1).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping, Sequence

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorWrapper
from gymnasium.vector.utils import batch_space

from snake_env.controllers import StraightGait, gait_for_links

def _number(name, value, unit, minimum=0.0, strict=False) -> float:
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or (value <= minimum if strict else value < minimum):
        bound = f"{'>' if strict else '>='} {minimum}"
        raise ValueError(f"{name} must be a finite number {bound} ({unit}), got {value!r}")
    return float(value)


def _geometry(env) -> dict:
    """n_links, max_torque (N m), dt (s), joint_limit (rad or None) and the
    phi / phidot slices of the observation, read from the unwrapped env."""
    base = env.unwrapped
    try:
        n = int(base.n_links)
        max_torque = float(base.max_torque)
        dt = float(base.dt)
    except AttributeError as exc:
        raise ValueError(f"snake wrappers need a snake_env env (n_links, max_torque, dt), got {base!r}") from None
    start = 0 if getattr(base, "exclude_current_positions_from_observation", True) else 2
    phi = slice(start, start + n - 1)
    rates_start = start + (n - 1) + 4
    return dict(n_links=n, max_torque=max_torque, dt=dt, joint_limit=getattr(base, "joint_limit", None),
                phi=phi, rates=slice(rates_start, rates_start + n - 1))


def _frequencies(frequencies) -> np.ndarray:
    if isinstance(frequencies, numbers.Real) and not isinstance(frequencies, bool):
        frequencies = [frequencies]
    if not isinstance(frequencies, Sequence) or isinstance(frequencies, str) or not frequencies:
        raise ValueError(f"frequencies must be a number or a non-empty list of numbers > 0 (rad/s), got {frequencies!r}")
    return np.array([_number("frequencies", f, "rad/s", strict=True) for f in frequencies])


def _phase_features(time: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """(..., 2 k) = [sin(w_1 t), cos(w_1 t), ..., sin(w_k t), cos(w_k t)]."""
    angle = np.asarray(time, dtype=np.float64)[..., None] * omega
    return np.stack([np.sin(angle), np.cos(angle)], axis=-1).reshape(*angle.shape[:-1], 2 * omega.size)


def _extend_box(box: spaces.Space, extra: int, bound: float = 1.0) -> spaces.Space:
    """``box`` with ``extra`` entries in [-bound, bound] appended (to the ``observation`` entry of a Dict space)."""
    if isinstance(box, spaces.Dict):
        return spaces.Dict({**box.spaces, "observation": _extend_box(box["observation"], extra, bound)})
    low = np.concatenate([box.low, np.full(extra, -bound, box.dtype)])
    high = np.concatenate([box.high, np.full(extra, bound, box.dtype)])
    return spaces.Box(low, high, dtype=box.dtype)


REFERENCE_RATES = ("difference", "zero")


class _ClockRestarts:
    """Which sub-envs' clocks (phase, oscillator, gait) restart after a vector step.

    Next-step autoreset resets a sub-env on the call after its episode ended, so its
    clock restarts then; same-step autoreset resets it in the call that ended it, whose
    ``info["final_obs"]`` still holds the episode's last observation (see
    :func:`_map_final_obs`)."""

    def __init__(self, env):
        mode = env.metadata.get("autoreset_mode", AutoresetMode.NEXT_STEP)
        self.same_step = mode == AutoresetMode.SAME_STEP
        self._pending = np.zeros(env.num_envs, bool)

    def reset(self, mask=None) -> None:
        self._pending[slice(None) if mask is None else np.asarray(mask, dtype=bool)] = False

    def after_step(self, done: np.ndarray) -> np.ndarray:
        """Boolean rows whose clock restarts with the observation this step returns."""
        if self.same_step:
            return np.asarray(done, bool).copy()
        restart, self._pending = self._pending, np.asarray(done, bool).copy()
        return restart


def _map_final_obs(info: dict, rows: np.ndarray, transform) -> dict:
    """info with ``final_obs[i]`` replaced by ``transform(final_obs[i], i)`` for the rows
    given (same-step autoreset: the last observation of each episode that ended)."""
    if "final_obs" not in info:
        return info
    final = info["final_obs"].copy()
    for i in np.flatnonzero(rows):
        final[i] = transform(final[i], i)
    return {**info, "final_obs": final}


class _PDSettings:
    """Validated gains of the joint-target PD (shared by the single and vector wrapper)."""

    def __init__(self, env, kp, kd, target_range, reference_rate):
        g = _geometry(env)
        if reference_rate not in REFERENCE_RATES:
            raise ValueError(f"reference_rate must be one of {list(REFERENCE_RATES)}, got {reference_rate!r}")
        self.use_rate = reference_rate == "difference"
        self.dt = g["dt"]
        self.kp = _number("kp", kp, "N m/rad")
        self.kd = _number("kd", kd, "N m s/rad")
        if self.kp == 0 and self.kd == 0:
            raise ValueError("joint_target needs kp > 0 or kd > 0 (N m/rad, N m s/rad)")
        if target_range is None:
            target_range = g["joint_limit"] if g["joint_limit"] else math.pi / 2
        self.target_range = _number("target_range", target_range, "rad", strict=True)
        if self.target_range > math.pi:
            raise ValueError(f"target_range must be in (0, pi] rad, got {target_range!r}")
        self.max_torque, self.phi, self.rates = g["max_torque"], g["phi"], g["rates"]

    def target(self, action) -> np.ndarray:
        """Target joint angles (rad) of an action."""
        return np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0) * self.target_range

    def torque_action(self, action, obs, previous_target=None) -> np.ndarray:
        """Env action (torque / max_torque, in [-1, 1]) of the PD for a target
        ``action``; ``previous_target`` (rad, or None on a first step) gives the reference rate."""
        target = self.target(action)
        obs = np.asarray(obs, dtype=np.float64)
        rate = 0.0
        if self.use_rate and previous_target is not None:
            rate = (target - previous_target) / self.dt
        torque = self.kp * (target - obs[..., self.phi]) + self.kd * (rate - obs[..., self.rates])
        return np.clip(torque / self.max_torque, -1.0, 1.0).astype(np.float32)


class JointTargetAction(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Action = target joint angles (fraction of ``target_range``, in [-1, 1]),
    tracked by a joint PD within the torque limit.

    Args:
        kp: PD stiffness (N m/rad), default 1.0.
        kd: PD damping (N m s/rad), default 0.05.
        target_range: rad of target per unit action (default: the env's joint
            limit, pi/2 if it has none).
        reference_rate: "difference" (target change / dt, default) or "zero".
    """

    def __init__(self, env: gym.Env, kp: float = 1.0, kd: float = 0.05, target_range: float | None = None,
                 reference_rate: str = "difference"):
        gym.utils.RecordConstructorArgs.__init__(self, kp=kp, kd=kd, target_range=target_range,
                                                 reference_rate=reference_rate)
        super().__init__(env)
        self.pd = _PDSettings(env, kp, kd, target_range, reference_rate)
        self._obs = None
        self._previous = None

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self._obs = obs
        self._previous = None
        return obs, info

    def step(self, action):
        if self._obs is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        torque = self.pd.torque_action(action, self._obs, self._previous)
        self._previous = self.pd.target(action)
        obs, reward, terminated, truncated, info = self.env.step(torque)
        self._obs = obs
        return obs, reward, terminated, truncated, info


class JointTargetActionVector(VectorWrapper):
    """:class:`JointTargetAction` for a batched vector env (one PD per sub-env row)."""

    def __init__(self, env, kp: float = 1.0, kd: float = 0.05, target_range: float | None = None,
                 reference_rate: str = "difference"):
        super().__init__(env)
        self.pd = _PDSettings(env, kp, kd, target_range, reference_rate)
        self._obs = None
        self._previous = None
        self._first = np.ones(self.num_envs, bool)  # rows on an episode's first step: reference rate 0
        self._restarts = _ClockRestarts(env)

    def reset(self, *, seed=None, options=None):
        obs, info = self.env.reset(seed=seed, options=options)
        self._obs = obs
        mask = (options or {}).get("reset_mask")
        self._first[slice(None) if mask is None else np.asarray(mask, dtype=bool)] = True
        self._restarts.reset(mask)
        return obs, info

    def step(self, actions):
        if self._obs is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        target = self.pd.target(actions)
        previous = target if self._previous is None else np.where(self._first[:, None], target, self._previous)
        # rows being auto-reset (next-step mode) ignore their action, so any PD value is fine there
        obs, reward, terminated, truncated, info = self.env.step(self.pd.torque_action(actions, self._obs, previous))
        self._obs = obs
        self._previous = target
        self._first[:] = False
        self._first |= self._restarts.after_step(np.asarray(terminated | truncated))
        return obs, reward, terminated, truncated, info


class PhaseObservation(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Appends ``sin(w t), cos(w t)`` per frequency ``w`` (rad/s) to the
    observation; ``t`` (s) counts env steps since the reset times the env's dt.

    Args:
        frequencies: one frequency or a list (rad/s), default 25.0 (the
            searched serpenoids' 25-40 rad/s range; 4 env steps per period at 40).
    """

    def __init__(self, env: gym.Env, frequencies=25.0):
        gym.utils.RecordConstructorArgs.__init__(self, frequencies=frequencies)
        super().__init__(env)
        self.omega = _frequencies(frequencies)
        self.dt = _geometry(env)["dt"]
        self.observation_space = _extend_box(env.observation_space, 2 * self.omega.size)
        self._steps = 0

    def _augment(self, obs):
        phase = _phase_features(np.array(self._steps * self.dt), self.omega)
        return np.concatenate([obs, phase.astype(obs.dtype)])

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self._steps = 0
        return self._augment(obs), info

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._steps += 1
        return self._augment(obs), reward, terminated, truncated, info


class PhaseObservationVector(VectorWrapper):
    """:class:`PhaseObservation` for a batched vector env: one clock per sub-env,
    restarted with the sub-env's (auto)reset; ``info["final_obs"]`` (same-step
    autoreset) carries the phase of the episode's last step."""

    def __init__(self, env, frequencies=25.0):
        super().__init__(env)
        self.omega = _frequencies(frequencies)
        self.dt = _geometry(env)["dt"]
        self.single_observation_space = _extend_box(env.single_observation_space, 2 * self.omega.size)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._steps = np.zeros(self.num_envs, np.int64)
        self._restarts = _ClockRestarts(env)

    def _augment(self, obs, steps):
        phase = _phase_features(steps * self.dt, self.omega).astype(obs.dtype)
        return np.concatenate([obs, phase], axis=-1)

    def reset(self, *, seed=None, options=None):
        obs, info = self.env.reset(seed=seed, options=options)
        mask = (options or {}).get("reset_mask")
        self._steps[slice(None) if mask is None else np.asarray(mask, dtype=bool)] = 0
        self._restarts.reset(mask)
        return self._augment(obs, self._steps), info

    def step(self, actions):
        obs, reward, terminated, truncated, info = self.env.step(actions)
        done = np.asarray(terminated | truncated)
        self._steps += 1
        restart = self._restarts.after_step(done)
        if self._restarts.same_step:
            info = _map_final_obs(info, done, lambda final, i: self._augment(np.asarray(final), self._steps[i]))
        self._steps[restart] = 0
        return self._augment(obs, self._steps), reward, terminated, truncated, info


CPG_PARAMETERS = ("amplitude", "frequency", "phase_lag", "offset")


class _CPGSettings:
    """Validated ranges of the CPG action and its arithmetic (shared by the single and vector wrapper).

    Action entries in [-1, 1], in the order of :data:`CPG_PARAMETERS`, mapped
    linearly: amplitude to [0, max_amplitude] rad, frequency to [0,
    max_frequency] rad/s, phase lag to [-pi, pi] rad, offset to [-max_offset,
    max_offset] rad. PD gains kp (N m/rad), kd (N m s/rad).
    """

    def __init__(self, env, max_amplitude, max_frequency, max_offset, kp, kd):
        g = _geometry(env)
        self.max_amplitude = _number("max_amplitude", max_amplitude, "rad", strict=True)
        self.max_frequency = _number("max_frequency", max_frequency, "rad/s", strict=True)
        self.max_offset = _number("max_offset", max_offset, "rad")
        self.kp = _number("kp", kp, "N m/rad")
        self.kd = _number("kd", kd, "N m s/rad")
        if self.kp == 0 and self.kd == 0:
            raise ValueError("cpg needs kp > 0 or kd > 0 (N m/rad, N m s/rad)")
        self.n_joints = g["n_links"] - 1
        self.dt, self.max_torque, self.phi, self.rates = g["dt"], g["max_torque"], g["phi"], g["rates"]

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
        """(env action = PD torque / max_torque in [-1, 1] (float32), phase after the step (rad))."""
        p = self.decode(action)
        obs = np.asarray(obs, dtype=np.float64)
        angle = np.asarray(phase, dtype=np.float64)[..., None] + np.arange(self.n_joints) * p["phase_lag"][..., None]
        amplitude = p["amplitude"][..., None]
        reference = amplitude * np.sin(angle) + p["offset"][..., None]
        reference_rate = amplitude * p["frequency"][..., None] * np.cos(angle)
        torque = self.kp * (reference - obs[..., self.phi]) + self.kd * (reference_rate - obs[..., self.rates])
        next_phase = np.mod(phase + p["frequency"] * self.dt, 2.0 * math.pi)
        return np.clip(torque / self.max_torque, -1.0, 1.0).astype(np.float32), next_phase


def _with_phase(obs, phase):
    """obs with sin(phase), cos(phase) appended (last axis; of the ``observation`` entry of a Dict observation)."""
    phase = np.asarray(phase, dtype=np.float64)
    return _append(obs, np.stack([np.sin(phase), np.cos(phase)], axis=-1))


def _append(obs, extra):
    """obs with the columns ``extra`` (..., k) appended (to the ``observation`` entry of a Dict observation)."""
    if isinstance(obs, Mapping):
        return {**obs, "observation": _append(obs["observation"], extra)}
    obs = np.asarray(obs)
    return np.concatenate([obs, np.asarray(extra).astype(obs.dtype)], axis=-1)


def _cpg_action_space() -> spaces.Box:
    return spaces.Box(-1.0, 1.0, (len(CPG_PARAMETERS),), np.float32)


class CPGAction(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Action = parameters of a serpenoid CPG (see :class:`_CPGSettings`), tracked by a
    joint PD within the torque limit; observation + (sin psi, cos psi) of the oscillator.

    Args (ranges: the serpenoid search's ``pd`` box):
        max_amplitude: rad, default 1.5.
        max_frequency: rad/s, default 40 (>= 4 env steps per gait period).
        max_offset: rad, default 0.5 (turning).
        kp: PD stiffness (N m/rad), default 1.0.
        kd: PD damping (N m s/rad), default 0.05 (the searched Snake5/12/30 gaits
            have kp 0.6-1.3, kd 0.02-0.1).
    """

    def __init__(self, env: gym.Env, max_amplitude: float = 1.5, max_frequency: float = 40.0,
                 max_offset: float = 0.5, kp: float = 1.0, kd: float = 0.05):
        gym.utils.RecordConstructorArgs.__init__(self, max_amplitude=max_amplitude, max_frequency=max_frequency,
                                                 max_offset=max_offset, kp=kp, kd=kd)
        super().__init__(env)
        self.cpg = _CPGSettings(env, max_amplitude, max_frequency, max_offset, kp, kd)
        self.action_space = _cpg_action_space()
        self.observation_space = _extend_box(env.observation_space, 2)
        self._obs = None
        self._phase = 0.0

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self._obs = obs
        self._phase = np.float64(0.0)
        return _with_phase(obs, self._phase), info

    def step(self, action):
        if self._obs is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        torque, self._phase = self.cpg.torque_action(action, self._obs, self._phase)
        obs, reward, terminated, truncated, info = self.env.step(torque)
        self._obs = obs
        return _with_phase(obs, self._phase), reward, terminated, truncated, info


class CPGActionVector(VectorWrapper):
    """:class:`CPGAction` for a batched vector env: one oscillator per sub-env, its phase
    restarted at 0 with the sub-env's (auto)reset."""

    def __init__(self, env, max_amplitude: float = 1.5, max_frequency: float = 40.0, max_offset: float = 0.5,
                 kp: float = 1.0, kd: float = 0.05):
        super().__init__(env)
        self.cpg = _CPGSettings(env, max_amplitude, max_frequency, max_offset, kp, kd)
        self.single_action_space = _cpg_action_space()
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.single_observation_space = _extend_box(env.single_observation_space, 2)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._obs = None
        self._phase = np.zeros(self.num_envs)
        self._restarts = _ClockRestarts(env)

    def reset(self, *, seed=None, options=None):
        obs, info = self.env.reset(seed=seed, options=options)
        mask = (options or {}).get("reset_mask")
        rows = slice(None) if mask is None else np.asarray(mask, dtype=bool)
        self._phase[rows] = 0.0
        self._restarts.reset(mask)
        self._obs = obs
        return _with_phase(obs, self._phase), info

    def step(self, actions):
        if self._obs is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        # rows being auto-reset (next-step mode) ignore their action; their phase restarts below
        torque, phase = self.cpg.torque_action(actions, self._obs, self._phase)
        obs, reward, terminated, truncated, info = self.env.step(torque)
        self._obs = obs
        self._phase = phase
        done = np.asarray(terminated | truncated)
        restart = self._restarts.after_step(done)
        if self._restarts.same_step:
            info = _map_final_obs(info, done, lambda final, i: _with_phase(final, self._phase[i]))
        self._phase[restart] = 0.0
        return _with_phase(obs, self._phase), reward, terminated, truncated, info


def _controller_geometry(env, num_envs: int) -> dict:
    """The keyword arguments a gait controller takes from the env (n_links, max_torque, dt, num_envs,
    include_position)."""
    g = _geometry(env)
    return dict(n_links=g["n_links"], max_torque=g["max_torque"], dt=g["dt"], num_envs=num_envs,
                include_position=g["phi"].start == 2)


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


class _TorqueResidual:
    """Env action = baseline torque + ``scale`` max_torque x action (the joint-torque residual)."""

    def __init__(self, env, scale, gait, num_envs: int):
        self.scale = _number("scale", scale, "fraction of max_torque", strict=True)
        if self.scale > 2.0:
            raise ValueError(f"scale must be in (0, 2] (fraction of max_torque), got {scale!r}")
        self.controller = _task_baseline(env, gait, num_envs)
        self.action_space = None  # the env's own: one correction per joint

    def env_action(self, obs, action) -> np.ndarray:
        base = self.controller.act(obs)  # advances the gait's clock by dt
        correction = self.scale * np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        return np.clip(base + correction, -1.0, 1.0).astype(np.float32)


STEERING_ACTIONS = ("offset", "speed")
# what steering_residual corrects: the task's baseline (snake-eval --baseline), or the searched gait
# run straight, which reads no goal (so HER may relabel the goals of its transitions)
STEERING_BASELINES = ("task", "gait")


def _straight_gait(env, num_envs: int):
    geometry = _controller_geometry(env, num_envs)
    return StraightGait(gait_for_links(geometry["n_links"])[0], **geometry)


class _SteeringResidual:
    """Env action = the baseline's cascade with its guidance corrected: the gait offset gamma
    plus ``offset_scale`` rad x action[0], the gait frequency times 1 + ``speed_range`` x action[1]
    (its sign, the direction of travel, stays the baseline's)."""

    def __init__(self, env, offset_scale, speed_range, baseline, num_envs: int):
        self.offset_scale = _number("offset_scale", offset_scale, "rad", strict=True)
        self.speed_range = _number("speed_range", speed_range, "fraction of the gait frequency")
        if self.offset_scale > 1.0 or self.speed_range > 1.0:
            raise ValueError(f"offset_scale must be in (0, 1] rad and speed_range in [0, 1], got "
                             f"{offset_scale!r}, {speed_range!r}")
        if baseline not in STEERING_BASELINES:
            raise ValueError(f"baseline must be one of {list(STEERING_BASELINES)}, got {baseline!r}")
        if baseline == "gait":
            self.controller = _straight_gait(env, num_envs)
        else:
            self.controller = _task_baseline(env, None, num_envs)
            if not hasattr(self.controller, "guidance"):
                raise ValueError(f"steering_residual needs a task whose baseline steers the gait (path, command, "
                                 f"reach) or baseline: gait; the {env.unwrapped.task.name} task's baseline "
                                 f"{type(self.controller).__name__} has no steering")
        self.action_space = spaces.Box(-1.0, 1.0, (len(STEERING_ACTIONS),), np.float32)

    def env_action(self, obs, action) -> np.ndarray:
        physics, offset, freq_scale, single = self.controller.guidance(obs)
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0).reshape(-1, len(STEERING_ACTIONS))
        torque = self.controller.gait_action(physics, offset + self.offset_scale * a[:, 0],
                                             freq_scale * (1.0 + self.speed_range * a[:, 1]))
        return torque[0] if single else torque


class _BaselineResidualAction(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """A residual on the task's baseline controller (``residual`` maps the action to the env's);
    observation + sin, cos of the baseline gait's phase (+ its hidden mode, ``observe_mode``)."""

    def __init__(self, env: gym.Env, residual, observe_mode: bool, **recorded):
        gym.utils.RecordConstructorArgs.__init__(self, **recorded, observe_mode=observe_mode)
        super().__init__(env)
        self.residual = residual
        self.controller = residual.controller
        mode_size = _mode_size(self.controller, observe_mode)
        self.observe_mode = mode_size > 0
        self.observation_space = _extend_box(env.observation_space, 2 + mode_size)
        if residual.action_space is not None:
            self.action_space = residual.action_space
        self._obs = None

    def _augment(self, obs):
        obs = _with_phase(obs, self.controller.phase[0])
        return _append(obs, self.controller.mode()[0]) if self.observe_mode else obs

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self.controller.reset()
        self._obs = obs
        return self._augment(obs), info

    def step(self, action):
        if self._obs is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        obs, reward, terminated, truncated, info = self.env.step(self.residual.env_action(self._obs, action))
        self._obs = obs
        return self._augment(obs), reward, terminated, truncated, info


class _BaselineResidualActionVector(VectorWrapper):
    """:class:`_BaselineResidualAction` for a batched vector env: one gait clock per sub-env,
    restarted with the sub-env's (auto)reset."""

    def __init__(self, env, residual, observe_mode: bool):
        super().__init__(env)
        self.residual = residual
        self.controller = residual.controller
        mode_size = _mode_size(self.controller, observe_mode)
        self.observe_mode = mode_size > 0
        self.single_observation_space = _extend_box(env.single_observation_space, 2 + mode_size)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        if residual.action_space is not None:
            self.single_action_space = residual.action_space
            self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._obs = None
        self._restarts = _ClockRestarts(env)

    def _augment(self, obs, rows=slice(None)):
        obs = _with_phase(obs, self.controller.phase[rows])
        return _append(obs, self.controller.mode()[rows]) if self.observe_mode else obs

    def reset(self, *, seed=None, options=None):
        obs, info = self.env.reset(seed=seed, options=options)
        mask = (options or {}).get("reset_mask")
        self.controller.reset(mask)
        self._restarts.reset(mask)
        self._obs = obs
        return self._augment(obs), info

    def step(self, actions):
        if self._obs is None:
            raise gym.error.ResetNeeded("call reset() before step()")
        obs, reward, terminated, truncated, info = self.env.step(self.residual.env_action(self._obs, actions))
        self._obs = obs
        done = np.asarray(terminated | truncated)
        restart = self._restarts.after_step(done)
        if self._restarts.same_step:
            info = _map_final_obs(info, done, lambda final, i: self._augment(final, i))
        self.controller.reset(restart)
        return self._augment(obs), reward, terminated, truncated, info


class SerpenoidResidualAction(_BaselineResidualAction):
    """Action = correction (fraction ``scale`` of max_torque per unit) added to the task's
    baseline controller's action; observation + sin, cos of the baseline gait's phase.

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
        residual = _TorqueResidual(env, scale, gait, 1)
        super().__init__(env, residual, observe_mode, scale=scale, gait=gait)
        self.scale = residual.scale


class SerpenoidResidualActionVector(_BaselineResidualActionVector):
    """:class:`SerpenoidResidualAction` for a batched vector env."""

    def __init__(self, env, scale: float = 0.3, gait: str | None = None, observe_mode: bool = False):
        residual = _TorqueResidual(env, scale, gait, env.num_envs)
        super().__init__(env, residual, observe_mode)
        self.scale = residual.scale


class SteeringResidualAction(_BaselineResidualAction):
    """Action (2,) in [-1, 1] = correction to the task baseline's steering, the outer loop of
    its cascade (Liljebäck et al. 2011): the gait offset gamma plus ``offset_scale`` rad x
    action[0], the gait frequency times 1 + ``speed_range`` x action[1]; the inner loop, the
    PD-tracked serpenoid, turns them into joint torques. The zero action is the baseline.
    Exploration noise then perturbs the heading, not the gait: joint-torque noise of
    std 0.135 x 0.3 max_torque takes goal seeking on SnakeReach12 from 80 % to 16 % of goals.
    Observation + sin, cos of the gait's phase. Path, command and reach tasks; with
    ``baseline: "gait"`` also the forward task.

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
        residual = _SteeringResidual(env, offset_scale, speed_range, baseline, 1)
        super().__init__(env, residual, observe_mode, offset_scale=offset_scale, speed_range=speed_range,
                         baseline=baseline)


class SteeringResidualActionVector(_BaselineResidualActionVector):
    """:class:`SteeringResidualAction` for a batched vector env."""

    def __init__(self, env, offset_scale: float = 0.15, speed_range: float = 0.5, baseline: str = "task",
                 observe_mode: bool = False):
        super().__init__(env, _SteeringResidual(env, offset_scale, speed_range, baseline, env.num_envs),
                         observe_mode)


def _goal_frame_geometry(env) -> dict:
    g = _geometry(env)
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


class GoalFrameObservation(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """Goal tasks: the goal relative to the CM in the heading frame (m) appended to ``observation``."""

    def __init__(self, env: gym.Env):
        gym.utils.RecordConstructorArgs.__init__(self)
        super().__init__(env)
        self._geometry = _goal_frame_geometry(env)
        self.observation_space = _extend_box(env.observation_space, 2, np.inf)

    def observation(self, observation):
        return _with_goal_frame(observation, self._geometry)


class GoalFrameObservationVector(VectorWrapper):
    """:class:`GoalFrameObservation` for a batched vector env (one row per sub-env), also on the
    ``final_obs`` of same-step autoreset (which gymnasium's VectorObservationWrapper refuses)."""

    def __init__(self, env):
        super().__init__(env)
        self._geometry = _goal_frame_geometry(env)
        self.single_observation_space = _extend_box(env.single_observation_space, 2, np.inf)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)

    def reset(self, *, seed=None, options=None):
        obs, info = self.env.reset(seed=seed, options=options)
        return _with_goal_frame(obs, self._geometry), info

    def step(self, actions):
        obs, reward, terminated, truncated, info = self.env.step(actions)
        # same-step autoreset: one Dict observation (or None) per sub-env
        info = _map_final_obs(info, info.get("_final_obs", np.zeros(self.num_envs, bool)),
                              lambda final, i: _with_goal_frame(final, self._geometry))
        return _with_goal_frame(obs, self._geometry), reward, terminated, truncated, info


WRAPPERS = {
    "phase_observation": (PhaseObservation, PhaseObservationVector),
    "joint_target": (JointTargetAction, JointTargetActionVector),
    "cpg": (CPGAction, CPGActionVector),
    "serpenoid_residual": (SerpenoidResidualAction, SerpenoidResidualActionVector),
    "steering_residual": (SteeringResidualAction, SteeringResidualActionVector),
    "goal_frame": (GoalFrameObservation, GoalFrameObservationVector),
}


def parse_env_wrapper(spec) -> list[tuple[str, dict]]:
    """``env_wrapper`` config value -> [(name, kwargs)], in order.

    Accepts None, a name, a list of names or one-key mappings, or a mapping
    ``{name: kwargs-or-None}``; an unknown name or bad kwargs is a one-line ValueError."""
    if spec is None or spec == {} or spec == []:
        return []
    if isinstance(spec, str):
        items = [(spec, {})]
    elif isinstance(spec, Mapping):
        items = list(spec.items())
    elif isinstance(spec, Sequence):
        items = []
        for entry in spec:
            if isinstance(entry, str):
                items.append((entry, {}))
            elif isinstance(entry, Mapping) and len(entry) == 1:
                items.extend(entry.items())
            else:
                raise ValueError(f"env_wrapper entries must be names or one-key mappings, got {entry!r}")
    else:
        raise ValueError(f"env_wrapper must be a mapping {{name: kwargs}}, a name or a list, got {spec!r}")
    out = []
    for name, kwargs in items:
        if name not in WRAPPERS:
            raise ValueError(f"env_wrapper name must be one of {sorted(WRAPPERS)}, got {name!r}")
        if kwargs is None:
            kwargs = {}
        if not isinstance(kwargs, Mapping):
            raise ValueError(f"env_wrapper {name!r} kwargs must be a mapping, got {kwargs!r}")
        out.append((name, dict(kwargs)))
    return out


def _construct(cls, env, name, kwargs):
    try:
        return cls(env, **kwargs)
    except TypeError as exc:
        raise ValueError(f"env_wrapper {name!r}: {str(exc).splitlines()[0]}") from None


def wrap_env(env: gym.Env, spec) -> gym.Env:
    """Apply the ``env_wrapper`` spec to a single env."""
    for name, kwargs in parse_env_wrapper(spec):
        env = _construct(WRAPPERS[name][0], env, name, kwargs)
    return env


def wrap_vector_env(envs, spec):
    """Apply the ``env_wrapper`` spec to a batched vector env."""
    for name, kwargs in parse_env_wrapper(spec):
        envs = _construct(WRAPPERS[name][1], envs, name, kwargs)
    return envs

