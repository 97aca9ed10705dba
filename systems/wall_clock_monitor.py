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

import time
from typing import NamedTuple

import numpy as np
from pydrake.systems.framework import LeafSystem

from telesmooth.systems.timing import check_period

__all__ = ["LatenessStatistics", "WallClockMonitor", "lateness_statistics"]


class LatenessStatistics(NamedTuple):
    """A run's ticks against the wall clock (s)."""

    ticks: int
    late_ticks: int          # later than one period
    worst_s: float           # the largest lateness
    p99_s: float
    realtime_rate: float     # simulated time / wall time over the run


def lateness_statistics(sim_t_s, wall_t_s, *, period_s: float,
                        rate: float = 1.0) -> LatenessStatistics:
    """Lateness of each tick: (wall − wall₀) − (sim − sim₀)/rate, the first tick taken as the
    start; a tick is late when its lateness exceeds ``period_s``."""
    sim_t = np.asarray(sim_t_s, dtype=float)
    wall_t = np.asarray(wall_t_s, dtype=float)
    if sim_t.size < 2:
        return LatenessStatistics(int(sim_t.size), 0, 0.0, 0.0, float("nan"))
    lateness = (wall_t - wall_t[0]) - (sim_t - sim_t[0]) / rate
    elapsed = wall_t[-1] - wall_t[0]
    return LatenessStatistics(
        ticks=int(sim_t.size), late_ticks=int(np.count_nonzero(lateness > period_s)),
        worst_s=float(max(0.0, lateness.max())),
        p99_s=float(max(0.0, np.percentile(lateness, 99))),
        realtime_rate=float((sim_t[-1] - sim_t[0]) / elapsed) if elapsed > 0 else float("nan"))


class WallClockMonitor(LeafSystem):
    r"""Records the wall-clock instant of every tick (no ports).

    .. pydrake_system::

        name: WallClockMonitor

    Publish: periodic every ``period_s`` from 0; each appends (simulated time,
    ``time.perf_counter()``) to :attr:`sim_t_s` / :attr:`wall_t_s`.
    """

    def __init__(self, period_s: float = 0.01, *, rate: float = 1.0):
        super().__init__()
        check_period("WallClockMonitor.period_s", period_s)
        self.period_s = float(period_s)
        self.rate = float(rate)
        self.sim_t_s: list[float] = []
        self.wall_t_s: list[float] = []
        self.DeclarePeriodicPublishEvent(self.period_s, 0.0, self._tick)

    def _tick(self, context) -> None:
        self.sim_t_s.append(context.get_time())
        self.wall_t_s.append(time.perf_counter())

    def statistics(self, last_s: float | None = None) -> LatenessStatistics:
        """The statistics of the run so far (``last_s``: of its last seconds only; the
        lateness still counts from the run's start)."""
        sim_t, wall_t = np.array(self.sim_t_s), np.array(self.wall_t_s)
        stats = lateness_statistics(sim_t, wall_t, period_s=self.period_s, rate=self.rate)
        if last_s is None or sim_t.size < 2:
            return stats
        keep = sim_t >= sim_t[-1] - last_s
        lateness = (wall_t - wall_t[0]) - (sim_t - sim_t[0]) / self.rate
        span = wall_t[keep][-1] - wall_t[keep][0]
        recent_rate = ((sim_t[keep][-1] - sim_t[keep][0]) / span) if span > 0 else float("nan")
        late = int(np.count_nonzero(lateness[keep] > self.period_s))
        return LatenessStatistics(
            ticks=int(keep.sum()), late_ticks=late,
            worst_s=float(max(0.0, lateness[keep].max())),
            p99_s=float(max(0.0, np.percentile(lateness[keep], 99))), realtime_rate=recent_rate)
