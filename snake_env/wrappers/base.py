"""What every opt-in mode shares: the batched form of a mode, and the two adapters that make it a
wrapper of the single env and of the batched vector env.

A mode (:class:`BatchedMode`) works on rows, one per sub-env: it maps a batch of policy actions to
env actions (advancing its clocks by one env step), appends its features to observations, and
restarts the clocks of the rows whose episode restarts. :class:`SingleEnvWrapper` runs it as a
batch of one (a ``gymnasium.Wrapper``); :class:`VectorEnvWrapper` runs it over a vector env's
sub-envs (a ``gymnasium.vector.VectorWrapper``), restarting the clocks under either of Gymnasium's
autoreset modes (:class:`ClockRestarts`) and extending ``info["final_obs"]``.

Observation layout read here (the env's documented one): [x, y]? + joint angles phi (n-1) +
cos/sin heading (2) + (V_1, thetadot_1) + joint rates (n-1).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorWrapper
from gymnasium.vector.utils import batch_space

from snake_env.controllers import joint_slices

# the env geometry the controllers of snake_env.controllers take as keyword arguments
CONTROLLER_KEYS = ("n_links", "max_torque", "dt", "include_position")


def number(name, value, unit, minimum=0.0, strict=False) -> float:
    """``value`` as a float if it is a finite real >= ``minimum`` (> with ``strict``); a one-line
    ValueError naming ``name`` and its ``unit`` otherwise."""
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or (value <= minimum if strict else value < minimum):
        bound = f"{'>' if strict else '>='} {minimum}"
        raise ValueError(f"{name} must be a finite number {bound} ({unit}), got {value!r}")
    return float(value)


def env_geometry(env) -> dict:
    """n_links, max_torque (N m), dt (s), joint_limit (rad or None), include_position and the
    phi / phidot slices of the observation (:func:`snake_env.controllers.joint_slices`), read from
    the unwrapped env."""
    base = env.unwrapped
    try:
        n = int(base.n_links)
        max_torque = float(base.max_torque)
        dt = float(base.dt)
    except AttributeError:
        raise ValueError(f"snake wrappers need a snake_env env (n_links, max_torque, dt), got {base!r}") from None
    include_position = not getattr(base, "exclude_current_positions_from_observation", True)
    phi, rates = joint_slices(n, include_position)
    return dict(n_links=n, max_torque=max_torque, dt=dt, joint_limit=getattr(base, "joint_limit", None),
                include_position=include_position, phi=phi, rates=rates)


def controller_kwargs(geometry: dict) -> dict:
    """The keyword arguments of a :mod:`snake_env.controllers` controller taken from :func:`env_geometry`."""
    return {key: geometry[key] for key in CONTROLLER_KEYS}


def extend_box(box: spaces.Space, extra: int, bound: float = 1.0) -> spaces.Space:
    """``box`` with ``extra`` entries in [-bound, bound] appended (to the ``observation`` entry of a Dict space)."""
    if isinstance(box, spaces.Dict):
        return spaces.Dict({**box.spaces, "observation": extend_box(box["observation"], extra, bound)})
    low = np.concatenate([box.low, np.full(extra, -bound, box.dtype)])
    high = np.concatenate([box.high, np.full(extra, bound, box.dtype)])
    return spaces.Box(low, high, dtype=box.dtype)


def append(obs, extra):
    """obs with the columns ``extra`` (..., k) appended, cast to the observation's dtype (to the
    ``observation`` entry of a Dict observation)."""
    if isinstance(obs, Mapping):
        return {**obs, "observation": append(obs["observation"], extra)}
    obs = np.asarray(obs)
    return np.concatenate([obs, np.asarray(extra).astype(obs.dtype)], axis=-1)


def with_phase(obs, phase):
    """obs with sin(phase), cos(phase) appended (phase in rad; last axis; to the ``observation``
    entry of a Dict observation)."""
    phase = np.asarray(phase, dtype=np.float64)
    return append(obs, np.stack([np.sin(phase), np.cos(phase)], axis=-1))


def selected(mask):
    """The rows a ``reset_mask`` selects, as an index: all of them for None."""
    return slice(None) if mask is None else np.asarray(mask, dtype=bool)


class ClockRestarts:
    """Which sub-envs' clocks (phase, oscillator, gait) restart after a vector step.

    Next-step autoreset resets a sub-env on the call after its episode ended, so its
    clock restarts then; same-step autoreset resets it in the call that ended it, whose
    ``info["final_obs"]`` still holds the episode's last observation (see
    :func:`map_final_obs`)."""

    def __init__(self, env):
        mode = env.metadata.get("autoreset_mode", AutoresetMode.NEXT_STEP)
        self.same_step = mode == AutoresetMode.SAME_STEP
        self._pending = np.zeros(env.num_envs, bool)

    def reset(self, mask=None) -> None:
        self._pending[selected(mask)] = False

    def after_step(self, done: np.ndarray) -> np.ndarray:
        """Boolean rows whose clock restarts with the observation this step returns."""
        if self.same_step:
            return np.asarray(done, bool).copy()
        restart, self._pending = self._pending, np.asarray(done, bool).copy()
        return restart


def map_final_obs(info: dict, rows: np.ndarray, transform) -> dict:
    """info with ``final_obs[i]`` replaced by ``transform(final_obs[i], i)`` for the rows
    given (same-step autoreset: the last observation of each episode that ended)."""
    if "final_obs" not in info:
        return info
    final = info["final_obs"].copy()
    for i in np.flatnonzero(rows):
        final[i] = transform(final[i], i)
    return {**info, "final_obs": final}


class BatchedMode:
    """One opt-in mode over a batch of sub-envs (rows), written once for the single env (a batch of
    one) and the vector env. A subclass sets what applies of:

    extra: entries appended to the observation (to the ``observation`` entry of a Dict observation),
        each in [-bound, bound]; 0 leaves the observation as it is.
    acts: whether the mode maps the policy's action to the env's (:meth:`act`).
    action_space: the policy's action space for one sub-env; None keeps the env's.
    attributes: names of the mode's attributes that its wrappers carry too (e.g. ``pd``).
    """

    extra: int = 0
    bound: float = 1.0
    acts: bool = False
    action_space: spaces.Space | None = None
    attributes: tuple[str, ...] = ()

    def observation_space(self, space: spaces.Space) -> spaces.Space:
        """The observation space of one sub-env, given the wrapped env's."""
        return extend_box(space, self.extra, self.bound) if self.extra else space

    def restart(self, mask=None) -> None:
        """Restart the clocks of the rows ``mask`` selects (every row for None): a new episode."""

    def act(self, obs, action) -> np.ndarray:
        """Env actions (B, ...) for the policy's ``action`` (B, ...), given the env's last observation
        ``obs`` (B rows); advances the mode's clocks by one env step."""
        raise NotImplementedError

    def stepped(self) -> None:
        """Called after every env step (after :meth:`act`, before the rows restart)."""

    def seen(self, info: dict) -> None:
        """Called with every env step's ``info`` (after :meth:`stepped`, before the rows restart)."""

    def observe(self, obs, rows=slice(None)):
        """``obs`` with the mode's features appended: ``rows=slice(None)`` for a batch (B rows), an int
        i for sub-env i's unbatched observation (the single env's, row 0, or ``final_obs[i]``)."""
        return obs


