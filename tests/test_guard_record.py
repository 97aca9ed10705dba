"""What the onboard link guard did, as the reports read it (diagrams/simulation.py):
``guard_record`` and ``guard_metrics``.

Oracles:

* ``guard_record`` dates every value at the poll that decided it (a Drake logger at t shows
  the state *before* the updates at t). The oracle does not read a logger at all: the
  simulator is stepped to the middle of every poll interval, where the receiver's outputs are
  exactly what the guard's poll just before read (the receiver's unrestricted update runs
  before the guard's discrete update at the same instant); those outputs are replayed through
  the pure :func:`telesmooth.safety.guard.guard_step`, poll by poll, and the record must be
  that replay: the same polls, modes, stream distances, commands, followed packets and
  counts. Two runs: ``bmfls`` (breaks the limits; the guard cuts its commands) through a
  1 s outage (the guard also stops and re-joins), and ``online-hard`` on a perfect link (it
  keeps the limits: nothing is cut, every packet is commanded in the poll that accepted it,
  k·0.25 + 0.01 s).
* ``guard_metrics`` on a ``GuardRecord`` written by hand, whose FD accelerations and jerks
  are worked out below on paper.
"""

import dataclasses
import functools

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from telesmooth.diagrams.scenario import LoadScenario
from telesmooth.diagrams.simulation import (
    GuardRecord,
    SimulationRecord,
    guard_metrics,
    guard_record,
)
from telesmooth.diagrams.teleoperation import MakeTeleoperationDiagram
from telesmooth.safety.guard import GuardInputs, GuardMode, guard_initial_state, guard_step

SHORT = ("{haptic: {source: synthetic, synthetic: {duration_s: 5.0, hold_start_s: 0.5, "
         "hold_end_s: 0.5}}, settle_s: 1.0, smoother: {method: %s}%s}")
POLL = 0.01
TICK = 0.25
NUM_POLLS = 600          # 6 s: the recording (5 s) and settle_s

RUNS = {
    # Breaks the limits (the guard cuts), and a 1 s outage makes the guard stop and re-join.
    "bmfls+outage": ("bmfls", ", link: {faults: {outages: [[2.0, 3.0]]}}"),
    # Keeps the limits on a perfect link: the guard passes every packet unchanged.
    "online-hard": ("online-hard", ""),
}


def _replay(handles, simulator):
    """Steps the run poll by poll; returns the pure guard's replay of the receiver outputs
    the guard read: per poll (mode, stream distance) and the commands (poll, q, packet)."""
    context = simulator.get_context()
    receiver, guard = handles.onboard.receiver, handles.onboard.guard
    receiver_context = receiver.GetMyContextFromRoot(context)
    params = guard.params
    state = guard_initial_state(params)
    modes, distances, commands, counts = [], [], [], []
    for i in range(NUM_POLLS):
        # Half-way to the next poll: the updates of poll i are done, those of i + 1 not yet.
        simulator.AdvanceTo((i + 0.5) * POLL)

        def read(port):
            return np.array(port.Eval(receiver_context), dtype=float)

        q = read(receiver.get_q_commanded_output_port())
        count = read(receiver.get_accepted_count_output_port())[0]
        seq = read(receiver.get_last_command_seq_output_port())[0]
        session = read(receiver.get_last_command_session_output_port())[0]
        issued = state.command_count
        state, command = guard_step(params, state, GuardInputs(
            poll=i, accepted_count=count, q_accepted=q, packet_id=(seq, session)))
        modes.append(int(state.mode))
        distances.append(state.stream_distance_rad)
        counts.append(count)
        if state.command_count > issued:
            commands.append((i, command, q))
    simulator.AdvanceTo(NUM_POLLS * POLL)      # the loggers' last row: poll NUM_POLLS − 1
    return dict(modes=np.array(modes), distances=np.array(distances), commands=commands,
                limited=state.limited_count, accepted=counts[-1])


@functools.cache
def _run(name):
    """(name, scenario, the record, the pure guard's replay) of one of RUNS, once."""
    method, link = RUNS[name]
    scenario = LoadScenario(scenario_text=SHORT % (method, link))
    assert scenario.chain == "deployed"
    assert scenario.command_receiver.poll_period_s == POLL and scenario.uplink.period_s == TICK
    handles = MakeTeleoperationDiagram(scenario)
    simulator = Simulator(handles.diagram)
    simulator.Initialize()
    replay = _replay(handles, simulator)
    record = guard_record(handles.logs, simulator.get_context(), POLL)
    return name, scenario, record, replay


@pytest.fixture(scope="module", autouse=True)
def _release_runs():
    yield
    _run.cache_clear()


@pytest.fixture(params=list(RUNS), ids=list(RUNS))
def run(request):
    return _run(request.param)


