"""``SnakeVectorEnv``: a batch of snakes stepped by one compiled call.

Created by ``gym.make_vec(id, num_envs, vectorization_mode="vector_entry_point")``,
which passes ``num_envs``, the registration's ``max_episode_steps`` and the
env kwargs. Every sub-env is the :class:`~snake_env.envs.snake.SnakeEnv` of
the same kwargs; the state lives in (B, ...) arrays and the physics is one
call of :func:`snake_env.physics.step` (numba ``prange`` over the batch),
so there is no Python loop over the sub-envs. With ``num_envs=1`` and the same
seed it reproduces ``gym.make(id)`` step for step, bit for bit.

Time limit and autoreset are handled here (a vector env gets no TimeLimit
wrapper): sub-env i is truncated after ``max_episode_steps`` steps and, in
the default ``AutoresetMode.NEXT_STEP``, reset on the following ``step`` call
(whose action for it is ignored, reward 0, terminated = truncated = False),
as Gymnasium's own vector envs do. ``autoreset_mode="SameStep"`` resets in
the same call and puts the last observation in ``info["final_obs"]`` and the
step's info in ``info["final_info"]``; ``"Disabled"`` leaves resets to
``reset(options={"reset_mask": mask})``.

Info follows Gymnasium's vector convention: ``info[key]`` is an array over the
sub-envs and ``info["_" + key]`` a bool mask of the sub-envs it holds data for.
"""

from __future__ import annotations

import warnings
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from snake_env.physics.settings import number
from .core import RANDOMIZED_PREFIX, TaskEnvBase
from snake_env.physics import AUX_X, AUX_Y
from .snake import RESET_INFO_KEYS, TRAIL_LENGTH

AUTORESET_MODES = {mode.value: mode for mode in AutoresetMode}


def _autoreset_mode(value) -> AutoresetMode:
    if isinstance(value, AutoresetMode):
        return value
    if value in AUTORESET_MODES:
        return AUTORESET_MODES[value]
    raise ValueError(f"autoreset_mode must be one of {sorted(AUTORESET_MODES)} or an AutoresetMode, got {value!r}")