def one_row(obs):
    """A single env's observation as a batch of one (each entry of a Dict observation)."""
    if isinstance(obs, Mapping):
        return {key: np.asarray(value)[None] for key, value in obs.items()}
    return np.asarray(obs)[None]


class _ModeWrapper:
    """What both adapters do: carry the mode's attributes, keep the env's last observation (the
    action modes' PD and baselines read it) and send the mode's env action."""

    def _adopt(self, batched: BatchedMode) -> None:
        self.batched = batched
        for name in batched.attributes:
            setattr(self, name, getattr(batched, name))
        self._obs = None

    def _env_action(self, action):
        raise NotImplementedError

    def _send(self, action):
        """The env's step for the policy's ``action``: (obs, reward, terminated, truncated, info)."""
        if self.batched.acts:
            if self._obs is None:
                raise gym.error.ResetNeeded("call reset() before step()")
            action = self._env_action(action)
        obs, reward, terminated, truncated, info = self.env.step(action)
        self._obs = obs
        self.batched.stepped()
        self.batched.seen(info)
        return obs, reward, terminated, truncated, info


class SingleEnvWrapper(_ModeWrapper, gym.Wrapper, gym.utils.RecordConstructorArgs):
    """A :class:`BatchedMode` of one row as a ``gymnasium.Wrapper``; ``recorded`` are the public
    class's constructor arguments (``gym.utils.RecordConstructorArgs``: the env spec's wrapper kwargs)."""

    def __init__(self, env: gym.Env, batched: BatchedMode, **recorded):
        gym.utils.RecordConstructorArgs.__init__(self, **recorded)
        gym.Wrapper.__init__(self, env)
        self._adopt(batched)
        if batched.extra:
            self.observation_space = batched.observation_space(env.observation_space)
        if batched.action_space is not None:
            self.action_space = batched.action_space

    def _env_action(self, action):
        return self.batched.act(one_row(self._obs), np.asarray(action)[None])[0]

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self.batched.restart()
        self._obs = obs
        return self.batched.observe(obs, 0), info

    def step(self, action):
        obs, reward, terminated, truncated, info = self._send(action)
        return self.batched.observe(obs, 0), reward, terminated, truncated, info


class VectorEnvWrapper(_ModeWrapper, VectorWrapper):
    """A :class:`BatchedMode` of ``env.num_envs`` rows as a ``gymnasium.vector.VectorWrapper``: a
    sub-env's clocks restart with its (auto)reset, and the ``final_obs`` of same-step autoreset
    carries the features of its episode's last step."""

    def __init__(self, env, batched: BatchedMode):
        VectorWrapper.__init__(self, env)
        self._adopt(batched)
        if batched.extra:
            self.single_observation_space = batched.observation_space(env.single_observation_space)
            self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        if batched.action_space is not None:
            self.single_action_space = batched.action_space
            self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._restarts = ClockRestarts(env)

    def _env_action(self, action):
        # rows being auto-reset (next-step mode) ignore their action; their clocks restart in step()
        return self.batched.act(self._obs, action)

    def reset(self, *, seed=None, options=None):
        obs, info = self.env.reset(seed=seed, options=options)
        mask = (options or {}).get("reset_mask")
        self.batched.restart(mask)
        self._restarts.reset(mask)
        self._obs = obs
        return self.batched.observe(obs), info

    def step(self, actions):
        obs, reward, terminated, truncated, info = self._send(actions)
        done = np.asarray(terminated | truncated)
        restart = self._restarts.after_step(done)
        if self.batched.extra:  # same-step autoreset: one observation (or None) per sub-env
            info = map_final_obs(info, info.get("_final_obs", done), self.batched.observe)
        self.batched.restart(restart)
        return self.batched.observe(obs), reward, terminated, truncated, info
