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
