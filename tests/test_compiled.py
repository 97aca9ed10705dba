"""compiled.py: numba kernels with an on-disk cache, and without one where none is writable."""

from __future__ import annotations

import numpy as np


def _twice(values):
    total = 0.0
    for value in values:
        total += 2.0 * value
    return total


def _signature():
    from numba import types

    from telesmooth.compiled import readonly_array

    return types.float64(readonly_array(1))


def test_a_kernel_without_a_writable_cache_folder_is_compiled_in_memory(monkeypatch):
    """numba raises at decoration when no cache folder can be written (a read-only install
    without a home folder): the kernel is then compiled without a cache, and works."""
    from numba.core import caching

    from telesmooth.compiled import compile_kernel

    def read_only(self):
        raise PermissionError(30, "Read-only file system")

    monkeypatch.setattr(caching._CacheLocator, "ensure_cache_path", read_only)
    kernel = compile_kernel(_signature())(_twice)
    assert kernel._cache.__class__.__name__ == "NullCache"
    values = np.arange(4.0)
    values.flags.writeable = False
    assert kernel(values) == 12.0


def test_a_kernel_is_cached_where_a_folder_is_writable(monkeypatch, tmp_path):
    from numba.core import config

    from telesmooth.compiled import compile_kernel

    monkeypatch.setattr(config, "CACHE_DIR", str(tmp_path))
    kernel = compile_kernel(_signature())(_twice)
    assert kernel(np.arange(3.0)) == 6.0
    assert list(tmp_path.rglob("*.nbi")), "no cache index written"
    # An explicit signature: another type is an error, never a compilation inside a tick.
    try:
        kernel(np.arange(3))
    except TypeError:
        pass
    else:
        raise AssertionError("an int64 array was accepted")
