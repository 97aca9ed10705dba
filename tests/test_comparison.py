"""`telesmooth compare`: every method through one plant (paper Table 2).

Oracles: the Online-CKS packets equal the online chain's (the full diagram, simulated
independently); each method's packets are its smooth_recording estimate behind its delay;
e(i), P and the FD figures are recomputed from the raw arrays by hand.
"""

import csv
import json

import numpy as np
import pytest

from telesmooth.diagrams.scenario import LoadScenario
from telesmooth.diagrams.simulation import simulate, tool_positions
from telesmooth.scripts.cli import main
from telesmooth.smoothing.methods import smooth_recording
from telesmooth.studies.comparison import compare_methods, method_settings

METHODS = ("original", "kf-predictor", "offline-cks-trajectory", "bmfls", "online-cks")


@pytest.fixture(scope="module")
def scenario():
    return LoadScenario(scenario_name="OneOfEverything")


@pytest.fixture(scope="module")
def comparison(scenario):
    messages = []
    result = compare_methods(scenario, METHODS, progress=messages.append)
    assert len(messages) == len(METHODS)
    assert all(f"[{i}/{len(METHODS)}]" in m for i, m in enumerate(messages, start=1))
    return result


def test_online_cks_sends_exactly_what_the_online_chain_sends(scenario, comparison):
    record = simulate(scenario)
    assert not np.any(record.holding > 0.5)          # no collision hold in this scenario
    packets = comparison.runs["online-cks"].packets
    count = min(len(packets), record.q_sent.shape[0])
    assert count >= 30
    np.testing.assert_allclose(packets[:count], record.q_sent[:count], rtol=0, atol=1e-12)


