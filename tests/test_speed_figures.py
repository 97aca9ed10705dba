"""The speed figures ``simulate`` and the bench print are measured over the window they name.

The run's wall and CPU time cover the simulator's advance alone (the window the bare plant's
rows of the bench measure, so the two compare); the bench's "whole call" adds the diagram's
build and reading the logs back. Each test plants a known amount of CPU work inside and
outside the window and checks that exactly the work inside is counted. CPU time of this
process (``time.process_time``) is what another process on the machine cannot inflate, so the
bounds hold on a busy machine; wall time is only ever bounded from below by it.
"""

from __future__ import annotations

import time
from types import SimpleNamespace

import pytest

import telesmooth.diagrams.simulation as simulation
import telesmooth.scripts.bench_core as bench_core
from telesmooth.diagrams.scenario import load_scenario


def _burn_cpu(seconds: float) -> None:
    """Spends at least ``seconds`` of this process's CPU time."""
    end = time.process_time() + seconds
    while time.process_time() < end:
        pass


class _SlowAdvance:
    """A Simulator whose every AdvanceTo spends ``burn_s`` of CPU first."""

    def __init__(self, simulator, burn_s):
        self._simulator, self._burn_s, self.calls = simulator, burn_s, 0

    def AdvanceTo(self, t):  # noqa: N802 (Drake's name)
        self.calls += 1
        _burn_cpu(self._burn_s)
        return self._simulator.AdvanceTo(t)

    def __getattr__(self, name):
        return getattr(self._simulator, name)


def test_simulate_times_the_advance_and_not_the_build(monkeypatch):
    build_burn_s, advance_burn_s = 0.4, 0.03
    slow = []
    real_build, real_simulator = simulation.MakeTeleoperationDiagram, simulation.make_simulator

    def slow_build(*args, **kwargs):
        _burn_cpu(build_burn_s)
        return real_build(*args, **kwargs)

    def slow_simulator(*args, **kwargs):
        slow.append(_SlowAdvance(real_simulator(*args, **kwargs), advance_burn_s))
        return slow[-1]

    monkeypatch.setattr(simulation, "MakeTeleoperationDiagram", slow_build)
    monkeypatch.setattr(simulation, "make_simulator", slow_simulator)
    scenario = load_scenario(scenario_name="Defaults")
    cpu = time.process_time()
    record = simulation.simulate(scenario, duration_s=0.5)
    cpu = time.process_time() - cpu
    inside_s = slow[0].calls * advance_burn_s
    assert slow[0].calls == 10
    # Everything planted inside the window is counted ...
    assert record.cpu_time_s >= inside_s
    assert record.wall_time_s >= inside_s
    # ... and the build's planted work is not (it is in the call's CPU time, outside).
    assert record.cpu_time_s <= cpu - build_burn_s
    assert record.duration_s == pytest.approx(0.5)


def test_the_bench_row_divides_each_figure_by_its_own_window(monkeypatch):
    outside_s = 0.2
    record = SimpleNamespace(duration_s=8.0, wall_time_s=0.5, cpu_time_s=0.4)

    def fake_simulate(scenario, duration_s=None):
        _burn_cpu(outside_s)   # build and logs: in the whole call only
        return record

    monkeypatch.setattr(simulation, "simulate", fake_simulate)
    row = bench_core._chain_cell("Defaults", None)
    assert row["real_time_factor"] == pytest.approx(8.0 / 0.5)
    assert row["real_time_factor_cpu"] == pytest.approx(8.0 / 0.4)
    assert row["call_wall_s"] >= outside_s and row["call_cpu_s"] >= outside_s
    assert row["call_real_time_factor"] == pytest.approx(8.0 / row["call_wall_s"])
    assert row["arm"] == "air_bearing_arm" and row["scenario"] == "Defaults"


def test_chain_speed_known_figures():
    row = bench_core.chain_speed(10.0, 0.5, 0.4, 2.0, 1.9)
    assert row["real_time_factor"] == pytest.approx(20.0)
    assert row["real_time_factor_cpu"] == pytest.approx(25.0)
    assert row["call_real_time_factor"] == pytest.approx(5.0)
    assert (row["wall_s"], row["cpu_s"], row["call_wall_s"], row["call_cpu_s"]) == (
        0.5, 0.4, 2.0, 1.9)
