"""Atomic file writes: write a temp file in the target's directory, then rename.

``os.replace`` is atomic on POSIX within one file system, so a reader (or a
crash, or Ctrl-C) never sees a half-written model, statistics or config file.
"""

from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextmanager
def atomic_path(target, suffix: str = ""):
    """Yield a temp path beside ``target``; on success rename it onto ``target``.

    ``suffix`` keeps extensions that writers insist on (SB3 appends ``.zip``
    when a model path has no suffix).
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=f".tmp{suffix}", dir=target.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        # mkstemp creates 0600 files; give the result the usual umask-based mode
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, target)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def atomic_write_text(target, text: str) -> None:
    with atomic_path(target) as tmp:
        tmp.write_text(text)


def atomic_write_bytes(target, data: bytes) -> None:
    with atomic_path(target) as tmp:
        tmp.write_bytes(data)


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
