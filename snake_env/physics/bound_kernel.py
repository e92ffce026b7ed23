"""A compiled kernel bound to fixed arguments and called without numba's per-call dispatch.

On every call numba's dispatcher types each argument to pick the compiled version to run: about 0.1 us an
argument, and about 1 us for the physics step's nine (a tuple of 13 model arrays among them), of a
single-env step of ~12 us. The envs call their kernels on their own buffers, which they fill in place and
never replace, so the version can be picked once: :class:`BoundKernel` does so on its first call (which
compiles the version or loads it from the cache, at the point the caller's first call would have) and
afterwards calls that version directly. The same compiled code runs, so the results are the same bits.
"""

from __future__ import annotations

import functools

__all__ = ["BoundKernel"]


class BoundKernel:
    """``kernel(*args)`` as ``bound.call()``, for ``args`` that stay the same objects, of the same types,
    on every call (arrays the caller owns and updates in place; numbers fixed for its lifetime). Passing
    arrays that are later replaced, or of another type, is a bug: the version picked reads them as the
    first call's types."""

    __slots__ = ("call",)

    def __init__(self, kernel, *args):
        def first_call():
            version = kernel.compile(tuple(kernel.typeof_pyval(arg) for arg in args))
            self.call = functools.partial(version, *args)
            return self.call()

        self.call = first_call
