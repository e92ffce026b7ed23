"""Features extractors for SB3 policies on the snake's goal tasks.

``goal_frame`` (:class:`GoalFrameExtractor`) computes, inside the policy, what the
``goal_frame`` wrapper appends to the observation: the goal relative to the CM in the
snake's heading frame, R(-theta_bar) (desired_goal - achieved_goal) (m; x ahead, y to the
left). The wrapper computes it once from the goal the env drew, so HER's relabelled goals
would leave it stale. The extractor computes it from whatever ``desired_goal`` the batch
holds, so it stays true for relabelled transitions and combines with ``HerReplayBuffer``.
Select it in a config with ``policy_kwargs: "dict(features_extractor_class='goal_frame')"``;
``snake-train`` fills in the observation layout of the env (:func:`goal_frame_kwargs`).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor

GOAL_KEYS = ("observation", "achieved_goal", "desired_goal")


class GoalFrameExtractor(BaseFeaturesExtractor):
    """Features = [observation, achieved_goal, desired_goal, ahead, left] of a goal task's Dict
    observation; (ahead, left) = R(-theta_bar) (desired_goal - achieved_goal) (m), with
    theta_bar = theta_1 + (1/n) sum_j (n - j) phi_j the mean link angle (theta_k = theta_1 +
    sum_{j<k} phi_j) and theta_1 from the observation's heading entries (cos, sin).

    Args:
        observation_space: the goal task's Dict space (``observation``, ``achieved_goal``,
            ``desired_goal``; goals of shape (2,)).
        n_links: number of links n of the snake.
        phi_start: index of phi_1 in ``observation`` (0, or 2 when the CM position leads it).
    """

    def __init__(self, observation_space: spaces.Dict, n_links: int, phi_start: int = 0):
        if not isinstance(observation_space, spaces.Dict) or not set(GOAL_KEYS) <= set(observation_space.spaces):
            raise ValueError(f"goal_frame needs a goal task's Dict observation with keys {list(GOAL_KEYS)}, "
                             f"got {observation_space}")
        size = observation_space["observation"].shape[0]
        if isinstance(n_links, bool) or not isinstance(n_links, int) or n_links < 2:
            raise ValueError(f"goal_frame n_links must be an integer >= 2, got {n_links!r}")
        if phi_start not in (0, 2) or phi_start + n_links + 1 > size:
            raise ValueError(f"goal_frame phi_start must be 0 or 2 and leave room for {n_links - 1} joint angles and "
                             f"the heading in an observation of size {size}, got {phi_start!r}")
        goal_sizes = {observation_space[key].shape for key in GOAL_KEYS[1:]}
        if goal_sizes != {(2,)}:
            raise ValueError(f"goal_frame needs planar goals of shape (2,), got {sorted(goal_sizes)}")
        super().__init__(observation_space, features_dim=size + 2 + 2 + 2)
        self.phi = slice(phi_start, phi_start + n_links - 1)
        self.heading = phi_start + n_links - 1  # cos theta_1, then sin theta_1
        weights = (n_links - np.arange(1, n_links)) / n_links
        self.register_buffer("weights", torch.as_tensor(weights, dtype=torch.float32))

    def forward(self, observations: dict) -> torch.Tensor:
        obs = observations["observation"].float()
        achieved = observations["achieved_goal"].float()
        desired = observations["desired_goal"].float()
        theta_1 = torch.atan2(obs[:, self.heading + 1], obs[:, self.heading])
        theta_bar = theta_1 + obs[:, self.phi] @ self.weights
        cos, sin = torch.cos(theta_bar), torch.sin(theta_bar)
        delta = desired - achieved
        ahead = cos * delta[:, 0] + sin * delta[:, 1]
        left = -sin * delta[:, 0] + cos * delta[:, 1]
        return torch.cat([obs, achieved, desired, ahead[:, None], left[:, None]], dim=1)


def goal_frame_kwargs(env_id: str, env_kwargs: dict) -> dict:
    """GoalFrameExtractor's keyword arguments for the env ``env_id``: its n and where phi starts,
    read as the goal_frame wrapper reads them."""
    import snake_env  # noqa: F401  (registers the ids)
    from snake_env.wrappers.observation import _goal_frame_geometry

    env = gym.make(env_id, **env_kwargs)
    try:
        geometry = _goal_frame_geometry(env)
        return {"n_links": geometry["n_links"], "phi_start": geometry["phi"].start}
    finally:
        env.close()


# name in policy_kwargs -> (extractor class, its keyword arguments for an env id and env kwargs)
EXTRACTORS = {"goal_frame": (GoalFrameExtractor, goal_frame_kwargs)}
