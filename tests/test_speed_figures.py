"""The speed figures ``simulate`` and the bench print are measured over the window they name.

The run's wall and CPU time cover the simulator's advance alone (the window the bare plant's
rows of the bench measure, so the two compare); the bench's "whole call" adds the diagram's
build and reading the logs back. Each test plants a known amount of CPU work inside and
outside the window and checks that exactly the work inside is counted. The planted work
spends at least its amount on both clocks, so the lower bounds hold; the upper bound is on CPU
time of this process (``time.process_time``), which another process on the machine cannot
inflate, so it holds on a busy machine too.
"""

from __future__ import annotations

import time
from types import SimpleNamespace

import pytest

import telesmooth.diagrams.simulation as simulation
import telesmooth.scripts.bench_core as bench_core
from telesmooth.diagrams.scenario import load_scenario


def _burn_cpu(seconds: float) -> None:
    """Spends at least ``seconds`` of this process's CPU time *and* of wall time.

    Both, because neither bounds the other: on a busy machine the wall clock outruns this
    process's CPU time, and while another thread of this process runs (pytest-xdist's, a BLAS
    pool's) the process's CPU time outruns the wall clock (by 76 µs in 0.2 s on a CI run).
    """
    cpu_end, wall_end = time.process_time() + seconds, time.perf_counter() + seconds
    while time.process_time() < cpu_end or time.perf_counter() < wall_end:
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


def test_the_simulation_table_puts_each_figure_under_its_own_header():
    bare = {"arm": "space_arm", "time_step_s": 0.0, "simulated_s": 20.0, "wall_s": 0.25,
            "real_time_factor": 80.0, "real_time_factor_cpu": 79.0, "peak_rss_mb": 200.0}
    chain = {"scenario": "OneOfEverything", "arm": "space_arm", "time_step_s": 0.0,
             **bench_core.chain_speed(9.0, 0.5, 0.45, 0.8, 0.75),
             "over_bare_plant_continuous": 0.9 / 79.0 * 20.0, "peak_rss_mb": 316.0,
             "instrumented_cpu_s": 0.5, "stage_share": {}, "stage_cpu_s": {}, "drake_cpu_s": 0.3}
    text = bench_core._table([], [], {"bare_plant": [bare], "chain": [chain]})
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("| what |"))
    rows = lines[start:start + 4]
    del rows[1]     # the separator
    assert all(line.startswith("| ") for line in rows)
    header = [cell.strip() for cell in rows[0].strip("|").split("|")]
    for line in rows[1:3]:
        cells = dict(zip(header, (c.strip() for c in line.strip("|").split("|")), strict=True))
        if cells["what"].startswith("`telesmooth simulate`"):
            assert cells["×real time"] == "18.0" and cells["×real time (CPU)"] == "20.0"
            assert cells["whole call [s]"] == "0.80"
            assert cells["×real time (whole call)"] == "11.2"
        else:
            assert cells["×real time"] == "80.0" and cells["×real time (CPU)"] == "79.0"
            assert cells["whole call [s]"] == "–"
        assert cells["peak [MB]"] in ("200", "316")
