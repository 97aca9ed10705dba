"""The reports of the two processes (scripts/process_report.py).

* ``ground_record`` on a fabricated telemetry log: the robot's messages, on a clock 50 s
  ahead of the ground's, each arriving after its own latency and logged by the ground every
  10 ms (repeated until the next arrives; NaN before the first and for a message of another
  arm). Oracle, worked out by hand: the clock offset is the smallest (first ground row
  showing a message − its onboard time), one row per message, every field in place, and the
  ramp starts are the first messages naming each newly accepted packet, mapped, less the
  publish offset.
* ``onboard_record``/``onboard_metrics``/``write_onboard_report`` and ``ground_record`` end
  to end: the ground and onboard diagrams of the two processes on one ``memq://`` bus in one
  simulator (one clock). Oracles: the poll grid (packet k, published 1 ms after its tick,
  accepted by the onboard poll at k·0.25 + 0.01 s), the FD acceleration and jerk of the
  ground's sent packets computed here with numpy, and the onboard robot's own record.
"""

import json
from types import SimpleNamespace

import numpy as np
import pytest
from pydrake.lcm import DrakeLcm
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

import telesmooth.scripts.process_report as process_report
from telesmooth.diagrams.scenario import LoadScenario
from telesmooth.diagrams.simulation import response_errors
from telesmooth.diagrams.teleoperation import (
    MakeGroundDiagram,
    MakeOnboardDiagram,
    uplink_packets,
)
from telesmooth.systems.joint_status_decoder import telemetry_layout

SHORT = ("{haptic: {source: synthetic, synthetic: {duration_s: 3.0, hold_start_s: 0.5, "
         "hold_end_s: 0.5}}, settle_s: 1.0, smoother: {method: online-hard}}")
POLL, TICK = 0.01, 0.25

# -- ground_record on a fabricated telemetry log ---------------------------------------------

AHEAD_S = 50.0                    # the robot's clock reads ground time + 50 s
PUBLISHED = 0.303 + 0.05 * np.arange(8)           # ground instants the messages left, s
LATENCY = np.array([0.004, 0.020, 0.011, 0.004, 0.030, 0.013, 0.0045, 0.017])
LAST_SEQ = [-1, -1, 0, 0, 1, 3, 3, 4]             # the last accepted packet each names
# Each message is first shown by the ground's row at the next 10 ms after its arrival:
# 0.307 → 0.31, 0.373 → 0.38, 0.414 → 0.42, 0.457 → 0.46, 0.533 → 0.54, 0.566 → 0.57,
# 0.6075 → 0.61, 0.670 → 0.68; row − publish = 7, 27, 17, 7, 37, 17, 7, 27 ms. The smallest,
# 7 ms, is the offset: ground = onboard − 50 s + 7 ms.
FIRST_ROW = np.array([0.31, 0.38, 0.42, 0.46, 0.54, 0.57, 0.61, 0.68])
OFFSET = 0.007 - AHEAD_S


def _fabricated_log():
    n = 3
    layout = telemetry_layout(n)
    times = np.round(0.01 * np.arange(80), 10)         # the ground's rows, 0 … 0.79 s
    values = np.full((times.size, 3 * n + 8), np.nan)
    for m in range(len(PUBLISHED)):
        vector = np.empty(3 * n + 8)
        vector[layout["utime_s"]] = round(PUBLISHED[m] + AHEAD_S, 6)
        vector[layout["seq"]] = 100 + m
        vector[layout["last_command_seq"]] = LAST_SEQ[m]
        vector[layout["guard_mode"]] = m % 4
        vector[layout["stream_distance_rad"]] = 0.001 * m
        vector[layout["q_link"]] = [m, m + 0.1, m + 0.2]
        vector[layout["q_motor"]] = [-m, -m - 0.1, -m - 0.2]
        vector[layout["tool_position"]] = [10.0 * m, 1.0, 2.0]
        vector[layout["q_commanded"]] = [m + 0.5, m + 0.6, m + 0.7]
        until = FIRST_ROW[m + 1] if m + 1 < len(FIRST_ROW) else np.inf
        values[(times >= FIRST_ROW[m] - 1e-9) & (times < until - 1e-9)] = vector
    values[np.isclose(times, 0.50)] = np.nan      # a message of another arm, in between
    return times, values


class _Sink:
    def __init__(self, times, values):
        self._log = SimpleNamespace(sample_times=lambda: times, data=lambda: values.T)

    def FindLog(self, context):
        return self._log


