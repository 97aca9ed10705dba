"""The package's finite differences (``telesmooth.safety.finite_differences``) against closed
forms: backward differences of a cubic are exact polynomials, and the tick form and the
sequence form are the same differences up to rounding."""

import numpy as np
import pytest

from telesmooth.safety.finite_differences import (
    fd_acceleration,
    fd_jerk,
    fd_state,
    fd_velocity,
    finite_differences,
)

DT = 0.25
C = np.array([0.3, -1.2, 0.7, 0.4])   # p(t) = c0 + c1 t + c2 t² + c3 t³


def _p(t):
    return C[0] + C[1] * t + C[2] * t**2 + C[3] * t**3


@pytest.mark.parametrize("k", [3, 4, 10])
def test_the_tick_form_of_a_cubic_is_its_backward_difference_in_closed_form(k):
    t = DT * np.arange(k - 3, k + 1)
    p3, p2, p1, p0 = _p(t)
    tk = t[-1]
    # Backward differences of a cubic, expanded by hand: ∇p/Δt, ∇²p/Δt², ∇³p/Δt³.
    velocity = C[1] + C[2] * (2 * tk - DT) + C[3] * (3 * tk**2 - 3 * tk * DT + DT**2)
    acceleration = 2 * C[2] + C[3] * (6 * tk - 6 * DT)
    np.testing.assert_allclose(fd_velocity(p1, p0, DT), velocity, rtol=1e-12)
    np.testing.assert_allclose(fd_acceleration(p2, p1, p0, DT), acceleration, rtol=1e-10)
    np.testing.assert_allclose(fd_jerk(p3, p2, p1, p0, DT), 6 * C[3], rtol=1e-9)
    v, a = fd_state(np.array([[p2], [p1], [p0]]), DT)
    # The history's newest two differences: the same closed forms at t_k.
    np.testing.assert_allclose([v[0], a[0]], [velocity, acceleration], rtol=1e-10)


def test_the_sequence_form_is_the_tick_form_at_every_sample_up_to_rounding():
    rng = np.random.default_rng(1)
    p = np.cumsum(rng.normal(scale=0.01, size=(40, 3)), axis=0)
    for order, tick in ((1, lambda w: fd_velocity(w[-2], w[-1], DT)),
                        (2, lambda w: fd_acceleration(w[-3], w[-2], w[-1], DT)),
                        (3, lambda w: fd_jerk(w[-4], w[-3], w[-2], w[-1], DT))):
        sequence = finite_differences(p, DT, order)
        assert sequence.shape == (40 - order, 3)
        at_ticks = np.array([tick(p[k - order:k + 1]) for k in range(order, 40)])
        np.testing.assert_allclose(sequence, at_ticks, rtol=0,
                                   atol=64 * np.finfo(float).eps * np.abs(p).max() / DT**order)
