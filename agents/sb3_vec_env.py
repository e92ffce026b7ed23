"""Stable-Baselines3 ``VecEnv`` over the batched :class:`SnakeVectorEnv`.

SB3 trains on a ``VecEnv`` whose finished sub-envs are reset in the same
``step`` call: the returned observation is already the new episode's, the
last one goes to ``infos[i]["terminal_observation"]`` and a time-limit end is
flagged by ``infos[i]["TimeLimit.truncated"]`` (so bootstrapping stays right).
A Dict observation (goal tasks) is a dict of (B, ...) arrays and its terminal
observation a dict of rows, as SB3's ``DictReplayBuffer`` / ``HerReplayBuffer``
expect; ``env_method("compute_reward", ...)`` reaches the vector env's
vectorized ``compute_reward``. That is Gymnasium's ``AutoresetMode.SAME_STEP``, so the adapter runs the
vector env in that mode and only reshapes its outputs: one compiled physics
call per step for all sub-envs, instead of SB3's ``DummyVecEnv`` loop over
``gym.Env`` copies.

Usage::

    from snake_env.agents.sb3_vec_env import SnakeSB3VecEnv
    venv = SnakeSB3VecEnv("snake_env/Snake5-v2", num_envs=16, ctrl_cost_weight=1e-4)
    venv = VecMonitor(venv)          # episode returns/lengths in infos["episode"]
    venv = VecNormalize(venv)        # save its statistics with the model
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvObs, VecEnvStepReturn

import snake_env  # noqa: F401  (registers the ids)
from snake_env.envs.snake import RESET_INFO_KEYS
from snake_env.envs.vector import SnakeVectorEnv


class SnakeSB3VecEnv(VecEnv):
    """SB3 ``VecEnv`` of ``num_envs`` snakes stepped together.

    Args:
        env: a registered id (e.g. ``"snake_env/Snake5-v2"``), built with
            ``gym.make_vec(env, num_envs, vectorization_mode="vector_entry_point",
            autoreset_mode="SameStep", **env_kwargs)``; or an existing
            :class:`SnakeVectorEnv` created with ``autoreset_mode="SameStep"``.
        num_envs: number of sub-envs (only with an id).
        **env_kwargs: :class:`SnakeEnv` kwargs (only with an id), plus
            ``max_episode_steps`` to override the registration's 1000.

    ``seed(s)`` seeds the next ``reset()`` with ``s`` (one generator drives all
    sub-envs, so ``s + i`` seeds are not used individually).
    """

    def __init__(self, env: str | SnakeVectorEnv, num_envs: int | None = None, **env_kwargs: Any):
        if isinstance(env, str):
            if num_envs is None:
                num_envs = 1
            env_kwargs = {"autoreset_mode": AutoresetMode.SAME_STEP, **env_kwargs}
            venv = gym.make_vec(env, num_envs=num_envs, vectorization_mode="vector_entry_point", **env_kwargs)
        elif isinstance(getattr(env, "unwrapped", None), SnakeVectorEnv):
            if num_envs is not None or env_kwargs:
                raise ValueError("num_envs and env kwargs can only be given with an env id, not with a built SnakeVectorEnv")
            venv = env
        else:
            raise ValueError(f"env must be a registered snake_env id or a SnakeVectorEnv, got {env!r}")
        if venv.unwrapped.autoreset_mode != AutoresetMode.SAME_STEP:
            raise ValueError("SnakeSB3VecEnv needs the vector env's autoreset_mode='SameStep' (SB3 resets finished "
                             f"envs in the same step), got {venv.unwrapped.autoreset_mode}")
        self.venv = venv
        self.step_info_keys = venv.unwrapped.step_info_keys  # the task's
        self._actions: np.ndarray | None = None
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
        self.metadata = {**self.metadata, "render_fps": venv.metadata.get("render_fps")}

    # ------------------------------------------------------------------ core API
    def reset(self) -> VecEnvObs:
        seed = self._seeds[0]
        options = self._options[0] or None
        obs, info = self.venv.reset(seed=seed, options=options)
        self.reset_infos = self._split(info, RESET_INFO_KEYS)
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise ValueError("step_wait() called without a pending step_async(actions)")
        obs, rewards, terminated, truncated, info = self.venv.step(self._actions)
        self._actions = None
        dones = terminated | truncated
        infos = self._split(info, self.step_info_keys)
        time_limit = (truncated & ~terminated).tolist()
        for step_info, flag in zip(infos, time_limit):
            step_info["TimeLimit.truncated"] = flag  # as DummyVecEnv reports it, on every step
        if dones.any():
            final_info = info["final_info"]
            final_values = {key: final_info[key] for key in self.step_info_keys}
            for i in np.flatnonzero(dones):
                step_info = {key: _entry(final_values[key], i) for key in self.step_info_keys}
                step_info["terminal_observation"] = info["final_obs"][i]
                step_info["TimeLimit.truncated"] = time_limit[i]
                self.reset_infos[i] = {key: infos[i][key] for key in RESET_INFO_KEYS}
                infos[i] = step_info
        return obs, rewards.astype(np.float32), dones, infos

    def close(self) -> None:
        self.venv.close()

    # ------------------------------------------------------------------ helpers
    def _split(self, info: dict, keys: Sequence[str]) -> list[dict[str, Any]]:
        """Gymnasium's batched info (arrays + masks) -> SB3's list of per-env dicts."""
        present = [key for key in keys if key in info]
        # Python scalars, or one array per sub-env for a per-wheel entry (as DummyVecEnv gives them)
        columns = [info[key].tolist() if info[key].ndim == 1 else list(info[key]) for key in present]
        masks = [info["_" + key] for key in present]
        if all(mask.all() for mask in masks):
            return [dict(zip(present, row)) for row in zip(*columns)] if present else [{} for _ in range(self.num_envs)]
        return [{key: col[i] for key, col, mask in zip(present, columns, masks) if mask[i]} for i in range(self.num_envs)]

    # ------------------------------------------------------------------ attribute access
    # All sub-envs share one configuration, so attributes are read from the
    # vector env and reported once per requested index.
    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        value = getattr(self.venv.unwrapped, attr_name)
        return [value for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        if sorted(self._get_indices(indices)) != list(range(self.num_envs)):
            raise ValueError("set_attr applies to every sub-env of a batched snake env; pass indices=None")
        setattr(self.venv.unwrapped, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list[Any]:
        result = getattr(self.venv.unwrapped, method_name)(*method_args, **method_kwargs)
        return [result for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        # the sub-envs are rows of one batched env: no gym.Wrapper is ever around them
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        if self.render_mode != "rgb_array":
            return [None for _ in range(self.num_envs)]
        return list(self.venv.render())


def _entry(values: np.ndarray, i: int):
    """Sub-env i's value of a batched info entry: a Python scalar, or an array (a per-wheel entry),
    as the single env and SB3's DummyVecEnv give it."""
    return values[i].item() if values.ndim == 1 else values[i]
