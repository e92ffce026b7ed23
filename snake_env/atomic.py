"""Atomic file writes: write a temp file in the target's directory, then rename.

``os.replace`` is atomic on POSIX within one file system, so a reader (or a
crash, or Ctrl-C) never sees a half-written model, config, figure or report.
Used by training, evaluation, the gait search and the benchmarks alike.
"""

from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path


def _file_mode() -> int:
    """0o666 less the process umask: what open() would give (mkstemp gives 0o600)."""
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


@contextmanager
def atomic_path(target, suffix: str = ""):
    """Yield a temp path beside ``target``; on success rename it onto ``target``.

    ``suffix`` keeps extensions that writers insist on (SB3 appends ``.zip``
    when a model path has no suffix; matplotlib picks the format from it).
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=f".tmp{suffix}", dir=target.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, _file_mode())
        os.replace(tmp, target)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def atomic_write_text(target, text: str) -> None:
    with atomic_path(target) as tmp:
        tmp.write_text(text, encoding="utf-8")


def atomic_write_bytes(target, data: bytes) -> None:
    with atomic_path(target) as tmp:
        tmp.write_bytes(data)


def save_figure(fig, target, **savefig_kwargs) -> None:
    """``fig.savefig`` through a temp file with the target's extension."""
    suffix = Path(target).suffix or ".png"
    with atomic_path(target, suffix=suffix) as tmp:
        fig.savefig(tmp, format=suffix.lstrip("."), **savefig_kwargs)
