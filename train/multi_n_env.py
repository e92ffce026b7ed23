"""One SB3 ``VecEnv`` of snakes of several lengths, padded to the longest, for the shared per-joint policy.

Config (``snake-train``): ``n_links_set: [5, 8, 12]`` beside ``policy: JointPolicy`` trains one run on
snakes of 5, 8 and 12 links. ``env_id`` names the task and its registration (any forward id, e.g.
``snake_env/Snake-v2``); each size is made as ``gym.make_vec(env_id, n_links=n, **env_kwargs)``, so
every physical kwarg but n is shared. The ``n_envs`` sub-envs are split over the sizes in order,
as evenly as possible (rows 0.. of the batch hold the smallest n); ``n_envs`` must be at least the
number of sizes. Each size is one batched :class:`~snake_env.agents.sb3_vec_env.SnakeSB3VecEnv`
(one compiled physics call per size and step).

Padding (the format :mod:`snake_env.train.joint_features` reads): every observation is laid out as
the longest snake's, J_max = max(n) - 1 joints; a shorter snake's per-joint blocks (joint angles,
joint rates) hold its J real joints first and zeros after them, its body-level blocks are copied,
and a mask of J_max entries (1.0 real joint, 0.0 padding) ends the vector. Terminal observations in
``infos`` are padded the same way. Actions are (num_envs, J_max); sub-env i receives only its first
J_i entries, its real joints' torques, so padded actions never reach any physics. The policy
zeroes padded joints' features after every layer, so they never change real joints' actions.

Evaluation on one n needs no padding: the policy is rebuilt for that env's spaces with the same
weights (:meth:`snake_env.train.joint_policy.JointActorCriticPolicy.for_spaces`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvObs, VecEnvStepReturn

from snake_env.agents.sb3_vec_env import SnakeSB3VecEnv
from snake_env.train.joint_features import JOINT, base_size, layout_from_structure


def check_n_links_set(value) -> list[int]:
    """``n_links_set`` as a sorted list of distinct integers >= 2.

    Raises:
        ValueError: one line naming the allowed values.
    """
    if not isinstance(value, (list, tuple)) or not value or not all(
            isinstance(n, int) and not isinstance(n, bool) and n >= 2 for n in value) or len(set(value)) != len(value):
        raise ValueError(f"n_links_set must be a list of distinct integers >= 2 (link counts), got {value!r}")
    return sorted(int(n) for n in value)


def split_envs(num_envs: int, count: int) -> list[int]:
    """``num_envs`` sub-envs over ``count`` sizes, as evenly as possible, earlier sizes first."""
    if num_envs < count:
        raise ValueError(f"n_envs must be at least the number of sizes in n_links_set ({count}), got {num_envs}")
    return [num_envs // count + (1 if i < num_envs % count else 0) for i in range(count)]


class MultiNVecEnv(VecEnv):
    """SB3 ``VecEnv`` over snakes of several n, padded to the longest (module doc).

    Args:
        env_id: a registered forward-task id; its ``n_links`` is replaced by each size.
        n_links_set: the link counts, e.g. [5, 8, 12].
        num_envs: total number of sub-envs (at least ``len(n_links_set)``).
        **env_kwargs: :class:`SnakeEnv` kwargs shared by every size (not ``n_links``).
    """

    def __init__(self, env_id: str, n_links_set: Sequence[int], num_envs: int, **env_kwargs: Any):
        if "n_links" in env_kwargs:
            raise ValueError(f"env_kwargs n_links conflicts with n_links_set {list(n_links_set)}; remove one")
        self.n_links_set = check_n_links_set(n_links_set)
        counts = split_envs(int(num_envs), len(self.n_links_set))
        self.groups = [SnakeSB3VecEnv(env_id, num_envs=c, n_links=n, **env_kwargs)
                       for n, c in zip(self.n_links_set, counts)]
        self.rows = []
        start = 0
        for c in counts:
            self.rows.append(slice(start, start + c))
            start += c
        layouts, sources = [], []
        for group in self.groups:
            base = group.venv.unwrapped
            layouts.append(layout_from_structure(base.observation_structure, int(base.n_links),
                                                 int(group.observation_space.shape[0])))
        if any(layout != layouts[-1] for layout in layouts):
            raise ValueError(f"{env_id} observations differ in layout across n_links_set {self.n_links_set}")
        self.layout = layouts[-1]
        self.joints = [n - 1 for n in self.n_links_set]
        self.max_joints = self.joints[-1]
        size = base_size(self.layout, self.max_joints) + self.max_joints
        for joints in self.joints:
            sources.append(self._index_map(joints))
        self._targets = sources  # per group: (destination indices, mask start)
        longest = self.groups[-1].observation_space
        low = np.concatenate([longest.low, np.zeros(self.max_joints)])
        high = np.concatenate([longest.high, np.ones(self.max_joints)])
        observation_space = spaces.Box(low=low, high=high, shape=(size,), dtype=longest.dtype)
        self._dtype = longest.dtype
        super().__init__(int(num_envs), observation_space, self.groups[-1].action_space)

    def _index_map(self, joints: int) -> np.ndarray:
        """Where each entry of a J-joint observation goes in the padded vector."""
        dest, src_at, dst_at = [], 0, 0
        for _, size in self.layout:
            width = joints if size == JOINT else size
            padded = self.max_joints if size == JOINT else size
            dest.extend(range(dst_at, dst_at + width))
            src_at += width
            dst_at += padded
        return np.asarray(dest, dtype=np.intp)

    def pad(self, group: int, obs: np.ndarray) -> np.ndarray:
        """Observations (rows, obs_g) of size group ``group`` -> padded (rows, padded size)."""
        obs = np.asarray(obs)
        single = obs.ndim == 1
        obs = np.atleast_2d(obs)
        out = np.zeros((obs.shape[0], self.observation_space.shape[0]), dtype=self._dtype)
        out[:, self._targets[group]] = obs
        mask_start = base_size(self.layout, self.max_joints)
        out[:, mask_start:mask_start + self.joints[group]] = 1.0
        return out[0] if single else out

    # ------------------------------------------------------------------ core API
    def seed(self, seed: int | None = None):
        seeds = super().seed(seed)
        for group, rows in zip(self.groups, self.rows):
            group.seed(seeds[rows.start])
        return seeds

    def reset(self) -> VecEnvObs:
        obs = []
        for g, (group, rows) in enumerate(zip(self.groups, self.rows)):
            if self._options[rows.start]:
                group.set_options(self._options[rows.start])
            obs.append(self.pad(g, group.reset()))
        self.reset_infos = [info for group in self.groups for info in group.reset_infos]
        self._reset_seeds()
        self._reset_options()
        return np.concatenate(obs)

    def step_async(self, actions: np.ndarray) -> None:
        actions = np.asarray(actions)
        for group, rows, joints in zip(self.groups, self.rows, self.joints):
            group.step_async(actions[rows, :joints])

    def step_wait(self) -> VecEnvStepReturn:
        obs, rewards, dones, infos = [], [], [], []
        for g, group in enumerate(self.groups):
            o, r, d, i = group.step_wait()
            for info in i:
                if "terminal_observation" in info:
                    info["terminal_observation"] = self.pad(g, info["terminal_observation"])
            obs.append(self.pad(g, o))
            rewards.append(r)
            dones.append(d)
            infos.extend(i)
        self.reset_infos = [info for group in self.groups for info in group.reset_infos]
        return np.concatenate(obs), np.concatenate(rewards), np.concatenate(dones), infos

    def close(self) -> None:
        for group in self.groups:
            group.close()

    # ------------------------------------------------------------------ attribute access
    def _locate(self, indices: VecEnvIndices) -> list[tuple[int, int]]:
        """(group, row within the group) of each requested sub-env."""
        out = []
        for i in self._get_indices(indices):
            for g, rows in enumerate(self.rows):
                if rows.start <= i < rows.stop:
                    out.append((g, i - rows.start))
        return out

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [self.groups[g].get_attr(attr_name, [r])[0] for g, r in self._locate(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        if sorted(self._get_indices(indices)) != list(range(self.num_envs)):
            raise ValueError("set_attr applies to every sub-env of a multi-n snake env; pass indices=None")
        for group in self.groups:
            group.set_attr(attr_name, value)

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list[Any]:
        return [self.groups[g].env_method(method_name, *method_args, indices=[r], **method_kwargs)[0]
                for g, r in self._locate(indices)]

    def env_is_wrapped(self, wrapper_class, indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [image for group in self.groups for image in group.get_images()]