class SnakeVectorEnv(TaskEnvBase, VectorEnv):
    """``num_envs`` independent :class:`SnakeEnv` copies of one task in (B, ...) arrays.

    Args:
        num_envs: number of sub-envs B >= 1.
        max_episode_steps: steps before truncation (from the registration); None: never.
        autoreset_mode: "NextStep" (default, like Gymnasium), "SameStep" or "Disabled"
            (strings or :class:`gymnasium.vector.AutoresetMode`).
        task: as for :class:`SnakeEnv` (default "forward").
        render_mode: None or "rgb_array" (render() returns a tuple of B frames).
        Other kwargs: exactly those of :class:`SnakeEnv` for the task (same names, units, defaults).

    All sub-envs share one random generator (``self.np_random``): a reset of
    k sub-envs draws one (k, n+2) uniform array, then the task's draws, so
    B = 1 consumes the stream exactly as the single env does. A Dict
    observation (goal tasks) is a dict of (B, ...) arrays.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 25, "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(self, num_envs: int = 1, max_episode_steps: int | None = 1000,
                 autoreset_mode: str | AutoresetMode = AutoresetMode.NEXT_STEP, task="forward",
                 render_mode: str | None = None, width: int = 480, height: int = 480, **kwargs):
        self.num_envs = number("num_envs", num_envs, "sub-envs", minimum=0, integer=True)
        if max_episode_steps is not None:
            max_episode_steps = number("max_episode_steps", max_episode_steps, "steps, or None", minimum=0, integer=True)
        self.max_episode_steps = max_episode_steps
        self.autoreset_mode = _autoreset_mode(autoreset_mode)
        self._build(task, self.num_envs, render_mode, width, height, kwargs)
        self.metadata = {**self.metadata, "autoreset_mode": self.autoreset_mode}
        B = self.num_envs
        self.single_action_space = spaces.Box(-1.0, 1.0, (self.n_links - 1,), np.float32)
        self.action_space = batch_space(self.single_action_space, B)
        self.single_observation_space = self._batch.single_observation_space
        self.observation_space = batch_space(self.single_observation_space, B)
        self._steps = np.zeros(B, np.int64)
        self._autoreset = np.zeros(B, bool)
        self._trail = None  # (TRAIL_LENGTH, B, 2) ring of CM positions, only when rendering
        self._trail_len = np.zeros(B, np.int64)

    # ------------------------------------------------------------------ properties
    @property
    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Copies of (q (B, n+2), u (B, 2)), see :attr:`SnakeEnv.state`."""
        return self._batch.q.copy(), self._batch.u.copy()

    def set_state(self, q, u):
        """Put all sub-envs in states q (B, n+2), u (B, 2) (task state kept); return the observations.
        Episode step counters are not changed."""
        q = np.asarray(q, np.float64)
        u = np.asarray(u, np.float64)
        if q.shape != self._batch.q.shape or u.shape != self._batch.u.shape:
            raise ValueError(f"q must have shape {self._batch.q.shape} and u {self._batch.u.shape}, "
                             f"got {q.shape}, {u.shape}")
        self._batch.set_state(q, u)
        self._trail_len[:] = 0
        self._record_trail(np.ones(self.num_envs, bool))
        self._has_reset = True
        return self._batch.observation()

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Reset every sub-env, or those of ``options["reset_mask"]`` (bool (B,)).

        ``seed`` (int) reseeds the shared generator; per-sub-env seed lists are not supported.
        """
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer))):
            raise ValueError(f"seed must be an int or None (one generator drives all sub-envs), got {seed!r}")
        super().reset(seed=seed)
        mask = np.ones(self.num_envs, bool)
        if options is not None and "reset_mask" in options:
            mask = np.asarray(options["reset_mask"])
            if mask.shape != (self.num_envs,) or mask.dtype != np.bool_ or not mask.any():
                raise ValueError(f"options['reset_mask'] must be a bool array of shape ({self.num_envs},) with at "
                                 f"least one True, got {options['reset_mask']!r}")
        self._reset_envs(mask)
        self._has_reset = True
        return self._batch.observation(), self._reset_info(mask)

    def step(self, actions):
        if not self._has_reset:
            raise gym.error.ResetNeeded("call reset() before step()")
        if self.autoreset_mode == AutoresetMode.DISABLED and self._autoreset.any():
            raise ValueError("autoreset_mode='Disabled': reset the finished sub-envs with "
                             "reset(options={'reset_mask': mask}) before stepping them again")
        # every row is integrated (no branching in the kernel); rows awaiting a
        # next-step autoreset are overwritten by their reset below
        rewards, terminated, values = self._batch.step(actions)
        B = self.num_envs
        stepped = ~self._autoreset if self.autoreset_mode == AutoresetMode.NEXT_STEP else np.ones(B, bool)
        self._record_trail(stepped)
        failed = values["sim_failure"] & stepped
        values["sim_failure"] = failed
        if failed.any():
            reasons = "; ".join(self._batch.failure_reasons(np.flatnonzero(failed)))
            warnings.warn(f"snake_env: simulation failure in {int(failed.sum())} sub-env(s) ({reasons}); their step "
                          "was undone, reward 0 and the episode truncated (info['sim_failure'])",
                          RuntimeWarning, stacklevel=2)
        self._steps += 1
        terminated = terminated & stepped
        truncated = failed.copy()
        if self.max_episode_steps is not None:
            truncated |= self._steps >= self.max_episode_steps
        info = self._step_info(values, stepped)
        obs = self._batch.observation()

        if self.autoreset_mode == AutoresetMode.NEXT_STEP:
            reset_mask = self._autoreset.copy()
            if reset_mask.any():
                self._reset_envs(reset_mask)
                obs = self._batch.observation()
                rewards[reset_mask] = 0.0
                truncated[reset_mask] = False
                reset_info = self._reset_info(reset_mask)
                for key in RESET_INFO_KEYS:  # those sub-envs report their reset info
                    info[key][reset_mask] = reset_info[key][reset_mask]
                info.update(_drawn_robots(reset_info))
            self._autoreset = terminated | truncated
        elif self.autoreset_mode == AutoresetMode.SAME_STEP:
            done = terminated | truncated
            if done.any():
                final_obs = np.full(B, None, dtype=object)
                for i in np.flatnonzero(done):  # an object array of per-env rows, as Gymnasium's vector envs give
                    final_obs[i] = ({key: value[i].copy() for key, value in obs.items()} if isinstance(obs, dict)
                                    else obs[i].copy())
                info["final_obs"] = final_obs
                info["_final_obs"] = done.copy()
                final_info = {}
                for key in self.step_info_keys:
                    final_info[key] = info[key].copy()
                    final_info["_" + key] = done.copy()
                info["final_info"] = final_info
                info["_final_info"] = done.copy()
                self._reset_envs(done)
                obs = self._batch.observation()
                reset_info = self._reset_info(done)
                for key in self.step_info_keys:
                    if key in RESET_INFO_KEYS:
                        info[key][done] = reset_info[key][done]
                    else:
                        info["_" + key] = info["_" + key] & ~done
                info.update(_drawn_robots(reset_info))
        else:
            self._autoreset = terminated | truncated
        return obs, rewards, terminated, truncated, info

    def compute_reward(self, achieved_goal, desired_goal, info):
        """Goal tasks only (``task.goal_env``): the step reward for goals (..., 2) (m); SB3's
        HerReplayBuffer calls it through the VecEnv's ``env_method``."""
        if not self.task.goal_env:
            raise AttributeError(f"task {self.task.name!r} is not a goal task: it has no compute_reward")
        return self.task.compute_reward(achieved_goal, desired_goal, info)

    # ------------------------------------------------------------------ internals
    def _reset_envs(self, mask: np.ndarray) -> None:
        self._batch.reset(mask, self.np_random)
        self._steps[mask] = 0
        self._autoreset[mask] = False
        self._trail_len[mask] = 0
        self._record_trail(mask)

    def _reset_info(self, mask: np.ndarray) -> dict[str, np.ndarray]:
        info = {}
        for key, value in self._batch.reset_info().items():
            info[key] = np.where(mask.reshape(mask.shape + (1,) * (value.ndim - 1)), value, 0.0)
            info["_" + key] = mask.copy()
        return info

    def _step_info(self, values: dict, stepped) -> dict[str, np.ndarray]:
        info = {}
        everyone = np.ones(self.num_envs, bool)
        for key in self.step_info_keys:
            info[key] = values[key]
            # position and energy exist for every sub-env (reset ones get their reset values)
            info["_" + key] = everyone.copy() if key in RESET_INFO_KEYS else stepped.copy()
        return info

    def _record_trail(self, mask) -> None:
        if self.render_mode is None:
            return
        if self._trail is None:
            self._trail = np.zeros((TRAIL_LENGTH, self.num_envs, 2))
        slot = self._trail_len % TRAIL_LENGTH
        idx = np.flatnonzero(mask)
        self._trail[slot[idx], idx] = self._batch.aux[idx][:, [AUX_X, AUX_Y]]
        self._trail_len[idx] += 1

    # ------------------------------------------------------------------ rendering
    def render(self):
        """A tuple of B rgb frames (H, W, 3) uint8, one per sub-env."""
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' to gym.make_vec")
            return None
        from .rendering import SnakeRenderer

        if self._renderer is None:
            self._renderer = SnakeRenderer(self.width, self.height, self.params.half_length)
        frames = []
        for i in range(self.num_envs):
            count = int(min(self._trail_len[i], TRAIL_LENGTH))
            start = int(self._trail_len[i]) - count
            order = np.arange(start, start + count) % TRAIL_LENGTH
            frames.append(self._renderer.draw(self._batch.q[i], self._trail[order, i] if count else None,
                                              overlay=self._overlay(i)))
        return tuple(frames)

    def close_extras(self, **kwargs):
        self._renderer = None

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_renderer"] = None
        return state


def _drawn_robots(reset_info: dict) -> dict:
    """The randomized robots drawn at an autoreset (keys ``randomized_*`` and their masks), for the step's info."""
    return {key: value for key, value in reset_info.items() if key.lstrip("_").startswith(RANDOMIZED_PREFIX)}