def test_every_value_is_dated_at_the_poll_that_decided_it(run):
    # Catches: the row at t dated at t (dropping the "− poll_period_s"), or the first row (the
    # initial state, logged at t = 0 before any poll) kept: every poll, mode and command would
    # then be one poll late, or shifted by one row against the replay.
    name, _, record, replay = run
    assert record.poll_period_s == POLL
    np.testing.assert_allclose(record.poll_t_s, POLL * np.arange(NUM_POLLS), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(record.mode, replay["modes"])
    np.testing.assert_array_equal(record.stream_distance_rad, replay["distances"])
    polls = np.array([i for i, _, _ in replay["commands"]])
    assert record.num_commands == len(replay["commands"]) >= 20, name
    np.testing.assert_allclose(record.command_t_s, POLL * polls, rtol=0, atol=1e-12)


def test_commands_and_the_packets_they_followed_are_the_pure_guards(run):
    # Catches: q_followed read from another row than the command's (the packet of the poll
    # before: it differs from the command on every new packet), q_commanded taken from the
    # rows where the accepted count (not the command count) grew, or counts read from the
    # first logged row instead of the last.
    name, _, record, replay = run
    np.testing.assert_array_equal(record.q_commanded,
                                  np.array([q for _, q, _ in replay["commands"]]))
    np.testing.assert_array_equal(record.q_followed,
                                  np.array([r for _, _, r in replay["commands"]]))
    assert record.limited_count == replay["limited"]
    assert record.accepted_count == replay["accepted"]


def test_the_limited_count_is_the_commands_that_differ_from_their_packet(run):
    # Catches: a limited_count that counts anything else (every command, the stop's commands,
    # the commands issued after a gap): it must be exactly the commands issued while
    # following the stream (track, resuming) that differ from the packet they followed.
    name, _, record, _ = run
    after = record.mode[np.round(record.command_t_s / POLL).astype(int)]
    following = np.isin(after, [GuardMode.TRACK, GuardMode.RESUMING])
    differ = np.any(record.q_commanded != record.q_followed, axis=1)
    assert record.limited_count == int(np.count_nonzero(differ & following))
    if name == "online-hard":
        # Within the limits: nothing cut, every packet passed bit for bit.
        assert record.limited_count == 0
        np.testing.assert_array_equal(record.q_commanded, record.q_followed)
        np.testing.assert_array_equal(record.stream_distance_rad, 0.0)
    else:
        assert record.limited_count >= 5
        assert {GuardMode.STOPPING, GuardMode.RESUMING} <= set(record.mode.tolist())
        # The stop's commands are not "limited" though they differ from the stream.
        assert np.any(differ & ~following)


def test_on_a_perfect_link_packet_k_is_commanded_at_k_tick_plus_one_poll():
    # Catches a dating error on an absolute scale (the replay above shares the logger's grid
    # only through the poll index): the uplink forms packet k at k·0.25 s, the channel polls
    # 1 ms before the receiver, which accepts it at k·0.25 + 0.01 s, and the guard, tracking
    # a stream within the limits, commands it in that same poll.
    _, _, record, _ = _run("online-hard")
    k = np.arange(record.num_commands)
    np.testing.assert_allclose(record.command_t_s, TICK * k + POLL, rtol=0, atol=1e-12)
    assert record.accepted_count == record.num_commands


# -- guard_metrics on a record written by hand ---------------------------------------------

# q0 and three commands (joints a, b, c); Δt = 0.25 s, Δt² = 0.0625, Δt³ = 0.015625. The
# robot rested at q0 before: the sequence is q0, q0, q0, p1, p2, p3, and the FD samples that
# involve a command are
#   acceleration (p_k − 2 p_{k−1} + p_{k−2}) / Δt²:  p1 − q0,  p2 − 2p1 + q0,  p3 − 2p2 + p1
#   jerk (p_k − 3 p_{k−1} + 3 p_{k−2} − p_{k−3}) / Δt³: p1 − q0,  p2 − 3p1 + 2q0,
#                                                     p3 − 3p2 + 3p1 − q0
# Joint a moves by d = [0.00125, 0.00375, 0.0075] from q0: accelerations 0.02, 0.02, 0.02
#   (0.4 of a_max = 0.05), jerks 0.08, 0, 0 (0.8 of j_max = 0.1).
# Joint b moves by [0.0025, 0, 0]: accelerations 0.04, −0.08, 0.04 (1.6×, 1 of 3 over),
#   jerks 0.16, −0.48, 0.48 (4.8×, all 3 over).
# Joint c does not move.
Q0 = np.array([0.1, -0.2, 0.3])
MOVES = np.array([[0.00125, 0.0025, 0.0],
                  [0.00375, 0.0, 0.0],
                  [0.0075, 0.0, 0.0]])


def _hand_record():
    scenario = LoadScenario(scenario_text=SHORT % ("online-hard", ""))
    assert scenario.smoother.max_acceleration_rad_per_s2 == 0.05
    assert scenario.smoother.max_jerk_rad_per_s3 == 0.1
    # 10 polls: held 1, resuming 3, track 4, stopping 2. Commands at polls 1 (resuming),
    # 5 (track) and 8 (stopping: a stop's command, far from the stream, is no cut).
    mode = np.array([2, 3, 3, 3, 0, 0, 0, 0, 1, 1])
    commands = Q0 + MOVES
    followed = commands.copy()
    followed[0] += [0.0, 0.003, -0.001]     # cut 3 mrad on b, 1 mrad on c
    followed[1] += [-0.002, 0.0, 0.0]       # cut 2 mrad on a
    followed[2] += [0.5, 0.5, 0.5]          # the stop: not following
    guard = GuardRecord(
        poll_period_s=POLL, poll_t_s=POLL * np.arange(10), mode=mode,
        stream_distance_rad=np.array([0, 0.003, 0.001, 0, 0.002, 0, 0, 0, 0.5, 0.45]),
        command_t_s=POLL * np.array([1.0, 5.0, 8.0]), q_commanded=commands,
        q_followed=followed, limited_count=2, accepted_count=7)
    record = SimulationRecord(
        scenario=scenario, joint_names=("a", "b", "c"), duration_s=0.1, wall_time_s=1.0,
        cpu_time_s=1.0, target_t_s=None, q_target=None, collision_detected=None,
        min_distance_m=None, packet_seq=None, packet_t_s=None, packet_state=None,
        tick_t_s=None, q_delayed=None, holding=None, sigma=None, tracker_t_s=None,
        q_link=None, q_motor=None, tool_position_m=None, initial_position_rad=Q0,
        guard=guard)
    return record


def test_guard_metrics_against_a_hand_computation():
    # Catches: the rest prefix left out or taken at zero instead of the start pose (the first
    # samples would be ~q0/Δt²), FD samples inside the rest kept (num_samples 4, the share
    # over 1/4 instead of 1/3), the cut taken over every command (the stop's 0.5 rad), the
    # cut's joints mixed up, time in mode not the polls × poll period, the counts swapped.
    metrics = guard_metrics(_hand_record())
    assert metrics["commands"] == 3
    assert metrics["limited"] == 2
    assert metrics["accepted_packets"] == 7
    np.testing.assert_allclose(metrics["largest_cut_rad"], [0.002, 0.003, 0.001], atol=1e-15)
    assert metrics["stream_distance_rad"] == 0.5
    assert metrics["time_in_mode_s"] == pytest.approx(
        {"track": 0.04, "stopping": 0.02, "held": 0.01, "resuming": 0.03}, abs=1e-15)
    acceleration = metrics["received"]["fd_acceleration"]
    jerk = metrics["received"]["fd_jerk"]
    assert acceleration["num_samples"] == jerk["num_samples"] == 3
    np.testing.assert_allclose(acceleration["max_abs"], [0.02, 0.08, 0.0], atol=1e-12)
    np.testing.assert_allclose(acceleration["max_over_limit"], [0.4, 1.6, 0.0], atol=1e-10)
    np.testing.assert_allclose(acceleration["fraction_over_limit"], [0.0, 1 / 3, 0.0])
    np.testing.assert_allclose(jerk["max_abs"], [0.08, 0.48, 0.0], atol=1e-12)
    np.testing.assert_allclose(jerk["max_over_limit"], [0.8, 4.8, 0.0], atol=1e-10)
    np.testing.assert_allclose(jerk["fraction_over_limit"], [0.0, 1.0, 0.0])


def test_guard_metrics_without_a_guard_and_without_commands():
    # Catches: the paper's chain reported as if guarded (it has no guard: None), and a
    # deployed run in which the guard issued nothing failing on the empty arrays (the
    # largest cut is then zero per joint, every FD statistic empty).
    record = _hand_record()
    assert guard_metrics(dataclasses.replace(record, guard=None)) is None
    empty = dataclasses.replace(record.guard, command_t_s=np.zeros(0),
                                q_commanded=np.zeros((0, 3)), q_followed=np.zeros((0, 3)),
                                limited_count=0, accepted_count=0)
    metrics = guard_metrics(dataclasses.replace(record, guard=empty))
    assert metrics["commands"] == 0 and metrics["limited"] == 0
    assert metrics["largest_cut_rad"] == [0.0, 0.0, 0.0]
    assert metrics["received"]["fd_acceleration"]["num_samples"] == 0
