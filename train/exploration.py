"""Temporally correlated exploration for SAC and PPO: ``noise_type: pink`` (RL Zoo's key).

SAC's stochastic policy draws fresh white Gaussian noise at every control step. On a snake behind
servo motors (v3) that noise averages out within a few steps: the joints barely move away from the
mean action, and the policy rarely sees the slow, large bends a gait is made of. Pink noise (power
spectrum 1/f) keeps the per-step variance but puts it into slow variations; Eberhard et al.,
"Pink Noise Is All You Need: Colored Noise Exploration in Deep Reinforcement Learning" (ICLR 2023)
found it the best default over white and Ornstein-Uhlenbeck noise. The noise process is the
paper's package, ``pink-noise-rl`` (``pink.cnrl.PinkNoiseProcess``).

Its own SB3 distribution (``pink.sb3.PinkNoiseDist``) draws one noise vector per call, so the
``n_envs`` snakes of a batched rollout would share it, and it replaces the noise of the actor's
training batches too. :class:`PinkNoiseDistribution` keeps one pink process per sub-env, uses it
only while collecting rollouts (the actor in eval mode, one row per sub-env), and leaves SB3's
reparameterised white noise in the gradient steps, where the loss expects independent samples.

PPO (:class:`PinkNoiseGaussian`): the rollout's actions take the same per-sub-env pink noise, scaled
by the policy's std. Each step's noise is still a standard normal draw, so an action keeps the
Gaussian's marginal law and its log-probability is the Gaussian's, which PPO's ratio uses; only the
correlation from step to step changes, as in the paper's on-policy use of coloured noise. PPO's
gradient steps never sample (they evaluate the stored actions).
"""

from __future__ import annotations

import weakref

import numpy as np
import torch as th
from stable_baselines3.common.distributions import DiagGaussianDistribution, SquashedDiagGaussianDistribution

NOISE_TYPES = ("pink",)


def check_noise_type(config: dict) -> None:
    """One-line ValueError unless ``noise_type`` is None or a supported type for this config."""
    value = config.get("noise_type")
    if value is None:
        return
    if value not in NOISE_TYPES:
        raise ValueError(f"noise_type must be one of {list(NOISE_TYPES)} or null, got {value!r}")
    if config.get("policy", "MlpPolicy") not in ("MlpPolicy", "MultiInputPolicy"):
        raise ValueError(f"noise_type {value} needs policy MlpPolicy or MultiInputPolicy, "
                         f"got {config.get('policy')}")
    if config.get("use_sde"):
        raise ValueError(f"noise_type {value} does not combine with use_sde (gSDE draws its own noise)")


class _PinkRollouts:
    """One pink-noise process per sub-env, drawn only while ``owner`` (an nn.Module) is in eval mode."""

    def __init__(self, action_dim: int, n_envs: int, seq_len: int, owner, seed: int):
        super().__init__(action_dim)  # the SB3 distribution after this class in the MRO
        from pink.cnrl import PinkNoiseProcess

        self.n_envs = n_envs
        self.process = PinkNoiseProcess(size=(n_envs, action_dim, seq_len), rng=np.random.default_rng(seed))
        self._owner = weakref.ref(owner)  # the owner holds this distribution: no cycle back to it

    def _pink(self, mean: th.Tensor) -> th.Tensor | None:
        """A standard-normal pink draw shaped as ``mean``, or None outside a rollout (white noise then)."""
        if self._owner().training or mean.shape[0] != self.n_envs:
            return None
        return th.as_tensor(self.process.sample(), dtype=mean.dtype).reshape(mean.shape)


class PinkNoiseDistribution(_PinkRollouts, SquashedDiagGaussianDistribution):
    """SAC's squashed Gaussian whose rollout samples take pink noise, one process per sub-env.

    Args:
        action_dim: the action's size.
        n_envs: sub-envs of the rollout VecEnv (rows of a rollout batch).
        seq_len: the noise's longest correlation (control steps), the episode length as the paper sets it.
        owner: the SAC actor (its ``training`` flag tells rollouts, False, from gradient steps, True).
        seed: seed of the noise processes.
    """

    def sample(self) -> th.Tensor:
        mean = self.distribution.mean
        noise = self._pink(mean)
        if noise is None:
            return super().sample()
        self.gaussian_actions = mean + self.distribution.stddev * noise
        return th.tanh(self.gaussian_actions)


class PinkNoiseGaussian(_PinkRollouts, DiagGaussianDistribution):
    """PPO's diagonal Gaussian whose rollout samples take pink noise, one process per sub-env.

    Args: as :class:`PinkNoiseDistribution`, with ``owner`` the PPO policy (in eval mode while
    collecting rollouts, in train mode in its gradient steps).
    """

    def sample(self) -> th.Tensor:
        mean = self.distribution.mean
        noise = self._pink(mean)
        if noise is None:
            return super().sample()
        return mean + self.distribution.stddev * noise


def apply_exploration(model, config: dict, seq_len: int) -> None:
    """Install the configured exploration noise on a built or loaded model (a no-op without one)."""
    if config.get("noise_type") != "pink":
        return
    action_dim = int(np.prod(model.action_space.shape))
    seed = config["seed"] + 20_000
    if hasattr(model, "actor"):  # SAC
        model.actor.action_dist = PinkNoiseDistribution(action_dim, model.n_envs, seq_len, model.actor, seed=seed)
    else:  # PPO: the policy builds its distribution from action_dist on every forward pass
        model.policy.action_dist = PinkNoiseGaussian(action_dim, model.n_envs, seq_len, model.policy, seed=seed)
