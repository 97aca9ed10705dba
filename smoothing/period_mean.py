"""The FIFO's optional pre-filter as a pure step: the mean of the last M samples of a stream.

docs/method.md §5.1, step 1, option: instead of the latest 100 Hz IK sample, the FIFO may take
the average of the M samples of the last uplink period (M = 25). A ring of the last M samples
is kept; a sample that is not finite repeats the previous one, so the mean never turns NaN.
:class:`~telesmooth.systems.period_mean.PeriodMean` is the thin Drake system around
:func:`period_mean_step`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["PeriodMeanState", "period_mean", "period_mean_initial_state", "period_mean_step"]


class PeriodMeanState(NamedTuple):
    """The last M samples (a ring, oldest anywhere) and where the next one goes."""

    ring: np.ndarray             # (M, J)
    cursor: int                  # the slot the next sample replaces
    last: np.ndarray             # (J,) the last finite sample taken


def period_mean_initial_state(num_samples: int, initial_position) -> PeriodMeanState:
    """A ring of ``num_samples`` copies of ``initial_position`` (J,)."""
    q0 = np.array(initial_position, dtype=float)
    return PeriodMeanState(ring=np.tile(q0, (int(num_samples), 1)), cursor=0, last=q0.copy())


def period_mean_step(state: PeriodMeanState, sample) -> PeriodMeanState:
    """``sample`` (J,) taken into the ring (the previous one again if it is not finite)."""
    sample = np.asarray(sample, dtype=float)
    if not np.all(np.isfinite(sample)):
        sample = state.last
    ring = state.ring.copy()
    ring[state.cursor] = sample
    return PeriodMeanState(ring=ring, cursor=(state.cursor + 1) % ring.shape[0],
                           last=np.array(sample, dtype=float))


def period_mean(state: PeriodMeanState) -> np.ndarray:
    """(1/M) Σ of the ring's samples, (J,)."""
    return state.ring.mean(axis=0)
