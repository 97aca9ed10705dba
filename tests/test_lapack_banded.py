"""The ctypes route to LAPACK's banded Cholesky: against scipy's wrappers and a dense solve."""

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
from scipy.linalg import LinAlgError, cholesky_banded

from telesmooth.smoothing import lapack_banded
from telesmooth.smoothing.lapack_banded import cholesky_lower_band, solve_lower_band


def _random_band(n, kd, seed):
    """A random SPD band matrix: its lower storage (n, kd + 1) and the dense matrix."""
    rng = np.random.default_rng(seed)
    dense = np.zeros((n, n))
    for offset in range(1, kd + 1):
        values = rng.uniform(-1.0, 1.0, n - offset)
        dense += np.diag(values, -offset) + np.diag(values, offset)
    dense += np.diag(np.abs(dense).sum(axis=1) + rng.uniform(0.1, 1.0, n))
    band = np.zeros((n, kd + 1))
    for offset in range(kd + 1):
        band[: n - offset, offset] = np.diag(dense, -offset)
    return band, dense


def test_the_ctypes_route_is_in_use():
    # scipy >= 0.16 exports the function pointers; without them the speed-up is lost.
    assert lapack_banded.RELEASES_GIL


@pytest.mark.parametrize("n, kd", [(1, 0), (5, 2), (40, 7), (97, 12), (300, 13)])
def test_factor_and_solve_against_scipy_and_a_dense_solve(n, kd):
    band, dense = _random_band(n, kd, seed=n + kd)
    factor = cholesky_lower_band(band)
    expected = cholesky_banded(band.T, lower=True)
    np.testing.assert_allclose(factor, expected.T, rtol=1e-13, atol=1e-13)
    # The factor reproduces the matrix: L Lᵀ = M.
    lower = np.zeros((n, n))
    for offset in range(kd + 1):
        lower += np.diag(factor[: n - offset, offset], -offset)
    np.testing.assert_allclose(lower @ lower.T, dense, rtol=1e-12, atol=1e-12)
    rhs = np.random.default_rng(1).standard_normal(n)
    x = solve_lower_band(factor, rhs)
    np.testing.assert_allclose(x, np.linalg.solve(dense, rhs), rtol=1e-10, atol=1e-12)
    np.testing.assert_array_equal(band, _random_band(n, kd, seed=n + kd)[0])   # not changed


def test_overwrite_factorises_in_place():
    band, _ = _random_band(50, 4, seed=3)
    copy = band.copy()
    factor = cholesky_lower_band(band, overwrite=True)
    assert factor is band
    np.testing.assert_array_equal(factor, cholesky_lower_band(copy))


def test_not_positive_definite_raises_with_the_minor():
    band, _ = _random_band(20, 3, seed=4)
    band[7, 0] = -100.0
    with pytest.raises(LinAlgError, match="8-th leading minor"):
        cholesky_lower_band(band)


@pytest.mark.parametrize("bad", [np.zeros((4, 3), dtype=np.float32), np.zeros((3, 4)).T,
                                 np.zeros(5)])
def test_band_layout_is_checked(bad):
    with pytest.raises(ValueError, match="C-contiguous float64"):
        cholesky_lower_band(bad)


def test_rhs_shape_is_checked():
    factor = cholesky_lower_band(_random_band(6, 1, seed=5)[0])
    with pytest.raises(ValueError, match=r"rhs must have shape \(6,\)"):
        solve_lower_band(factor, np.ones(5))


def test_threads_give_the_same_results():
    bands = [_random_band(2000, 7, seed=s)[0] for s in range(4)]
    rhs = np.ones(2000)

    def work(band):
        return solve_lower_band(cholesky_lower_band(band), rhs)

    alone = [work(band) for band in bands]
    with ThreadPoolExecutor(max_workers=4) as pool:
        together = list(pool.map(work, bands * 5))
    for i, x in enumerate(together):
        np.testing.assert_array_equal(x, alone[i % 4])


def test_the_scipy_fallback_gives_the_same_results(monkeypatch):
    band, _ = _random_band(200, 7, seed=6)
    rhs = np.linspace(-1.0, 1.0, 200)
    factor = cholesky_lower_band(band)
    x = solve_lower_band(factor, rhs)
    monkeypatch.setattr(lapack_banded, "_DPBTRF", None)
    monkeypatch.setattr(lapack_banded, "_DPBTRS", None)
    fallback = cholesky_lower_band(band)
    np.testing.assert_allclose(fallback, factor, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(solve_lower_band(fallback, rhs), x, rtol=1e-12, atol=1e-14)
    band[0, 0] = -1.0
    with pytest.raises(LinAlgError):
        cholesky_lower_band(band)
