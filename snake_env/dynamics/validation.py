"""Input checks shared by the dynamics entry points.

Every public function of :mod:`snake_env.dynamics` rejects bad input with a
``ValueError`` that names the argument and what was expected, instead of
letting NaN or a shape error surface deep inside a recursion.
"""

from __future__ import annotations

import numbers

import numpy as np

FLOAT_DTYPES = (np.float32, np.float64)


def check_n_links(n_links) -> int:
    """Return ``n_links`` as an int; it must be an integer >= 2."""
    if isinstance(n_links, bool) or not isinstance(n_links, numbers.Integral):
        raise ValueError(f"n_links must be an integer >= 2, got {n_links!r}")
    if n_links < 2:
        raise ValueError(f"n_links must be an integer >= 2, got {n_links}")
    return int(n_links)


def per_link_parameter(name: str, value, size: int, unit: str, allow_zero: bool = False) -> np.ndarray:
    """Broadcast a scalar or length-``size`` parameter to a float64 array.

    Physical parameters must be finite and positive (or non-negative where
    ``allow_zero``, as for damping coefficients where 0 is the paper's model).
    """
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number or a sequence of {size} numbers ({unit}), got {value!r}") from None
    if arr.ndim == 0:
        arr = np.full(size, float(arr))
    elif arr.shape != (size,):
        raise ValueError(f"{name} must be a scalar or a sequence of length {size} ({unit}), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite ({unit}), got {arr.tolist()}")
    if allow_zero:
        if np.any(arr < 0):
            raise ValueError(f"{name} must be >= 0 ({unit}), got {arr.tolist()}")
    elif np.any(arr <= 0):
        raise ValueError(f"{name} must be > 0 ({unit}), got {arr.tolist()}")
    arr.setflags(write=False)
    return arr


def result_dtype(*arrays: np.ndarray) -> np.dtype:
    """float32 only if every input is float32; float64 otherwise."""
    if all(a.dtype == np.float32 for a in arrays):
        return np.dtype(np.float32)
    return np.dtype(np.float64)


def state_array(name: str, value, trailing: int) -> np.ndarray:
    """Return ``value`` as a float array of shape (..., trailing), finite.

    float32 input stays float32 (the paper's single-precision runs, Figs. 4-5);
    anything else becomes float64.
    """
    arr = np.asarray(value)
    if arr.dtype not in FLOAT_DTYPES:
        if arr.dtype.kind not in "biuf":
            raise ValueError(f"{name} must be a real numeric array of shape (..., {trailing}), got dtype {arr.dtype}")
        arr = arr.astype(np.float64)
    if arr.ndim == 0 or arr.shape[-1] != trailing:
        raise ValueError(f"{name} must have shape (..., {trailing}), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite (no NaN or inf)")
    return arr


def check_choice(name: str, value, allowed) -> str:
    if value not in allowed:
        raise ValueError(f"{name} must be one of {sorted(allowed)}, got {value!r}")
    return value