def _fabricated_handles(monkeypatch, times, values):
    scenario = LoadScenario()
    assert scenario.publish_offset_s == 0.001
    # The ground's own fields (targets, packets, ticks) do not take part in the mapping.
    monkeypatch.setattr(process_report, "ground_fields", lambda handles, context: dict(
        target_t_s=None, q_target=None, collision_detected=None, min_distance_m=None,
        packet_seq=None, packet_t_s=None, packet_state=None, tick_t_s=None, q_delayed=None,
        holding=None, sigma=None, stop_status=None, braking_distance=None,
        initial_position_rad=np.zeros(3)))
    handles = SimpleNamespace(scenario=scenario, logs={"telemetry": _Sink(times, values)},
                              ground=SimpleNamespace(joint_names=("a", "b", "c")))
    return handles, SimpleNamespace(get_time=lambda: 0.8)


def test_the_telemetry_clock_mapping_on_a_fabricated_log(monkeypatch):
    # Catches: the offset taken as the largest or the mean difference, or from every logged
    # row (repeats of a message arrive "later" and would only raise it, but NaN rows would make
    # it NaN), the sign of the mapping (ground = onboard + offset), a message kept once per
    # row instead of once, the fields taken from the wrong slices, and ramp starts at every
    # message (or every change of seq) instead of the first naming each new packet.
    handles, context = _fabricated_handles(monkeypatch, *_fabricated_log())
    record, view = process_report.ground_record(handles, context, wall_time_s=2.0)
    assert view["clock_offset_s"] == pytest.approx(OFFSET, abs=1e-9)
    mapped = PUBLISHED + 0.007                    # each message's onboard time, mapped
    np.testing.assert_allclose(view["t_s"], mapped, rtol=0, atol=1e-9)
    m = np.arange(len(PUBLISHED))
    np.testing.assert_array_equal(view["guard_mode"], m % 4)
    np.testing.assert_allclose(view["stream_distance_rad"], 0.001 * m)
    np.testing.assert_array_equal(view["q_commanded"][:, 0], m + 0.5)
    np.testing.assert_array_equal(record.q_link[:, 2], m + 0.2)
    np.testing.assert_array_equal(record.q_motor[:, 1], -m - 0.1)
    np.testing.assert_array_equal(record.tool_position_m[:, 0], 10.0 * m)
    # Packets 0, 1, 3, 4 are first named by messages 2, 4, 5, 7.
    np.testing.assert_allclose(record.ramp_start_t_s, mapped[[2, 4, 5, 7]] - 0.001,
                               rtol=0, atol=1e-9)
    assert record.guard is None and record.duration_s == 0.8


def test_the_samples_are_dated_when_the_tracker_took_them(monkeypatch):
    # Catches a mapping in which the telemetry's samples and the ramp starts read from the
    # same messages disagree by the publish offset.
    handles, context = _fabricated_handles(monkeypatch, *_fabricated_log())
    record, _ = process_report.ground_record(handles, context, wall_time_s=2.0)
    np.testing.assert_allclose(record.tracker_t_s, PUBLISHED + 0.007 - 0.001, rtol=0,
                               atol=1e-9)


def test_without_telemetry_the_ground_record_has_no_robot(monkeypatch):
    # Catches: a NaN offset or a crash when nothing (or only another arm's messages) arrived.
    times, values = _fabricated_log()
    handles, context = _fabricated_handles(monkeypatch, times, np.full_like(values, np.nan))
    record, view = process_report.ground_record(handles, context, wall_time_s=2.0)
    assert view is None and record.ramp_start_t_s is None
    assert record.tracker_t_s.size == 0 and record.q_link.shape == (0, 3)


# -- the two processes' diagrams on one bus, one clock ---------------------------------------

@pytest.fixture(scope="module")
def two_sides():
    scenario = LoadScenario(scenario_text=SHORT)
    lcm = DrakeLcm("memq://")
    ground = MakeGroundDiagram(scenario, lcm=lcm)
    onboard = MakeOnboardDiagram(scenario, lcm=lcm)
    builder = DiagramBuilder()
    builder.AddSystem(ground.diagram)
    builder.AddSystem(onboard.diagram)
    simulator = Simulator(builder.Build())
    simulator.AdvanceTo(4.0)
    return scenario, ground, onboard, simulator.get_context()


def test_the_onboard_record_dates_each_packet_at_the_poll_that_accepted_it(two_sides):
    # Catches: accepted packets dated at the logger's row (a poll late), the wrong seq for a
    # packet, or the last packets of the run (accepted at its last polls) left out.
    scenario, ground, onboard, context = two_sides
    record = process_report.onboard_record(onboard, context, wall_time_s=1.0)
    seq, sent_t, states = uplink_packets(ground, context)
    # Packet k leaves at k·0.25 + 1 ms and is taken by the poll at k·0.25 + 10 ms; the last
    # poll the logs show is at 3.99 s.
    due = sent_t + POLL <= 3.99 + 1e-9
    np.testing.assert_array_equal(record.packet_seq, seq[due])
    np.testing.assert_allclose(record.packet_t_s, TICK * seq[due] + POLL, rtol=0, atol=1e-12)
    n = record.num_joints
    np.testing.assert_array_equal(record.q_sent, states[due][:, :n])
    assert np.all(np.isnan(record.packet_state[:, n:]))       # velocities unknown onboard
    np.testing.assert_array_equal(record.initial_position_rad,
                                  ground.ground.initial_position_rad)


