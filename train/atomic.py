"""Atomic saves of SB3 artefacts (model, VecNormalize statistics, replay buffer),
on top of :mod:`snake_env.atomic`: a crash or Ctrl-C never leaves a half-written file."""

from __future__ import annotations

from contextlib import contextmanager

from snake_env.atomic import atomic_path, atomic_write_bytes, atomic_write_text

__all__ = ["atomic_path", "atomic_write_bytes", "atomic_write_text", "save_model", "save_vecnormalize",
           "save_replay_buffer", "interrupts_deferred", "defer_interrupt"]

# An interrupt that arrives while a save runs is held until the save ends: raised inside torch.save, the
# KeyboardInterrupt left its zip writer half-closed, whose own error (RuntimeError) then replaced it, so the
# run exited 1 without saving its final model (seen in CI: tests/train/test_train_cli.py, SIGINT during a
# checkpoint).
_saving = 0
_pending: int | None = None


@contextmanager
def interrupts_deferred():
    """Hold an interrupt (:func:`defer_interrupt`) until the outermost such block ends, then raise it as
    KeyboardInterrupt."""
    global _saving, _pending
    _saving += 1
    try:
        yield
    finally:
        _saving -= 1
    if _saving == 0 and _pending is not None:
        signum, _pending = _pending, None
        raise KeyboardInterrupt(f"signal {signum}")


def defer_interrupt(signum: int) -> bool:
    """For a signal handler: True if a save is running, and the interrupt is then raised when it ends."""
    global _pending
    if _saving:
        _pending = signum
        return True
    return False


def save_model(model, target) -> None:
    """``model.save`` through a temp ``.zip`` then rename onto ``target``."""
    with interrupts_deferred(), atomic_path(target, suffix=".zip") as tmp:
        model.save(tmp)


def save_vecnormalize(vec_normalize, target) -> None:
    with interrupts_deferred(), atomic_path(target) as tmp:
        vec_normalize.save(tmp)


def save_replay_buffer(model, target) -> None:
    with interrupts_deferred(), atomic_path(target, suffix=".pkl") as tmp:
        model.save_replay_buffer(tmp)
