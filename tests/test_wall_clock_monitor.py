"""How a live run's timing is measured (systems/wall_clock_monitor.py): the lateness of each
tick against hand-made wall clocks. Each test's comment says which wrong implementation it
catches."""

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from telesmooth.systems.wall_clock_monitor import WallClockMonitor, lateness_statistics

# Five ticks 10 ms apart in simulated time; the wall clock runs from 100 s with the third tick
# 15 ms late and the fifth 25 ms late (lateness 0, 0, 15, 5, 25 ms: two later than a period).
SIM = [0.0, 0.01, 0.02, 0.03, 0.04]
WALL = [100.0, 100.01, 100.035, 100.035, 100.065]


def test_lateness_statistics_by_hand():
    # Catches: lateness from wall time 0 instead of the first tick, a late tick at exactly
    # one period, the worst or the rate from the wrong end.
    stats = lateness_statistics(SIM, WALL, period_s=0.01)
    assert stats.ticks == 5
    assert stats.late_ticks == 2
    assert stats.worst_s == pytest.approx(0.025, abs=1e-9)
    # 99th percentile of (0, 0, 5, 15, 25) ms, linear: 15 + 0.96 · 10 = 24.6 ms.
    assert stats.p99_s == pytest.approx(0.0246, abs=1e-9)
    assert stats.realtime_rate == pytest.approx(0.04 / 0.065, rel=1e-9)


def test_lateness_at_another_rate_counts_simulated_time_divided_by_the_rate():
    # Catches: the target rate ignored (a run at 2× would be "early" all the time).
    sim = [0.0, 0.02, 0.04]
    wall = [5.0, 5.01, 5.04]              # at 2×: due at 5.00, 5.01, 5.02 → 0, 0, 20 ms late
    stats = lateness_statistics(sim, wall, period_s=0.01, rate=2.0)
    assert stats.late_ticks == 1
    assert stats.worst_s == pytest.approx(0.02, abs=1e-9)


def test_fewer_than_two_ticks_have_no_rate():
    # Catches: a division by zero or a made-up rate before the run has a span.
    stats = lateness_statistics([0.0], [1.0], period_s=0.01)
    assert (stats.ticks, stats.late_ticks, stats.worst_s) == (1, 0, 0.0)
    assert np.isnan(stats.realtime_rate)


class ScriptedClock:
    """The wall clock: each call returns the next instant of ``WALL``."""

    def __init__(self, instants):
        self.instants = list(instants)
        self.calls = 0

    def __call__(self):
        self.calls += 1
        return self.instants[self.calls - 1]


def test_the_monitor_records_each_tick_and_counts_late_ones_as_it_goes():
    # Catches: ticks at the wrong instants (offset, period), the running late count differing
    # from the statistics of the whole run, a window that restarts the lateness at its start.
    monitor = WallClockMonitor(0.01, clock=ScriptedClock(WALL))
    simulator = Simulator(monitor)
    simulator.AdvanceTo(0.045)
    np.testing.assert_allclose(monitor.sim_t_s, SIM, rtol=0, atol=1e-12)
    assert monitor.wall_t_s == WALL
    assert monitor.late_ticks == 2
    assert monitor.statistics() == lateness_statistics(SIM, WALL, period_s=0.01)
    # The last 10 ms of simulated time: the ticks at 0.03 and 0.04 s, lateness 5 and 25 ms
    # counted from the run's start (not 0 and 20 from the window's).
    recent = monitor.statistics(last_s=0.01)
    assert recent.ticks == 2 and recent.late_ticks == 1
    assert recent.worst_s == pytest.approx(0.025, abs=1e-9)
    assert recent.realtime_rate == pytest.approx(0.01 / 0.03, rel=1e-9)



def test_the_session_writes_each_ticks_lateness_and_says_the_period(tmp_path):
    # Catches: ticks.csv with the lateness counted from wall time 0 or from each tick's
    # predecessor, a report line that names another period than the monitor's.
    import csv

    from telesmooth.scripts.teleop_report import _session_timing, _timing_text, _write_timing

    monitor = WallClockMonitor(0.01, clock=ScriptedClock(WALL))
    Simulator(monitor).AdvanceTo(0.045)
    figures = _write_timing(tmp_path, monitor)
    assert [name for _, name in figures] == ["timing.png"]
    assert (tmp_path / "timing.png").stat().st_size > 0
    with open(tmp_path / "ticks.csv") as handle:
        rows = list(csv.DictReader(handle))
    np.testing.assert_allclose([float(r["wall_s"]) for r in rows],
                               [0.0, 0.01, 0.035, 0.035, 0.065], rtol=0, atol=1e-9)
    np.testing.assert_allclose([float(r["lateness_s"]) for r in rows],
                               [0.0, 0.0, 0.015, 0.005, 0.025], rtol=0, atol=1e-9)
    text = _timing_text(_session_timing(monitor))
    assert "2 of 5 haptic ticks ran more than one period (10 ms) late" in text
    assert "the latest by 25.0 ms" in text
    assert _write_timing(tmp_path / "none", None) == []
