"""SB3 callbacks that keep VecNormalize statistics with every saved model.

RL Zoo users lose runs because a checkpoint without its normalization
statistics cannot be evaluated faithfully; here every checkpoint, every new
best model and the final model are written together with ``vecnormalize``
statistics, each file atomically.
"""

from __future__ import annotations

import re
from pathlib import Path

from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecNormalize

from snake_env.train import atomic

CHECKPOINT_RE = re.compile(r"^model_(\d+)_steps\.zip$")


def vecnormalize_of(model) -> VecNormalize | None:
    env = model.get_vec_normalize_env()
    return env if isinstance(env, VecNormalize) else None


def checkpoint_paths(directory, steps: int) -> dict[str, Path]:
    directory = Path(directory)
    return {
        "model": directory / f"model_{steps}_steps.zip",
        "vecnormalize": directory / f"vecnormalize_{steps}_steps.pkl",
    }


def save_snapshot(model, model_path, vecnormalize_path, replay_buffer_path=None) -> None:
    """Write the model, its normalization statistics and (off-policy) replay
    buffer; the statistics go first so a model file never exists without them."""
    vec_normalize = vecnormalize_of(model)
    if vec_normalize is not None:
        atomic.save_vecnormalize(vec_normalize, vecnormalize_path)
    if replay_buffer_path is not None and getattr(model, "replay_buffer", None) is not None:
        atomic.save_replay_buffer(model, replay_buffer_path)
    atomic.save_model(model, model_path)


def save_checkpoint(model, directory) -> Path:
    """Checkpoint at ``model.num_timesteps``; an off-policy model also keeps
    its (single, latest) replay buffer so ``--resume`` continues faithfully."""
    paths = checkpoint_paths(directory, model.num_timesteps)
    replay = Path(directory) / "replay_buffer.pkl" if hasattr(model, "replay_buffer") else None
    save_snapshot(model, paths["model"], paths["vecnormalize"], replay)
    return paths["model"]


def latest_checkpoint(directory) -> tuple[int, Path] | None:
    """(timesteps, path) of the newest ``model_<steps>_steps.zip``, or None."""
    directory = Path(directory)
    if not directory.is_dir():
        return None
    found = []
    for path in directory.iterdir():
        match = CHECKPOINT_RE.match(path.name)
        if match:
            found.append((int(match.group(1)), path))
    return max(found) if found else None


class CheckpointWithStats(BaseCallback):
    """Save a checkpoint (model + VecNormalize statistics) every ``save_freq``
    environment steps, counted over all envs."""

    def __init__(self, save_freq: int, directory, verbose: int = 0):
        super().__init__(verbose)
        self.save_freq = int(save_freq)
        self.directory = Path(directory)
        self._next_save = None

    def _on_training_start(self) -> None:
        self._next_save = (self.model.num_timesteps // self.save_freq + 1) * self.save_freq

    def _on_step(self) -> bool:
        if self.model.num_timesteps >= self._next_save:
            path = save_checkpoint(self.model, self.directory)
            self._next_save += self.save_freq
            if self.verbose:
                print(f"checkpoint saved: {path}")
        return True


class SaveBestWithStats(BaseCallback):
    """Used as ``EvalCallback(callback_on_new_best=...)``: writes the best
    model and its VecNormalize statistics atomically into ``directory``."""

    def __init__(self, directory, verbose: int = 0):
        super().__init__(verbose)
        self.directory = Path(directory)

    def _on_step(self) -> bool:
        save_snapshot(self.model, self.directory / "best_model.zip", self.directory / "vecnormalize.pkl")
        return True


class ResidualBurnIn(BaseCallback):
    """The start of residual policy learning (Silver et al. 2018, "Residual Policy Learning",
    sec. 4): for use with ``env_wrapper: serpenoid_residual``, whose zero action is the
    baseline gait.

    On a fresh model the policy's mean layer is set to zero, so the first policy *is* the
    baseline, and (SAC) its log standard deviation to the constant ``log_std``, a small
    exploration noise that the gait survives (docs/learning.md, note 4: per-step torque
    noise of 0.135 of the torque limit takes the Snake12 gait from 1.03 to 0.09 m/s). For the first ``burn_in_steps``
    env steps (summed over envs) the actor is frozen and only the critic learns, from
    rollouts of that gait; the actor's first update then follows a critic that has seen
    what the gait is worth, rather than a random one. Needs ``learning_starts: 0`` with
    SAC: SB3 acts uniformly at random before ``learning_starts``, which is not the gait.

    Args:
        burn_in_steps: env steps with the actor frozen, an integer >= 0.
        log_std: initial log standard deviation of SAC's Gaussian before its tanh, in
            [-10, 2] (SB3 clips SAC's log std to [-20, 2]); PPO keeps its ``log_std_init``.
    """

    def __init__(self, burn_in_steps: int = 50_000, log_std: float = -3.0, verbose: int = 0):
        super().__init__(verbose)
        if isinstance(burn_in_steps, bool) or not isinstance(burn_in_steps, int) or burn_in_steps < 0:
            raise ValueError(f"ResidualBurnIn burn_in_steps must be an integer >= 0, got {burn_in_steps!r}")
        if isinstance(log_std, bool) or not isinstance(log_std, (int, float)) or not -10.0 <= log_std <= 2.0:
            raise ValueError(f"ResidualBurnIn log_std must be a number in [-10, 2], got {log_std!r}")
        self.burn_in_steps = burn_in_steps
        self.log_std = float(log_std)
        self._frozen = False

    def _actor_parts(self):
        """(mean layer, SAC log-std layer or None, parameters the actor's update changes)."""
        import torch.nn as nn

        if hasattr(self.model, "actor"):  # SAC
            actor = self.model.actor
            if not isinstance(actor.mu, nn.Linear) or not isinstance(actor.log_std, nn.Linear):
                raise ValueError("ResidualBurnIn supports SAC without gSDE (use_sde: false)")
            return actor.mu, actor.log_std, list(actor.parameters())
        policy = self.model.policy  # PPO: the policy branch, its action head and log std
        params = [*policy.mlp_extractor.policy_net.parameters(), *policy.action_net.parameters(), policy.log_std]
        return policy.action_net, None, params

    def _set_frozen(self, frozen: bool) -> None:
        for param in self._actor_parts()[2]:
            param.requires_grad_(not frozen)
        self._frozen = frozen

    def _on_training_start(self) -> None:
        import torch

        # snake-train's config check says this first; RL Zoo builds the callback without it
        if getattr(self.model, "learning_starts", 0) > self.model.num_timesteps:
            raise ValueError("ResidualBurnIn needs learning_starts: 0 (SB3 acts at random before learning_starts)")
        mean, log_std, _ = self._actor_parts()
        if self.model.num_timesteps == 0:
            with torch.no_grad():
                mean.weight.zero_()
                mean.bias.zero_()
                if log_std is not None:
                    log_std.weight.zero_()
                    log_std.bias.fill_(self.log_std)
        self._set_frozen(self.model.num_timesteps < self.burn_in_steps)

    def _on_step(self) -> bool:
        if self._frozen and self.model.num_timesteps >= self.burn_in_steps:
            self._set_frozen(False)
            if self.verbose:
                print(f"ResidualBurnIn: actor unfrozen at {self.model.num_timesteps} steps")
        return True

    def _on_training_end(self) -> None:
        self._set_frozen(False)  # a saved or resumed model trains as usual
