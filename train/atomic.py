"""Atomic saves of SB3 artefacts (model, VecNormalize statistics, replay buffer),
on top of :mod:`snake_env.atomic`: a crash or Ctrl-C never leaves a half-written file."""

from __future__ import annotations

from snake_env.atomic import atomic_path, atomic_write_bytes, atomic_write_text

__all__ = ["atomic_path", "atomic_write_bytes", "atomic_write_text", "save_model", "save_vecnormalize",
           "save_replay_buffer"]


def save_model(model, target) -> None:
    """``model.save`` through a temp ``.zip`` then rename onto ``target``."""
    with atomic_path(target, suffix=".zip") as tmp:
        model.save(tmp)


def save_vecnormalize(vec_normalize, target) -> None:
    with atomic_path(target) as tmp:
        vec_normalize.save(tmp)


def save_replay_buffer(model, target) -> None:
    with atomic_path(target, suffix=".pkl") as tmp:
        model.save_replay_buffer(tmp)
