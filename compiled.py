"""Compiled per-tick kernels: numba's ``njit`` with an on-disk cache where one can be written.

The per-tick paths of the hard limiter (:mod:`telesmooth.safety.limiter_kernel`) and of the
Online-CKS recursion (:mod:`telesmooth.smoothing.fixed_lag_kernel`) work on a few dozen floats;
in NumPy or on Python floats a tick costs a hundred microseconds or more of interpreter
overhead. Compiled, the same arithmetic costs a few.

* **Same floats.** No ``fastmath``: LLVM then keeps IEEE semantics (no reassociation, no fused
  multiply-add, no reciprocal instead of a division), so a kernel that writes the operations
  of the NumPy reference in the same order gives the same floats bit for bit (tested per
  kernel).
* **Compiled once, before the first tick.** Each kernel has one explicit signature (readonly
  arrays of any layout, so every caller's arrays match it), so it is compiled when its module
  is imported, never inside a tick, and a call with other types is an error instead of a new
  compilation. The modules that use a kernel import it when their parameters are built
  (``limiter_params``, ``OnlineCks``), not at their own import, so a command that never ticks
  does not pay for numba.
* **Cache.** numba keeps the machine code next to the source (``__pycache__``) or, where that
  is not writable, in the user's cache folder (``~/.cache/numba``; ``NUMBA_CACHE_DIR``
  overrides both). Where none of them can be written (a read-only install without a home
  folder), numba refuses to cache and the kernel is compiled in memory in every process
  instead (about a second per kernel) rather than failing.
"""

from __future__ import annotations

import numpy as np

__all__ = ["compile_kernel", "readonly_array", "readonly_copy"]


def readonly_copy(value) -> np.ndarray:
    """A read-only float64 copy of ``value``: the constant inputs of a kernel (and the
    parameters they come from), which the readonly signatures accept and nothing can change
    between ticks."""
    array = np.array(value, dtype=float)
    array.flags.writeable = False
    return array


def readonly_array(ndim: int, layout: str = "A"):
    """The numba type of a readonly float64 array of ``ndim`` dimensions, of any layout by
    default (a writable or C-contiguous array converts to it safely)."""
    from numba import types

    return types.Array(types.float64, ndim, layout, readonly=True)


def compile_kernel(signature, *, cache: bool = True):
    """Decorator: ``numba.njit(signature, cache=True)``, compiled now, or ``cache=False`` when
    numba finds no writable cache folder (it raises RuntimeError at decoration then)."""
    import numba

    def decorate(function):
        if cache:
            try:
                return numba.njit(signature, cache=True)(function)
            except RuntimeError as error:
                if "no locator available" not in str(error):
                    raise
        return numba.njit(signature, cache=False)(function)

    return decorate
