"""Typed settings: dataclass fields that validate themselves (shared by the physics and the tasks).

A field made with :func:`setting` carries its unit, kind and bounds in its
``metadata``; :func:`check_fields` validates every such field of a frozen
dataclass, so a bad value raises ``ValueError`` with one line naming the
argument, the allowed values and the unit. :func:`split_kwargs` hands env
kwargs to the dataclasses that own them (an unknown name is a one-line error).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import field, fields

import numpy as np


def number(name, value, unit, *, minimum=None, strict=True, integer=False, maximum=None):
    """A finite real scalar (int when ``integer``) within bounds, else ValueError naming ``name``."""
    kind = numbers.Integral if integer else numbers.Real
    bound = "" if minimum is None else f" {'>' if strict else '>='} {minimum}"
    if maximum is not None:
        bound += f" and <= {maximum:g}"
    what = f"{'an integer' if integer else 'a finite number'}{bound} ({unit})"
    if isinstance(value, bool) or not isinstance(value, kind) or not math.isfinite(value):
        raise ValueError(f"{name} must be {what}, got {value!r}")
    if minimum is not None and (value <= minimum if strict else value < minimum):
        raise ValueError(f"{name} must be {what}, got {value!r}")
    if maximum is not None and value > maximum:
        raise ValueError(f"{name} must be {what}, got {value!r}")
    return int(value) if integer else float(value)


def flag(name, value):
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def setting(default, unit, kind="real", *, minimum=None, strict=True, maximum=None, doc=""):
    """A dataclass field whose metadata drives :func:`check_fields`.

    kind: "real", "int", "bool", "optional_real" (None allowed), "per_link"
    (scalar or length-n sequence, checked by :class:`SnakeModel`), "mapping" (checked by the
    dataclass that owns it), "choice"
    (``maximum`` then holds the allowed values) or "range" (a (low, high) pair).
    """
    return field(default=default, metadata=dict(unit=unit, kind=kind, minimum=minimum, strict=strict,
                                                maximum=maximum, doc=doc))


def check_value(name: str, value, meta: dict):
    kind = meta["kind"]
    if kind == "bool":
        return flag(name, value)
    if kind in ("per_link", "mapping"):  # validated by their owner (SnakeModel, physics.randomization)
        return value
    if kind == "choice":
        if value not in meta["maximum"]:
            raise ValueError(f"{name} must be one of {list(meta['maximum'])}, got {value!r}")
        return value
    if kind == "range":
        if not isinstance(value, (list, tuple)) or len(value) != 2:
            raise ValueError(f"{name} must be a pair [low, high] ({meta['unit']}), got {value!r}")
        low, high = (number(name, v, meta["unit"], minimum=meta["minimum"], strict=False) for v in value)
        if low > high:
            raise ValueError(f"{name} must be a pair [low, high] with low <= high ({meta['unit']}), got {value!r}")
        return (low, high)
    if kind == "optional_real" and value is None:
        return None
    unit = meta["unit"] + (", or None to disable" if kind == "optional_real" else "")
    return number(name, value, unit, minimum=meta["minimum"], strict=meta["strict"], integer=kind == "int",
                  maximum=meta["maximum"])


def check_fields(obj) -> None:
    """Validate and normalize every field of a (frozen) dataclass built with :func:`setting`."""
    for f in fields(obj):
        if f.metadata:
            object.__setattr__(obj, f.name, check_value(f.name, getattr(obj, f.name), f.metadata))


def split_kwargs(kwargs: dict, *owners) -> list[dict]:
    """Split ``kwargs`` among dataclasses by field name; an unknown name -> one-line ValueError."""
    parts = [{} for _ in owners]
    names = [{f.name for f in fields(owner)} for owner in owners]
    unknown = []
    for key, value in kwargs.items():
        for part, owned in zip(parts, names):
            if key in owned:
                part[key] = value
                break
        else:
            unknown.append(key)
    if unknown:
        valid = sorted(set().union(*names))
        raise ValueError(f"unknown argument(s) {sorted(unknown)}; valid arguments: {valid}")
    return parts
