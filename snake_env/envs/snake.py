"""``SnakeEnv``: one n-link wheeled snake doing a task, as a Gymnasium environment.

The env is written once for every task: the physics settings are a
:class:`~snake_env.physics.config.PhysicsConfig`, what differs between tasks is a
:class:`~snake_env.tasks.Task` (``task="forward" | "command" | "reach" | "path"``),
and the state is a :class:`~snake_env.envs.core.SnakeBatch` of one row, the
same code the vector env runs for B rows. The spec of each registered id
(spaces with units, rewards, episode end, arguments, version history) is its
task's class docstring, e.g. ``snake_env.tasks.ForwardTask.__doc__``.
"""

from __future__ import annotations

import warnings
from collections import deque
from typing import Any

import gymnasium as gym
import numpy as np

from snake_env.tasks.base import COMMON_STEP_INFO_KEYS, RESET_INFO_KEYS
from snake_env.tasks.forward import ForwardTask

from .core import TaskEnvBase, action_array, first_row
from snake_env.physics import AUX_X, AUX_Y

TRAIL_LENGTH = 250  # env steps of CM trail kept for rendering (10 s)
# the forward task's info keys (``env.step_info_keys`` gives any task's)
STEP_INFO_KEYS = COMMON_STEP_INFO_KEYS + ForwardTask.step_info_keys
__all__ = ["SnakeEnv", "SnakeGoalEnv", "STEP_INFO_KEYS", "RESET_INFO_KEYS", "TRAIL_LENGTH"]


class SnakeEnv(TaskEnvBase, gym.Env):
    """One snake doing one task; ``task`` names it (default "forward", the
    ``snake_env/Snake{n}-v2`` task), every other kwarg is a field of
    :class:`~snake_env.physics.config.PhysicsConfig` or of the task class, whose
    docstring is the spec. Unknown kwargs raise a one-line ``ValueError``.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 25}

    def __init__(self, task="forward", render_mode: str | None = None, width: int = 480, height: int = 480,
                 **kwargs):
        self._build(task, 1, render_mode, width, height, kwargs)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (self.n_links - 1,), np.float32)
        self.observation_space = self._batch.single_observation_space
        self._trail = deque(maxlen=TRAIL_LENGTH)
        self._window = None

    # ------------------------------------------------------------------ properties
    @property
    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Copies of (q, u): q = (theta_1..theta_n, x, y) (eq. 1), u = (V_1, thetadot_1) (eq. 2)."""
        return self._batch.q[0].copy(), self._batch.u[0].copy()

    def joint_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Copies of (phi, phidot, torque) of every joint (n-1,): the angles theta_{k+1} - theta_k (rad,
        not wrapped), their rates omega_{k+1} - omega_k (rad/s, eq. 7) and the torques (N m) held over
        the last step (zero before the first), for gait metrics."""
        q = self._batch.q[0]
        n = self.n_links
        blocks = self.observation_structure  # the joint rates are the physics observation's last block
        start = sum(size for block, size in blocks.items() if block not in ("skipped_position", "joint_rates"))
        return (np.diff(q[:n]), self._batch.physics_obs[0, start:start + n - 1].copy(),
                self._batch.torques[0].copy())

    def wheel_lateral_forces(self) -> np.ndarray:
        """The sideways force (N) each wheel exerts on its link, (n,): eq. 27's multipliers of the current
        state under the torques held over the last step (0 before the first); in ``info`` at every step
        when ``wheel_friction`` is given."""
        return self._batch.wheel_lateral_forces()[0]

    def set_state(self, q, u):
        """Put the snake in state (q, u) (the task state is kept); return the new observation."""
        self._batch.set_state(np.asarray(q, np.float64)[None], np.asarray(u, np.float64)[None])
        self._restart_trail()
        self._has_reset = True
        return self._batch.observation_first()

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        self._batch.reset(np.ones(1, bool), self.np_random)
        self._restart_trail()
        self._has_reset = True
        if self.render_mode == "human":
            self.render()
        return self._batch.observation_first(), first_row(self._batch.reset_info())

    def step(self, action):
        if not self._has_reset:
            raise gym.error.ResetNeeded("call reset() before step()")
        # checked here (not only in the batch) so that an error names the single env's shape
        action = action_array(action, self.action_space.shape)
        reward, terminated, info = self._batch.step_first(action)
        if info["sim_failure"]:
            warnings.warn(f"snake_env: simulation failure ({self._batch.failure_reasons(np.zeros(1, int))[0]}); the "
                          "step was undone, reward 0 and the episode truncated (info['sim_failure'] = True)",
                          RuntimeWarning, stacklevel=2)
        if self.render_mode is not None:  # the trail is drawn, not observed
            aux = self._batch.aux[0]
            self._trail.append((aux[AUX_X], aux[AUX_Y]))
            if self.render_mode == "human":
                self.render()
        return self._batch.observation_first(), reward, terminated, info["sim_failure"], info

    def _restart_trail(self):
        aux = self._batch.aux[0]
        self._trail.clear()
        self._trail.append((aux[AUX_X], aux[AUX_Y]))

    # ------------------------------------------------------------------ rendering
    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human' "
                            "to gym.make")
            return None
        from .rendering import HumanWindow, SnakeRenderer

        if self._renderer is None:
            self._renderer = SnakeRenderer(self.width, self.height, self.params.half_length)
        frame = self._renderer.draw(self._batch.q[0], np.asarray(self._trail), overlay=self._overlay(0))
        if self.render_mode == "rgb_array":
            return frame
        if self._window is None:
            self._window = HumanWindow(self.width, self.height, fps=self.metadata["render_fps"])
        self._window.show(frame)
        return None

    def close(self):
        if self._window is not None:
            self._window.close()
            self._window = None
        self._renderer = None

    def __getstate__(self):
        # the window and renderer hold OS / cache resources; they are rebuilt on demand
        state = self.__dict__.copy()
        state["_renderer"] = None
        state["_window"] = None
        return state


class SnakeGoalEnv(SnakeEnv):
    """:class:`SnakeEnv` of a goal task (``task.goal_env``): a gymnasium_robotics-style
    GoalEnv with a Dict observation and a vectorized ``compute_reward``."""

    def compute_reward(self, achieved_goal, desired_goal, info):
        """The step reward for goals of shape (..., 2) (m); equals the reward of step()."""
        return self.task.compute_reward(achieved_goal, desired_goal, info)
