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
from telesmooth.diagrams.scenario import LoadScenario


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
    real_build, real_simulator = simulation.MakeTeleoperationDiagram, simulation.MakeSimulator

    def slow_build(*args, **kwargs):
        _burn_cpu(build_burn_s)
        return real_build(*args, **kwargs)

    def slow_simulator(*args, **kwargs):
        slow.append(_SlowAdvance(real_simulator(*args, **kwargs), advance_burn_s))
        return slow[-1]

    monkeypatch.setattr(simulation, "MakeTeleoperationDiagram", slow_build)
    monkeypatch.setattr(simulation, "MakeSimulator", slow_simulator)
    scenario = LoadScenario(scenario_name="Defaults")
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


def test_each_chain_row_runs_its_chain_and_is_set_over_the_bare_plant_of_its_arm(monkeypatch):
    """Every scenario is timed through the deployed chain (``simulate``'s default) and the
    paper's, each row over the bare plant of its arm and plant step measured in the same run:
    planted figures, known ratios (the deployed Defaults run: 8 s simulated in 0.5 s wall,
    0.4 s CPU, against a bare plant at 400× wall and 500× CPU: 16 / 400 = 0.04 and
    20 / 500 = 0.04)."""
    outside_s = 0.05
    seen = []
    timings = {"deployed": (0.5, 0.4), "paper": (0.25, 0.2)}

    def fake_simulate(scenario, duration_s=None):
        _burn_cpu(outside_s)
        seen.append((scenario.arm, scenario.chain))
        wall, cpu = timings[scenario.chain]
        return SimpleNamespace(duration_s=8.0, wall_time_s=wall, cpu_time_s=cpu)

    bare_factors = {("air_bearing_arm", 0.0): (400.0, 500.0),
                    ("space_arm", 0.0): (100.0, 125.0)}

    def fake_bare(arm, time_step_s, duration_s):
        wall, cpu = bare_factors.get((arm, time_step_s), (1000.0, 1000.0))
        return {"arm": arm, "time_step_s": time_step_s,
                **bench_core._run_speed(duration_s, duration_s / wall, duration_s / cpu)}

    def fake_shares(name, duration_s, chain):
        return {"python_s": {}, "calls": {}, "drake_s": 0.1, "cpu_s": 0.1}

    monkeypatch.setattr(simulation, "simulate", fake_simulate)
    monkeypatch.setattr(bench_core, "_bare_plant_cell", fake_bare)
    monkeypatch.setattr(bench_core, "_chain_shares_cell", fake_shares)
    monkeypatch.setattr(bench_core, "in_fresh_process",
                        lambda function, *args: {**function(*args), "peak_rss_mb": 1.0})
    result = bench_core.bench_simulation(None, bare_duration_s=20.0)
    rows = result["chain"]
    assert [(r["scenario"], r["chain"]) for r in rows] == [
        ("Defaults", "deployed"), ("Defaults", "paper"),
        ("OneOfEverything", "deployed"), ("OneOfEverything", "paper")]
    assert seen == [("air_bearing_arm", "deployed"), ("air_bearing_arm", "paper"),
                    ("space_arm", "deployed"), ("space_arm", "paper")]
    expected = {("Defaults", "deployed"): (16.0 / 400, 20.0 / 500),
                ("Defaults", "paper"): (32.0 / 400, 40.0 / 500),
                ("OneOfEverything", "deployed"): (16.0 / 100, 20.0 / 125),
                ("OneOfEverything", "paper"): (32.0 / 100, 40.0 / 125)}
    for row in rows:
        wall, cpu = expected[(row["scenario"], row["chain"])]
        assert row["over_bare_plant_wall"] == pytest.approx(wall, rel=1e-12)
        assert row["over_bare_plant_cpu"] == pytest.approx(cpu, rel=1e-12)
        assert row["call_wall_s"] >= outside_s      # the planted build: the whole call only
    # The printed table: each ratio under its header, each chain on its own row.
    lines = bench_core._table([], [], result).splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("| what |"))
    header = [cell.strip() for cell in lines[start].strip("|").split("|")]
    printed = {}
    for line in lines[start + 2:]:
        if not line.startswith("| "):
            break
        cells = dict(zip(header, (c.strip() for c in line.strip("|").split("|")), strict=True))
        printed[(cells["what"], cells["chain"])] = cells
    deployed = printed[("`telesmooth simulate`, Defaults (air_bearing_arm)", "deployed")]
    assert deployed["chain / bare plant"] == "0.04"
    assert deployed["chain / bare plant (CPU)"] == "0.04"
    assert deployed["×real time"] == "16.0"
    paper = printed[("`telesmooth simulate`, OneOfEverything (space_arm)", "paper")]
    assert paper["chain / bare plant"] == "0.32" and paper["chain / bare plant (CPU)"] == "0.32"
    bare = printed[("bare plant, space_arm", "–")]
    assert bare["×real time"] == "100.0" and bare["chain / bare plant"] == "–"


def test_over_bare_plant_known_ratios():
    chain = bench_core.chain_speed(10.0, 0.5, 0.4, 2.0, 1.9)          # 20× wall, 25× CPU
    bare = bench_core._run_speed(20.0, 0.05, 0.04)                     # 400× wall, 500× CPU
    assert bench_core.over_bare_plant(chain, bare) == pytest.approx(
        {"over_bare_plant_wall": 0.05, "over_bare_plant_cpu": 0.05}, rel=1e-12)
