"""LAPACK's banded Cholesky factorisation and solve, callable from threads that run at once.

scipy's ``cholesky_banded`` and ``cho_solve_banded`` (f2py wrappers) hold the GIL for the
whole LAPACK call and copy the band to Fortran order first, so joints solved in threads
factorised one at a time (measured: two threads, 10 factorisations and 10 solves each at
n = 4·10⁵, kd = 7, took as long as one thread doing all 20). Here ``dpbtrf`` and ``dpbtrs``
are called through the function pointers scipy exports for Cython (``scipy.linalg.
cython_lapack``, the same LAPACK scipy links) with ctypes, which releases the GIL during a
foreign call, on a band stored the way LAPACK reads it without a copy.

Storage: ``band`` of shape (n, kd + 1), C-contiguous, with ``band[j, i − j] = M[i, j]`` for
j ≤ i ≤ j + kd (the lower triangle of the symmetric M, one column of M per row of ``band``).
In memory this is LAPACK's lower band layout ``AB(1 + i − j, j)`` with ``LDAB = kd + 1``,
i.e. the transpose of scipy's ``(kd + 1, n)`` lower storage.

If the function pointers cannot be had (a scipy without them), the scipy wrappers are used:
the same results, without running in parallel.
"""

from __future__ import annotations

import ctypes

import numpy as np
from scipy.linalg import LinAlgError, cho_solve_banded, cholesky_banded

__all__ = ["cholesky_lower_band", "solve_lower_band", "RELEASES_GIL"]


def _lapack_function(name: str, argument_types):
    try:
        from scipy.linalg import cython_lapack
        capsule = cython_lapack.__pyx_capi__[name]
        get_name = ctypes.pythonapi.PyCapsule_GetName
        get_name.restype = ctypes.c_char_p
        get_name.argtypes = [ctypes.py_object]
        get_pointer = ctypes.pythonapi.PyCapsule_GetPointer
        get_pointer.restype = ctypes.c_void_p
        get_pointer.argtypes = [ctypes.py_object, ctypes.c_char_p]
        address = get_pointer(capsule, get_name(capsule))
    except (ImportError, AttributeError, KeyError, ValueError):
        return None
    if not address:
        return None
    return ctypes.CFUNCTYPE(None, *argument_types)(address)


_INT = ctypes.POINTER(ctypes.c_int)
# void dpbtrf(char *uplo, int *n, int *kd, double *ab, int *ldab, int *info)
_DPBTRF = _lapack_function("dpbtrf", [ctypes.c_char_p, _INT, _INT, ctypes.c_void_p, _INT, _INT])
# void dpbtrs(char *uplo, int *n, int *kd, int *nrhs, double *ab, int *ldab, double *b,
#             int *ldb, int *info)
_DPBTRS = _lapack_function("dpbtrs", [ctypes.c_char_p, _INT, _INT, _INT, ctypes.c_void_p, _INT,
                                      ctypes.c_void_p, _INT, _INT])
RELEASES_GIL = _DPBTRF is not None and _DPBTRS is not None
"""Whether the ctypes route is in use (else the scipy wrappers)."""

_INT_MAX = 2**31 - 1


def _check_band(band) -> np.ndarray:
    band = np.asarray(band)
    if band.ndim != 2 or band.dtype != np.float64 or not band.flags.c_contiguous:
        raise ValueError("band must be a C-contiguous float64 array of shape (n, kd + 1); got "
                         f"{band.dtype} {band.shape}")
    if band.size > _INT_MAX:
        raise ValueError(f"band of shape {band.shape} is too large for 32-bit LAPACK indices")
    return band


def cholesky_lower_band(band: np.ndarray, overwrite: bool = False) -> np.ndarray:
    """Cholesky factor L (M = L Lᵀ) of the symmetric positive definite band matrix M.

    Args:
        band: (n, kd + 1) lower band storage of M (module docstring).
        overwrite: factorise ``band`` in place (saves a copy).

    Returns:
        L in the same storage.

    Raises:
        LinAlgError: M is not positive definite (the order of the failing leading minor).
    """
    band = _check_band(band)
    factor = band if overwrite else band.copy()
    n, width = factor.shape
    if _DPBTRF is None:
        factor[...] = cholesky_banded(factor.T, lower=True, check_finite=False).T
        return factor
    info = ctypes.c_int(0)
    _DPBTRF(b"L", ctypes.byref(ctypes.c_int(n)), ctypes.byref(ctypes.c_int(width - 1)),
            factor.ctypes.data, ctypes.byref(ctypes.c_int(width)), ctypes.byref(info))
    if info.value > 0:
        raise LinAlgError(f"{info.value}-th leading minor not positive definite")
    if info.value < 0:
        raise ValueError(f"dpbtrf: illegal value in argument {-info.value}")
    return factor


def solve_lower_band(factor: np.ndarray, rhs) -> np.ndarray:
    """x with L Lᵀ x = rhs, L from :func:`cholesky_lower_band`; rhs (n,) is not changed."""
    factor = _check_band(factor)
    n, width = factor.shape
    x = np.array(rhs, dtype=np.float64, order="C")
    if x.shape != (n,):
        raise ValueError(f"rhs must have shape ({n},); got {x.shape}")
    if _DPBTRS is None:
        return cho_solve_banded((factor.T, True), x, check_finite=False)
    info = ctypes.c_int(0)
    size = ctypes.c_int(n)
    _DPBTRS(b"L", ctypes.byref(size), ctypes.byref(ctypes.c_int(width - 1)),
            ctypes.byref(ctypes.c_int(1)), factor.ctypes.data, ctypes.byref(ctypes.c_int(width)),
            x.ctypes.data, ctypes.byref(size), ctypes.byref(info))
    if info.value != 0:
        raise ValueError(f"dpbtrs: illegal value in argument {-info.value}")
    return x
