"""``SnakeVectorEnv``: a batch of snakes stepped by one compiled call.

Created by ``gym.make_vec(id, num_envs, vectorization_mode="vector_entry_point")``,
which passes ``num_envs``, the registration's ``max_episode_steps`` and the
env kwargs. Every sub-env is the :class:`~snake_env.envs.snake.SnakeEnv` of
the same kwargs; the state lives in (B, ...) arrays and the physics is one
call of :func:`snake_env.envs.physics.step` (numba ``prange`` over the batch),
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

from . import physics
from .physics import AUX_FAILED, AUX_KINETIC, AUX_VX, AUX_VY, AUX_WORK, AUX_X, AUX_Y
from .snake import (DEFAULT_CTRL_COST_WEIGHT, DEFAULT_ENERGY_TOLERANCE, DEFAULT_ERROR_TOLERANCE, DEFAULT_FRAME_SKIP, DEFAULT_INTEGRATOR,
                    DEFAULT_JOINT_DAMPING, DEFAULT_JOINT_LIMIT, DEFAULT_LIMIT_DAMPING, DEFAULT_LIMIT_STIFFNESS,
                    DEFAULT_MAX_REFINEMENTS, DEFAULT_MAX_TORQUE, DEFAULT_RESET_NOISE_SCALE,
                    DEFAULT_SIM_DT, DEFAULT_WHEEL_DAMPING, RESET_INFO_KEYS, STEP_INFO_KEYS, TRAIL_LENGTH,
                    _number, check_actions, configure, observation_space, observation_structure,
                    squared_norm)

AUTORESET_MODES = {mode.value: mode for mode in AutoresetMode}


def _autoreset_mode(value) -> AutoresetMode:
    if isinstance(value, AutoresetMode):
        return value
    if value in AUTORESET_MODES:
        return AUTORESET_MODES[value]
    raise ValueError(f"autoreset_mode must be one of {sorted(AUTORESET_MODES)} or an AutoresetMode, got {value!r}")


class SnakeVectorEnv(VectorEnv):
    """``num_envs`` independent :class:`SnakeEnv` copies in (B, ...) arrays.

    Args:
        num_envs: number of sub-envs B >= 1.
        max_episode_steps: steps before truncation (1000 from the registration); None: never.
        autoreset_mode: "NextStep" (default, like Gymnasium), "SameStep" or "Disabled"
            (strings or :class:`gymnasium.vector.AutoresetMode`).
        render_mode: None or "rgb_array" (render() returns a tuple of B frames).
        Other kwargs: exactly those of :class:`SnakeEnv` (same names, units, defaults).

    All sub-envs share one random generator (``self.np_random``): a reset of
    k sub-envs draws one (k, n+2) uniform array, so B = 1 consumes the stream
    exactly as the single env does.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 25, "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(
        self,
        num_envs: int = 1,
        max_episode_steps: int | None = 1000,
        autoreset_mode: str | AutoresetMode = AutoresetMode.NEXT_STEP,
        n_links: int = 5,
        frame_skip: int = DEFAULT_FRAME_SKIP,
        sim_dt: float = DEFAULT_SIM_DT,
        max_torque: float = DEFAULT_MAX_TORQUE,
        forward_reward_weight: float = 1.0,
        ctrl_cost_weight: float = DEFAULT_CTRL_COST_WEIGHT,
        reset_noise_scale: float = DEFAULT_RESET_NOISE_SCALE,
        exclude_current_positions_from_observation: bool = True,
        joint_damping: float = DEFAULT_JOINT_DAMPING,
        wheel_damping: float = DEFAULT_WHEEL_DAMPING,
        joint_limit: float | None = DEFAULT_JOINT_LIMIT,
        joint_limit_stiffness: float = DEFAULT_LIMIT_STIFFNESS,
        joint_limit_damping: float = DEFAULT_LIMIT_DAMPING,
        paper_model: bool = False,
        mass: float = 1.0,
        length: float = 0.2,
        inertia: float = 0.005,
        render_mode: str | None = None,
        width: int = 480,
        height: int = 480,
        integrator: str = DEFAULT_INTEGRATOR,
        energy_tolerance: float = DEFAULT_ENERGY_TOLERANCE,
        error_tolerance: float = DEFAULT_ERROR_TOLERANCE,
        max_refinements: int = DEFAULT_MAX_REFINEMENTS,
    ):
        self.num_envs = _number("num_envs", num_envs, "sub-envs", minimum=0, integer=True)
        if max_episode_steps is not None:
            max_episode_steps = _number("max_episode_steps", max_episode_steps, "steps, or None", minimum=0, integer=True)
        self.max_episode_steps = max_episode_steps
        self.autoreset_mode = _autoreset_mode(autoreset_mode)
        configure(self, n_links=n_links, frame_skip=frame_skip, sim_dt=sim_dt, max_torque=max_torque,
                  forward_reward_weight=forward_reward_weight, ctrl_cost_weight=ctrl_cost_weight,
                  reset_noise_scale=reset_noise_scale,
                  exclude_current_positions_from_observation=exclude_current_positions_from_observation,
                  joint_damping=joint_damping, wheel_damping=wheel_damping, joint_limit=joint_limit,
                  joint_limit_stiffness=joint_limit_stiffness, joint_limit_damping=joint_limit_damping,
                  paper_model=paper_model, mass=mass, length=length, inertia=inertia,
                  render_mode=render_mode, width=width, height=height, integrator=integrator,
                  energy_tolerance=energy_tolerance, error_tolerance=error_tolerance,
                  max_refinements=max_refinements)
        self.metadata = {**self.metadata, "render_fps": int(round(1.0 / self.dt)), "autoreset_mode": self.autoreset_mode}

        n, B = self.n_links, self.num_envs
        self.single_action_space = spaces.Box(-1.0, 1.0, (n - 1,), np.float32)
        self.action_space = batch_space(self.single_action_space, B)
        self.single_observation_space = observation_space(n, self.params.include_position)
        self.observation_space = batch_space(self.single_observation_space, B)
        self.observation_structure = observation_structure(n, self.params.include_position)

        self._q = np.zeros((B, n + 2))
        self._u = np.zeros((B, 2))
        self._torques = np.zeros((B, n - 1))
        self._obs = np.zeros((B, self.params.obs_size))
        self._aux = np.zeros((B, physics.AUX_SIZE))
        self._steps = np.zeros(B, np.int64)
        self._autoreset = np.zeros(B, bool)
        self._trail = None  # (TRAIL_LENGTH, B, 2) ring of CM positions, only when rendering
        self._trail_len = np.zeros(B, np.int64)
        self._renderer = None
        self._has_reset = False

    # ------------------------------------------------------------------ properties
    @property
    def dt(self) -> float:
        """Duration of one env step (s)."""
        return self.params.dt

    @property
    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """Copies of (q (B, n+2), u (B, 2)), see :attr:`SnakeEnv.state`."""
        return self._q.copy(), self._u.copy()

    def set_state(self, q, u) -> np.ndarray:
        """Put all sub-envs in states q (B, n+2), u (B, 2); return the observations.
        Episode step counters are not changed."""
        q = np.asarray(q, np.float64)
        u = np.asarray(u, np.float64)
        if q.shape != self._q.shape or u.shape != self._u.shape:
            raise ValueError(f"q must have shape {self._q.shape} and u {self._u.shape}, got {q.shape}, {u.shape}")
        obs, aux = physics.observe(self.params, q, u)
        self._q[:], self._u[:], self._obs[:], self._aux[:] = q, u, obs, aux
        self._trail_len[:] = 0
        self._record_trail(np.ones(self.num_envs, bool))
        self._has_reset = True
        return self._obs.copy()

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
        return self._obs.copy(), self._reset_info(mask)

    def step(self, actions):
        if not self._has_reset:
            raise gym.error.ResetNeeded("call reset() before step()")
        if self.autoreset_mode == AutoresetMode.DISABLED and self._autoreset.any():
            raise ValueError("autoreset_mode='Disabled': reset the finished sub-envs with "
                             "reset(options={'reset_mask': mask}) before stepping them again")
        a = check_actions(actions, self.action_space.shape)
        np.multiply(a, self.max_torque, out=self._torques)
        # every row is integrated (no branching in the kernel); rows awaiting a
        # next-step autoreset are overwritten by their reset below
        physics.step_inplace(self.params, self._q, self._u, self._torques, self._obs, self._aux)
        aux = self._aux
        B = self.num_envs
        stepped = ~self._autoreset if self.autoreset_mode == AutoresetMode.NEXT_STEP else np.ones(B, bool)
        self._record_trail(stepped)
        failed = (aux[:, AUX_FAILED] != 0.0) & stepped
        if failed.any():
            reasons = sorted({physics.FAILURE_REASONS[int(c)] for c in aux[failed, AUX_FAILED]})
            warnings.warn(f"snake_env: simulation failure in {int(failed.sum())} sub-env(s) ({'; '.join(reasons)}); "
                          "their step was undone, reward 0 and the episode truncated (info['sim_failure'])",
                          RuntimeWarning, stacklevel=2)
        reward_forward = self.forward_reward_weight * aux[:, AUX_VX]  # 0 on failure: the state was kept
        # as in SnakeEnv: a failed step has no control cost either (reward exactly 0)
        ctrl_cost = np.where(aux[:, AUX_FAILED] != 0.0, 0.0, self.ctrl_cost_weight * squared_norm(a))
        rewards = reward_forward - ctrl_cost
        self._steps += 1
        terminated = np.zeros(B, bool)
        truncated = failed.copy()
        if self.max_episode_steps is not None:
            truncated |= self._steps >= self.max_episode_steps
        info = self._step_info(reward_forward, ctrl_cost, failed, stepped)

        if self.autoreset_mode == AutoresetMode.NEXT_STEP:
            reset_mask = self._autoreset.copy()
            if reset_mask.any():
                self._reset_envs(reset_mask)
                rewards[reset_mask] = 0.0
                truncated[reset_mask] = False
                reset_info = self._reset_info(reset_mask)
                for key in RESET_INFO_KEYS:  # those sub-envs report their reset info
                    info[key][reset_mask] = reset_info[key][reset_mask]
            self._autoreset = terminated | truncated
        elif self.autoreset_mode == AutoresetMode.SAME_STEP:
            done = terminated | truncated
            if done.any():
                final_obs = np.full(B, None, dtype=object)
                for i in np.flatnonzero(done):  # an object array of per-env rows, as Gymnasium's vector envs give
                    final_obs[i] = self._obs[i].copy()
                info["final_obs"] = final_obs
                info["_final_obs"] = done.copy()
                final_info = {}
                for key in STEP_INFO_KEYS:
                    final_info[key] = info[key].copy()
                    final_info["_" + key] = done.copy()
                info["final_info"] = final_info
                info["_final_info"] = done.copy()
                self._reset_envs(done)
                reset_info = self._reset_info(done)
                for key in STEP_INFO_KEYS:
                    if key in RESET_INFO_KEYS:
                        info[key][done] = reset_info[key][done]
                    else:
                        info["_" + key] = info["_" + key] & ~done
        else:
            self._autoreset = terminated | truncated
        return self._obs.copy(), rewards, terminated, truncated, info

    # ------------------------------------------------------------------ internals
    def _reset_envs(self, mask: np.ndarray) -> None:
        k = int(mask.sum())
        s = self.reset_noise_scale
        noise = self.np_random.uniform(low=-s, high=s, size=(k, self.n_links + 2))
        q, u, obs, aux = physics.reset(self.params, noise)
        self._q[mask], self._u[mask], self._obs[mask], self._aux[mask] = q, u, obs, aux
        self._steps[mask] = 0
        self._autoreset[mask] = False
        self._trail_len[mask] = 0
        self._record_trail(mask)

    def _reset_info(self, mask: np.ndarray) -> dict[str, np.ndarray]:
        aux = self._aux
        values = {
            "x_position": aux[:, AUX_X].copy(),
            "y_position": aux[:, AUX_Y].copy(),
            "distance_from_origin": np.hypot(aux[:, AUX_X], aux[:, AUX_Y]),
            "kinetic_energy": aux[:, AUX_KINETIC].copy(),
        }
        info = {}
        for key, value in values.items():
            info[key] = np.where(mask, value, 0.0)
            info["_" + key] = mask.copy()
        return info

    def _step_info(self, reward_forward, ctrl_cost, failed, stepped) -> dict[str, np.ndarray]:
        aux = self._aux
        values = {
            "x_position": aux[:, AUX_X].copy(),
            "y_position": aux[:, AUX_Y].copy(),
            "distance_from_origin": np.hypot(aux[:, AUX_X], aux[:, AUX_Y]),
            "x_velocity": aux[:, AUX_VX].copy(),
            "y_velocity": aux[:, AUX_VY].copy(),
            "reward_forward": reward_forward,
            "reward_ctrl": -ctrl_cost,
            "kinetic_energy": aux[:, AUX_KINETIC].copy(),
            "power": aux[:, AUX_WORK] / self.dt,
            "sim_failure": failed,
        }
        info = {}
        everyone = np.ones(self.num_envs, bool)
        for key in STEP_INFO_KEYS:
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
        self._trail[slot[idx], idx] = self._aux[idx][:, [AUX_X, AUX_Y]]
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
            frames.append(self._renderer.draw(self._q[i], self._trail[order, i] if count else None))
        return tuple(frames)

    def close_extras(self, **kwargs):
        self._renderer = None

    def __getstate__(self):
        state = self.__dict__.copy()
        state["_renderer"] = None
        return state