def test_packets_are_each_estimate_behind_its_delay(scenario, comparison):
    z = comparison.q_original
    lag = scenario.smoother.lag
    for name, run in comparison.runs.items():
        base, settings = method_settings(scenario, name)
        expected = smooth_recording(z, comparison.period_s, base, settings,
                                    joint_names=comparison.joint_names).positions
        delay = lag if name in ("bmfls", "online-cks") else 0
        assert run.delay_ticks == delay, name
        np.testing.assert_allclose(run.packets[delay:], expected, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(run.packets[:delay],
                                      np.tile(comparison.q_start, (delay, 1)))
    np.testing.assert_array_equal(comparison.runs["original"].packets, z)


def test_response_errors_and_improvement_ratio_recomputed_by_hand(scenario, comparison):
    # OneOfEverything commands the robot with a zero-order hold: the response to a packet is
    # read at the end of its hold, one uplink period after it was sent.
    assert scenario.onboard.interpolator.interpolation == "zoh"
    period = comparison.period_s
    ramp = period
    sums = {}
    for name, run in comparison.runs.items():
        errors = []
        for i, q in enumerate(run.estimate):
            when = (i + run.delay_ticks) * period + ramp
            row = max(k for k, t in enumerate(run.tracker_t_s) if t <= when + 1e-9)
            commanded = tool_positions(scenario, q[None, :])[0]
            errors.append(np.linalg.norm(commanded - run.tool_position_m[row]))
        np.testing.assert_allclose(run.response_error_m, errors, rtol=1e-12, atol=1e-15)
        sums[name] = sum(errors)
    for name, run in comparison.runs.items():
        expected = 100.0 * (sums["original"] - sums[name]) / sums["original"]
        assert run.metrics["improvement_ratio_percent"] == pytest.approx(expected, abs=1e-9)
    assert comparison.runs["original"].metrics["improvement_ratio_percent"] == 0.0


def test_fd_figures_are_of_what_the_plant_receives(scenario, comparison):
    period = comparison.period_s
    a_max = np.asarray(scenario.smoother.max_acceleration_rad_per_s2, dtype=float)
    for name, run in comparison.runs.items():
        received = np.vstack([np.tile(comparison.q_start, (3, 1)), run.packets,
                              np.tile(run.packets[-1], (3, 1))])
        acc = np.array([(received[k + 1] - 2 * received[k] + received[k - 1]) / period**2
                        for k in range(1, len(received) - 1)])
        np.testing.assert_allclose(run.metrics["fd_acceleration"]["max_over_limit"],
                                   np.abs(acc).max(axis=0) / a_max, rtol=1e-9, err_msg=name)
    # The hard finite-difference mode keeps its promise through the start and the held tail.
    hard = comparison.runs["offline-cks-trajectory"].metrics
    assert max(hard["fd_acceleration"]["max_over_limit"]) <= 1.0 + 1e-6
    assert max(hard["fd_jerk"]["max_over_limit"]) <= 1.0 + 1e-6
    # The one-step predictor does not (it overshoots every turn of the synthetic operator).
    predictor = comparison.runs["kf-predictor"].metrics
    assert max(predictor["fd_acceleration"]["max_over_limit"]) > 1.0


def test_residual_motion_and_table_rows(scenario, comparison):
    period = comparison.period_s
    operator_samples = comparison.q_original.shape[0] - round(scenario.settle_s / period)
    for run in comparison.runs.values():
        final = tool_positions(scenario, run.packets[-1][None, :])[0]
        # From the end of the hold of the packet carrying the last sample (zoh).
        after = run.tracker_t_s >= (operator_samples + run.delay_ticks) * period
        expected = np.linalg.norm(run.tool_position_m[after] - final, axis=1).max()
        assert run.metrics["residual_motion_m"] == pytest.approx(expected, rel=1e-12)
        # Settling: the last tracker sample farther than 0.1 mm from the final position,
        # counted from the operator's last sample (0 if the tool was settled by then).
        distance = np.linalg.norm(run.tool_position_m - final, axis=1)
        last_outside = max((t for t, d in zip(run.tracker_t_s, distance) if d > 1e-4),
                           default=-np.inf)
        stop = (operator_samples - 1) * period
        if last_outside > run.tracker_t_s[-1] - 0.5:   # not inside for the last 0.5 s
            assert not run.metrics["settled"] and np.isnan(run.metrics["settling_time_s"])
        else:
            assert run.metrics["settled"]
            assert run.metrics["settling_time_s"] == pytest.approx(
                max(0.0, last_outside - stop))
    rows = comparison.table()
    assert [row["method"] for row in rows] == list(METHODS)
    assert rows[0]["improvement_ratio_percent"] == 0.0
    assert all(row["presim_violations"] == 0 for row in rows)
    # Same simulated time for every method, so the errors are comparable.
    ends = {round(run.tracker_t_s[-1], 6) for run in comparison.runs.values()}
    assert len(ends) == 1


def test_the_banded_solver_sends_the_same_offline_cks_packets(scenario, comparison):
    """--solver banded-ip: the Offline-CKS packets are the MathematicalProgram's to 1e-6 rad,
    and the details say which solver ran."""
    banded = compare_methods(scenario, ("original", "offline-cks-trajectory"),
                             offline_solver="banded-ip")
    drake_packets = comparison.runs["offline-cks-trajectory"].packets
    np.testing.assert_allclose(banded.runs["offline-cks-trajectory"].packets, drake_packets,
                               rtol=0, atol=1e-6)
    base, settings = method_settings(scenario, "offline-cks-trajectory", "banded-ip")
    assert settings.offline_solver == "banded-ip"
    assert smooth_recording(comparison.q_original, comparison.period_s, base, settings,
                            joint_names=comparison.joint_names).details["solver"] == "banded-ip"


def test_bad_methods_and_live_operator_are_refused(scenario):
    with pytest.raises(ValueError, match="'smoothest'"):
        compare_methods(scenario, ("original", "smoothest"))
    with pytest.raises(ValueError, match="offline_solver = 'cvxpy'"):
        compare_methods(scenario, ("original",), offline_solver="cvxpy")
    with pytest.raises(ValueError, match="offline_solver = 'cvxpy'"):
        method_settings(scenario, "offline-cks", "cvxpy")
    with pytest.raises(ValueError, match="repeats"):
        compare_methods(scenario, ("bmfls", "bmfls"))
    live = LoadScenario(scenario_text="{haptic: {source: lcm}}")
    with pytest.raises(ValueError, match="live device"):
        compare_methods(live, ("original",))


def test_cli_writes_the_report(tmp_path, capsys):
    out = tmp_path / "compare"
    code = main(["compare", "--scenario-name", "OneOfEverything", "--methods",
                 "bmfls,online-cks,offline-hard", "--out", str(out)])
    assert code == 0
    assert f"report: {out / 'report.md'}" in capsys.readouterr().out
    for name in ("report.md", "table.md", "comparison.json", "packets.csv",
                 "acceleration_jerk.png", "end_effector.png", "error_along_path.png",
                 "response_error.png", "summary.png"):
        assert (out / name).is_file(), name
    data = json.loads((out / "comparison.json").read_text())
    assert [row["method"] for row in data["table"]] == ["original", "bmfls", "online-cks",
                                                        "offline-hard"]
    # Three tables (limits, accuracy, timing), each under its title, one row per method.
    blocks = (out / "table.md").read_text().strip().split("\n\n")
    assert [b for b in blocks if b.startswith("**")] == [
        "**The commands against the limits**", "**Deformation and tracking**",
        "**Delay, latency and settling**"]
    limits, accuracy, timing = (b.splitlines() for b in blocks if b.startswith("| method |"))
    assert all(len(table) == 2 + 4 for table in (limits, accuracy, timing))
    assert timing[2].startswith("| original | 0.00 |")
    # Every method's E_def beside offline-hard's, the least deformation the limits allow.
    # This synthetic operator keeps the limits, so offline-hard sends its samples unchanged
    # and there is no ratio to give.
    assert "| E_def / offline-hard |" in accuracy[0]
    rows = {row["method"]: row for row in data["table"]}
    assert rows["offline-hard"]["cartesian_deformation_mean_m"] == 0.0
    assert "| n/a (offline-hard deforms nothing) |" in accuracy[4]
    # offline-hard keeps the limits: no ratio over 1 is flagged on its row.
    assert limits[5].startswith("| offline-hard |") and "!" not in limits[5]
    assert data["plant"]["modes"]["natural_frequency_hz"][0] > 0
    with open(out / "packets.csv", newline="") as handle:
        rows = list(csv.reader(handle))
    joints = data["scenario"]["joint_names"]
    assert rows[0] == ["t"] + [f"{m}:{j}" for m in ("original", "bmfls", "online-cks",
                                                     "offline-hard") for j in joints]
    # The CSV holds each method's packets (bmfls: the start pose for the first L ticks).
    start = np.array(rows[1][1 + len(joints):1 + 2 * len(joints)], dtype=float)
    np.testing.assert_allclose(start, np.array(rows[3][1 + len(joints):1 + 2 * len(joints)],
                                               dtype=float))


def test_cli_solver_reaches_the_comparison(tmp_path, monkeypatch):
    import telesmooth.scripts.compare_report as compare_report

    seen = {}

    def fake(out, scenario, *, methods, offline_solver, chain):
        seen.update(methods=methods, offline_solver=offline_solver, chain=chain,
                    scenario_chain=scenario.chain)
        return out / "report.md"

    monkeypatch.setattr(compare_report, "write_comparison_report", fake)
    code = main(["compare", "--methods", "offline-cks", "--solver", "banded-ip", "--out",
                 str(tmp_path / "x")])
    # The paper's chain by default, whatever the scenario's (deployed by default).
    assert code == 0 and seen == {"methods": ("offline-cks",), "offline_solver": "banded-ip",
                                  "chain": "paper", "scenario_chain": "paper"}
    code = main(["compare", "--methods", "offline-cks", "--chain", "deployed", "--out",
                 str(tmp_path / "y")])
    assert code == 0 and seen["chain"] == "deployed" and seen["scenario_chain"] == "deployed"


def test_cli_unknown_method_exits_2(tmp_path, capsys):
    code = main(["compare", "--methods", "original,fastest", "--out", str(tmp_path / "x")])
    assert code == 2
    assert "'fastest'" in capsys.readouterr().err


def test_a_method_whose_packets_were_played_already_reuses_that_plant_run(scenario):
    from telesmooth.studies.comparison import prepare_comparison, run_method

    setup = prepare_comparison(scenario)
    fresh = run_method(setup, "online-cks")
    playbacks = {}
    first = run_method(setup, "online-cks", playbacks=playbacks)
    again = run_method(setup, "online-cks", playbacks=playbacks)
    other = run_method(setup, "original", playbacks=playbacks)
    assert (first.playback_reused, again.playback_reused, other.playback_reused) == (
        False, True, False)
    assert len(playbacks) == 2
    for run in (first, again):
        np.testing.assert_array_equal(run.response_error_m, fresh.response_error_m)
        np.testing.assert_array_equal(run.tool_position_m, fresh.tool_position_m)
        assert {k: v for k, v in run.metrics.items() if k != "timings_s"} == {
            k: v for k, v in fresh.metrics.items() if k != "timings_s"}
    # A different packet stream is simulated: not the reused figures.
    assert other.metrics["response_error_m"] != again.metrics["response_error_m"]
    # The shared record cannot be changed through one of the runs that hold it.
    with pytest.raises(ValueError, match="read-only"):
        again.tool_position_m[0, 0] = 1.0


def test_a_run_that_keeps_its_collision_geometry_is_said_so_and_gives_the_same_figures(
        monkeypatch):
    import telesmooth.arms.self_contact as self_contact

    defaults = LoadScenario(scenario_text="{}")
    said = []
    certified = compare_methods(defaults, ("original",), progress=said.append)
    run = certified.runs["original"]
    assert run.self_contact.certified and "collision geometry" not in said[0]
    # A clearance no run can show: the run is refused and made again with the geometry.
    monkeypatch.setattr(self_contact, "CLEARANCE_M", 1e3)
    said.clear()
    kept = compare_methods(defaults, ("original",), progress=said.append).runs["original"]
    assert not kept.self_contact.certified
    assert "with the arm's collision geometry (self-contact not excluded)" in said[0]
    # No link touched another: the geometry's run is the same run.
    np.testing.assert_array_equal(kept.tool_position_m, run.tool_position_m)
    assert {k: v for k, v in kept.metrics.items() if k != "timings_s"} == {
        k: v for k, v in run.metrics.items() if k != "timings_s"}
