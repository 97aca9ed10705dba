"""`compare` and `experiment` through the deployed chain: each method's packets through the
onboard receiver and link guard (``chain = "deployed"``), the paper's chain by default.

Oracles: the FD limits of what the robot received are recomputed from the guard's logged
commands (``fd_limits_ratio``, written out independently of the guard's limiter); a stream
within the limits must reach the robot as sent, command for command; the instant the robot
begins each ramp follows from the documented timing of the link, the receiver and the
interpolator (each one poll or one offset, not a simulation).
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from telesmooth.diagrams.offline_playback import (
    play_path,
    playback_guard_record,
    ramp_start_times,
)
from telesmooth.diagrams.scenario import LoadScenario
from telesmooth.safety.guard import fd_limits_ratio
from telesmooth.scripts.cli import main
from telesmooth.studies.comparison import compare_methods, prepare_comparison, run_method
from telesmooth.systems.link_guard import GUARD_MODES, MODE_RESUMING, MODE_TRACK

# OneOfEverything (9 s of synthetic operator on the 6-DOF arm) with limits its raw commands
# break several times over.
TIGHT = "{smoother: {max_acceleration_rad_per_s2: 0.01, max_jerk_rad_per_s3: 0.02}}"


def _received_ratio(guard, q_start, period_s, a_max, j_max):
    """FD acceleration and jerk over the limits of what the robot received: its rest at the
    start pose (three samples, as before the first packet), then every guard command."""
    sequence = np.vstack([np.tile(q_start, (3, 1)), guard.q_commanded])
    return fd_limits_ratio(sequence, period_s, a_max, j_max)


@pytest.fixture(scope="module")
def tight():
    return LoadScenario(scenario_name="OneOfEverything", scenario_text=TIGHT)


def test_the_guard_keeps_what_the_robot_receives_within_the_limits(tight):
    setup = prepare_comparison(tight, chain="deployed")
    period = setup.period_s
    rest = np.tile(setup.q_start, (3, 1))
    sent = fd_limits_ratio(np.vstack([rest, setup.q_original]), period, setup.max_acceleration,
                           setup.max_jerk)
    assert sent.acceleration > 2.0 and sent.jerk > 2.0     # the original breaks them
    logs, _ = play_path(setup.scenario, setup.q_original, q_start=setup.q_start,
                        duration_s=setup.duration_s, chain="deployed")
    guard = playback_guard_record(logs, setup.scenario.command_receiver.poll_period_s)
    received = _received_ratio(guard, setup.q_start, period, setup.max_acceleration,
                               setup.max_jerk)
    assert received.acceleration <= 1.0 + 1e-9 and received.jerk <= 1.0 + 1e-9
    assert guard.limited_count > 0
    # The comparison reports the same guard, with what the method sent beside it.
    run = run_method(setup, "original")
    row = run.metrics["guard"]
    assert run.metrics["chain"] == "deployed"
    assert row["limited"] == guard.limited_count and row["commands"] == guard.num_commands
    assert max(row["received"]["fd_acceleration"]["max_over_limit"]) == pytest.approx(
        received.acceleration, rel=1e-12)
    assert max(row["received"]["fd_jerk"]["max_over_limit"]) == pytest.approx(
        received.jerk, rel=1e-12)
    cut = np.abs(guard.q_commanded - guard.q_followed).max()
    assert max(row["largest_cut_rad"]) == pytest.approx(cut, rel=1e-12) and cut > 0
    assert max(run.metrics["fd_acceleration"]["max_over_limit"]) == pytest.approx(
        sent.acceleration, rel=1e-12)          # the sent figures stay the method's


def test_a_stream_within_the_limits_reaches_the_robot_as_sent():
    """A minimum-jerk move from rest at the robot's pose to rest, well within the limits:
    every command the guard issues is its packet bit for bit, while it re-joins the stream
    (RESUMING, from its rest before the first packet) and once it follows it (TRACK); the
    uplink re-sends the last packet after the path. The robot begins each ramp one receiver
    poll and the interpolator's offset after the packet's send time (the paper's chain: at
    the send time)."""
    scenario = LoadScenario(scenario_name="Defaults")
    period = scenario.uplink.period_s
    q0 = np.array([0.3, 1.2, -1.0])
    t = period * np.arange(28)
    tau = np.minimum(t / 6.0, 1.0)[:, None]
    path = q0 + np.array([0.05, -0.05, 0.025]) * (10 * tau**3 - 15 * tau**4 + 6 * tau**5)
    # 5.77 d/T² and 60 d/T³ at most: 0.008 rad/s² and 0.014 rad/s³ against 0.05 and 0.1.
    assert max(fd_limits_ratio(np.vstack([np.tile(q0, (3, 1)), path]), period, 0.05, 0.1)) \
        <= 0.25
    duration = 8.0
    logs, _ = play_path(scenario, path, q_start=q0, duration_s=duration, chain="deployed")
    guard = playback_guard_record(logs, scenario.command_receiver.poll_period_s)
    assert guard.limited_count == 0
    # One command per packet sent before the end: the path, then the last packet re-sent.
    sent = np.vstack([path, np.tile(path[-1], (guard.num_commands - len(path), 1))])
    np.testing.assert_array_equal(guard.q_commanded, sent)
    np.testing.assert_array_equal(guard.q_commanded, guard.q_followed)
    modes = guard.mode[np.searchsorted(guard.poll_t_s, guard.command_t_s)]
    matches = scenario.link_guard.resume_match_ticks
    assert [GUARD_MODES[m] for m in modes[:matches]] == (
        ["resuming"] * (matches - 1) + ["track"])
    assert np.all(modes[matches:] == MODE_TRACK) and MODE_RESUMING in modes
    # Timing: the link takes the packet formed at t_k at its poll 0.9 poll periods after the
    # receiver's poll before t_k, the receiver and guard at the next poll (t_k + poll), the
    # interpolator 0.1 ms after that.
    poll = scenario.command_receiver.poll_period_s
    offset = scenario.onboard.interpolator.poll_offset_s
    # A ramp starts for every packet that differs from the one before (t = 0: the initial
    # ramp, at the robot's rest).
    moving = t[1:][np.any(np.diff(path, axis=0) != 0, axis=1)]
    starts = ramp_start_times(logs)
    assert starts[0] == 0.0 and starts.size == 1 + moving.size
    np.testing.assert_allclose(starts[1:], moving + poll + offset, rtol=0, atol=1e-9)
    paper, _ = play_path(scenario, path, q_start=q0, duration_s=duration)
    assert "guard_q_commanded" not in paper
    paper_starts = np.unique(paper["command_ramp"].values[:, 0])
    np.testing.assert_allclose(paper_starts[1:], moving, rtol=0, atol=1e-12)


def test_the_paper_chain_is_the_default_and_its_runs_have_no_guard():
    scenario = LoadScenario(scenario_name="OneOfEverything")
    assert scenario.chain == "deployed"           # the scenario's own default is not read
    comparison = compare_methods(scenario, ("original",))
    assert comparison.chain == "paper"
    run = comparison.runs["original"]
    assert run.metrics["chain"] == "paper" and run.metrics["guard"] is None
    assert not any(key.startswith("guard_") for key in comparison.table()[0])
    with pytest.raises(ValueError, match="chain = 'onboard'"):
        prepare_comparison(scenario, chain="onboard")


def test_the_compare_report_names_its_chain_first_and_what_the_guard_did(tmp_path, capsys):
    common = ["compare", "--scenario-name", "OneOfEverything", "--scenario-text", TIGHT,
              "--methods", "original"]
    assert main(common + ["--out", str(tmp_path / "paper")]) == 0
    assert main(common + ["--chain", "deployed", "--out", str(tmp_path / "deployed")]) == 0
    paper = (tmp_path / "paper" / "report.md").read_text().splitlines()
    deployed = (tmp_path / "deployed" / "report.md").read_text().splitlines()
    assert paper[2].startswith("Chain: the paper's chain")
    assert deployed[2].startswith("Chain: the deployed chain")
    assert "What the onboard link guard did" not in "\n".join(paper)
    # Above the timing table, delay and added latency are defined, with the original's τ.
    timing = paper.index("## Delay, latency and settling")
    table = next(i for i in range(timing, len(paper)) if paper[i].startswith("| method |"))
    above = "\n".join(paper[timing:table])
    assert "- *delay*: the method's designed delay d·Δt" in above
    assert "- *added latency*: τ of the method − τ of `original`" in above
    original = json.loads((tmp_path / "paper" / "comparison.json").read_text())["table"][0]
    assert f"τ of `original` here: {original['latency_s']:.2f} s." in above
    text = "\n".join(deployed)
    assert "## What the onboard link guard did" in text
    header = next(line for line in deployed if line.startswith("| method | commands |"))
    row = next(line for line in deployed[deployed.index(header):]
               if line.startswith("| original |"))
    cells = dict(zip([c.strip() for c in header.strip("|").split("|")],
                     [c.strip() for c in row.strip("|").split("|")], strict=True))
    data = json.loads((tmp_path / "deployed" / "comparison.json").read_text())
    guard = data["methods"]["original"]["guard"]
    assert data["scenario"]["chain"] == "deployed"
    assert cells["limited"] == str(guard["limited"]) and guard["limited"] > 0
    assert cells["received FD acc max/limit"] in ("1.00", "1.0000")   # within the limits
    # A link fault model needs the deployed chain: the paper's refuses it in one line.
    faults = "{link: {faults: {loss_probability: 0.1}}}"
    capsys.readouterr()
    status = main(["compare", "--scenario-text", faults, "--out", str(tmp_path / "faults")])
    err = capsys.readouterr().err.strip()
    assert status == 2 and err.count("\n") == 0 and "--chain paper" in err


def test_the_experiment_records_and_reports_its_chain(tmp_path):
    from telesmooth.studies.experiment import ExperimentConfig, ExperimentTask, run_task
    from telesmooth.studies.journal import grid_fingerprint

    base = LoadScenario(scenario_text="{haptic: {lasa_mapping: {time_scale: 4.0, "
                                       "hold_start_s: 0.5, hold_end_s: 1.0}}}")
    config = ExperimentConfig(shapes=("Angle",), methods=("original",), sensitivity_shapes=(),
                              c8_shapes=(), settle_s=2.0, speeds=(2.5,), chain="deployed")
    paper = dataclasses.replace(config, chain="paper")
    assert ExperimentConfig().chain == "paper"
    assert grid_fingerprint(base, config)["fingerprint"] != \
        grid_fingerprint(base, paper)["fingerprint"]
    task = ExperimentTask(index=0, kind="run", shape="Angle", demo=0, method="original",
                          label="original", speed=2.5)
    record = run_task(task, base, config)
    assert record["chain"] == "deployed"
    assert record["metrics"]["received_fd_acc_max_over_limit"] <= 1.0 + 1e-9
    assert record["metrics"]["fd_acc_max_over_limit"] > 1.0
    assert record["metrics"]["guard_limited"] > 0
    assert run_task(task, base, paper)["chain"] == "paper"
    with pytest.raises(ValueError, match="chain = 'onboard'"):
        ExperimentConfig(chain="onboard")
