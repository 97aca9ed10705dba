"""How a live run keeps up with the wall clock: each tick's lateness, measured as it happens.

A live run (``telesmooth teleop``) paces its Simulator to the wall clock
(``set_target_realtime_rate``): the Simulator waits when it is ahead, but nothing makes it
catch up when it falls behind. :class:`WallClockMonitor` publishes every ``period_s`` (the
haptic rate) and records, for each tick, how late it ran: the wall-clock time elapsed since
the run's start minus the tick's simulated time (divided by the target rate). A tick is
*late* when that exceeds one period: the operator's input and the display were then older
than the chain's own rate. :func:`lateness_statistics` summarises a run (the pure part).
"""

from __future__ import annotations

import bisect
import time
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from pydrake.systems.framework import LeafSystem

from telesmooth.systems.timing import check_period

__all__ = ["LatenessStatistics", "WallClockMonitor", "lateness", "lateness_statistics"]


class LatenessStatistics(NamedTuple):
    """A run's ticks against the wall clock (s)."""

    ticks: int
    late_ticks: int          # later than one period
    worst_s: float           # the largest lateness
    p99_s: float
    realtime_rate: float     # simulated time / wall time over the run


def lateness(sim_t, wall_t, sim_start: float, wall_start: float, rate: float = 1.0):
    """How late ticks ran, s: (wall − wall₀) − (sim − sim₀)/rate, from the run's first tick
    (sim₀, wall₀); a number or an array, as ``sim_t`` and ``wall_t``."""
    return (wall_t - wall_start) - (sim_t - sim_start) / rate


def _statistics(sim_t: np.ndarray, wall_t: np.ndarray, late: np.ndarray,
                period_s: float) -> LatenessStatistics:
    """The statistics of ticks (≥ 2) whose lateness is ``late``; the rate over their span."""
    span = wall_t[-1] - wall_t[0]
    return LatenessStatistics(
        ticks=int(sim_t.size), late_ticks=int(np.count_nonzero(late > period_s)),
        worst_s=float(max(0.0, late.max())),
        p99_s=float(max(0.0, np.percentile(late, 99))),
        realtime_rate=float((sim_t[-1] - sim_t[0]) / span) if span > 0 else float("nan"))


def lateness_statistics(sim_t_s, wall_t_s, *, period_s: float,
                        rate: float = 1.0) -> LatenessStatistics:
    """Lateness of each tick (:func:`lateness`), the first tick taken as the start; a tick is
    late when its lateness exceeds ``period_s``."""
    sim_t = np.asarray(sim_t_s, dtype=float)
    wall_t = np.asarray(wall_t_s, dtype=float)
    if sim_t.size < 2:
        return LatenessStatistics(int(sim_t.size), 0, 0.0, 0.0, float("nan"))
    return _statistics(sim_t, wall_t, lateness(sim_t, wall_t, sim_t[0], wall_t[0], rate),
                       period_s)


class WallClockMonitor(LeafSystem):
    r"""Records the wall-clock instant of every tick (no ports).

    .. pydrake_system::

        name: WallClockMonitor

    Publish: periodic every ``period_s`` from 0; each appends (simulated time, ``clock()``,
    by default ``time.perf_counter()``) to :attr:`sim_t_s` / :attr:`wall_t_s` and counts the
    tick in :attr:`late_ticks` if it was late. A live run asks for the statistics several
    times a second; :attr:`late_ticks` and ``statistics(last_s=...)`` cost the same in the
    first minute and after an hour (they do not go over the whole run).
    """

    def __init__(self, period_s: float = 0.01, *, rate: float = 1.0,
                 clock: Callable[[], float] = time.perf_counter):
        super().__init__()
        check_period("WallClockMonitor.period_s", period_s)
        self.period_s = float(period_s)
        self.rate = float(rate)
        self._clock = clock
        self.sim_t_s: list[float] = []
        self.wall_t_s: list[float] = []
        self.late_ticks = 0
        self.DeclarePeriodicPublishEvent(self.period_s, 0.0, self._tick)

    def _tick(self, context) -> None:
        sim_t, wall_t = context.get_time(), self._clock()
        self.sim_t_s.append(sim_t)
        self.wall_t_s.append(wall_t)
        if lateness(sim_t, wall_t, self.sim_t_s[0], self.wall_t_s[0], self.rate) \
                > self.period_s:
            self.late_ticks += 1

    def statistics(self, last_s: float | None = None) -> LatenessStatistics:
        """The statistics of the run so far (``last_s``: of the ticks of its last ``last_s``
        simulated seconds only; their lateness still counts from the run's start)."""
        if last_s is None or len(self.sim_t_s) < 2:
            return lateness_statistics(self.sim_t_s, self.wall_t_s, period_s=self.period_s,
                                       rate=self.rate)
        first = bisect.bisect_left(self.sim_t_s, self.sim_t_s[-1] - last_s)
        sim_t, wall_t = np.array(self.sim_t_s[first:]), np.array(self.wall_t_s[first:])
        return _statistics(sim_t, wall_t, lateness(sim_t, wall_t, self.sim_t_s[0],
                                                   self.wall_t_s[0], self.rate), self.period_s)