def test_the_onboard_metrics_against_numpy_on_the_packets_sent(two_sides, tmp_path):
    # Catches: the stream's FD taken without the robot's rest at its start pose (or with a
    # rest at zero), the first rest-only sample kept, the limits of another joint, and a
    # report whose metrics.json or text disagree with the run.
    scenario, ground, onboard, context = two_sides
    seq, sent_t, states = uplink_packets(ground, context)
    n = 3
    q = states[sent_t + POLL <= 3.99 + 1e-9][:, :n]
    rest = np.tile(ground.ground.initial_position_rad, (3, 1))
    sequence = np.vstack([rest, q])
    dt = scenario.uplink.period_s
    acceleration = np.abs(np.diff(sequence, 2, axis=0)[1:]) / dt**2
    jerk = np.abs(np.diff(sequence, 3, axis=0)) / dt**3
    a_max = scenario.smoother.max_acceleration_rad_per_s2
    j_max = scenario.smoother.max_jerk_rad_per_s3

    extra = {"authentication": "off", "onboard_epoch": 0,
             "packets": {"accepted": len(q), "invalid": 0, "auth": None}}
    report = process_report.write_onboard_report(tmp_path, onboard, context,
                                                 wall_time_s=1.5, extra=extra)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["side"] == "onboard" and metrics["accepted_packets"] == len(q)
    stream = metrics["stream"]
    assert stream["fd_acceleration"]["num_samples"] == len(q)
    np.testing.assert_allclose(stream["fd_acceleration"]["max_abs"], acceleration.max(axis=0),
                               rtol=0, atol=1e-12)
    np.testing.assert_allclose(stream["fd_acceleration"]["max_over_limit"],
                               acceleration.max(axis=0) / a_max, rtol=1e-12)
    np.testing.assert_allclose(stream["fd_jerk"]["max_abs"], jerk.max(axis=0), rtol=0,
                               atol=1e-12)
    # Online-hard keeps the limits: the guard passed every packet unchanged, so what the
    # robot received is the stream itself.
    guard = metrics["guard"]
    assert guard["commands"] == guard["accepted_packets"] == len(q) and guard["limited"] == 0
    np.testing.assert_allclose(guard["received"]["fd_jerk"]["max_abs"], jerk.max(axis=0),
                               rtol=0, atol=1e-12)
    assert max(stream["fd_jerk"]["max_over_limit"]) <= 1 + 1e-6
    assert jerk.max() / j_max > 0.1           # the checks above are not vacuous
    text = report.read_text()
    assert text.startswith("# telesmooth onboard\n")
    assert "authentication off, epoch 0000000000000" in text
    assert f"{len(q)} packets accepted; packets by class: accepted {len(q)}, invalid 0." in text
    assert "The packets accepted from the ground stay within" in text
    assert (tmp_path / "received.csv").read_text().count("\n") == len(q) + 1


def test_the_ground_record_maps_the_robots_clock_within_a_telemetry_period(two_sides):
    # Catches: an offset of the wrong sign or size. On one clock the robot's telemetry,
    # published at j·0.01 + 1 ms (its utime), is first logged by the ground at (j + 1)·0.01:
    # the smallest arrival − onboard time is 9 ms (up to the µs of utime).
    scenario, ground, onboard, context = two_sides
    record, view = process_report.ground_record(ground, context, wall_time_s=1.0)
    assert view["clock_offset_s"] == pytest.approx(0.009, abs=1e-6)
    onboard_tracker = onboard.logs["tracker"].FindLog(context).data()
    assert record.tracker_t_s.size >= 390
    # Every sample the robot took is reported once, in order.
    np.testing.assert_allclose(np.diff(record.tracker_t_s), 0.01, atol=1e-6)
    assert np.unique(onboard_tracker[0]).size >= record.tracker_t_s.size


def test_the_ground_reads_the_same_response_error_as_the_robot(two_sides):
    # Catches: any inconsistency between the ground's ramp starts and its samples: on one
    # clock, with the same packets and the same robot, the ground must read the response the
    # robot's own record reads.
    scenario, ground, onboard, context = two_sides
    ground_side, _ = process_report.ground_record(ground, context, wall_time_s=1.0)
    onboard_side = process_report.onboard_record(onboard, context, wall_time_s=1.0)
    e_ground = response_errors(ground_side).response_m
    e_onboard = response_errors(onboard_side).response_m
    assert e_ground.size >= 10
    assert np.mean(e_ground) == pytest.approx(np.mean(e_onboard), rel=0.05)
