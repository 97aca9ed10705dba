"""Backward finite differences of sent positions: the velocity, acceleration and jerk the
limits are stated on (docs/method.md §4: v_k = (p_k − p_{k−1})/Δt, a_k = (p_k − 2p_{k−1} +
p_{k−2})/Δt², u_k = (p_k − 3p_{k−1} + 3p_{k−2} − p_{k−3})/Δt³).

Two forms of the same differences, which agree to rounding (a few ulps of |p|/Δt^order):

* at one tick, from the last samples with the binomial weights (:func:`fd_velocity`,
  :func:`fd_acceleration`, :func:`fd_jerk`, :func:`fd_state`): what the hard limiter, the stop
  planner, the link guard, the reduced-Q trigger and the online smoother compute each tick;
* over a whole sequence, as differences of differences (:func:`finite_differences`, numpy's
  ``diff``): what the metrics and reports compute of a run.

Every FD in the package is one of these (the limiter's compiled tick,
:mod:`telesmooth.safety.limiter_kernel`, writes the tick form inline for its compiler).
"""

from __future__ import annotations

import numpy as np

__all__ = ["fd_acceleration", "fd_jerk", "fd_state", "fd_velocity", "finite_differences"]


def fd_velocity(p1, p0, dt_s: float):
    """(p_k − p_{k−1})/Δt of the newest sample ``p0`` = p_k and ``p1`` = p_{k−1}."""
    return (p0 - p1) / dt_s


def fd_acceleration(p2, p1, p0, dt_s: float):
    """(p_k − 2p_{k−1} + p_{k−2})/Δt² of ``p2, p1, p0`` = p_{k−2}, p_{k−1}, p_k."""
    return (p0 - 2.0 * p1 + p2) / dt_s**2


def fd_jerk(p3, p2, p1, p0, dt_s: float):
    """(p_k − 3p_{k−1} + 3p_{k−2} − p_{k−3})/Δt³ of ``p3, p2, p1, p0`` = p_{k−3} … p_k."""
    return (p0 - 3.0 * p1 + 3.0 * p2 - p3) / dt_s**3


def fd_state(history, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(v, a) of the history [p_{k−3}, p_{k−2}, p_{k−1}] (3, J): rad/s, rad/s²."""
    h = np.asarray(history, dtype=float)
    return fd_velocity(h[1], h[2], dt_s), fd_acceleration(h[0], h[1], h[2], dt_s)


def finite_differences(positions, dt_s: float, order: int) -> np.ndarray:
    """Order-1/2/3 finite differences along axis 0, divided by Δt^order, shape (N−order, …)."""
    return np.diff(np.asarray(positions, dtype=float), n=order, axis=0) / dt_s**order
