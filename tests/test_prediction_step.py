"""The predicted robot as a pure step (``telesmooth.link.prediction``).

Hand-made telemetry with known answers: each prediction is measured by the sample of its
instant (not one off the grid, not one after a newer sample dropped it), the newest sample
and the 2 s window follow the samples' instants whatever their arrival order, the robot's
clock is the medians the docstring states; the copies follow the newest telemetry they may
use (on the bus, no further than the packets known), are re-synchronised when due but not
during a catch-up, and a catch-up runs at most its budget per update and is shown once it
reaches now. Over random streams (reordered and off-grid samples, random predictions) the
residual shown equals the largest residual over the run's whole log as ``recent_residual``
reads it (the step keeps only a suffix), and the step never changes the state it is given.
The Drake system's outputs are the step's, run here on the same packets with the copy's
predictions fed in, and the horizons it recorded are those of the step's actions.
"""

import copy
import pickle

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from telesmooth.lcm_types import lcmt_onboard_joint_status, lcmt_teleop_joint_command
from telesmooth.link.prediction import (
    AdvanceSynced,
    Build,
    ClockParams,
    FrozenMap,
    PredictorParams,
    PredictorView,
    RestSynced,
    Resync,
    advance_step,
    clock_newest,
    clock_packet,
    clock_telemetry,
    prediction_now,
    predictor_initial_state,
    receive_step,
    record_step,
    telemetry_sample,
)

J = 3
GRID = 0.01
PARAMS = PredictorParams(num_joints=J, sample_period_s=GRID, residual_window_s=0.5,
                         residual_history=1000, clock=None)
NAN_VIEW = PredictorView(np.full(J, np.nan), np.full(3, np.nan), np.full(J, np.nan),
                         np.full(3, np.nan), np.inf, np.inf, np.nan, -1.0, np.nan)


def _status(sample_t, *, tool=(0.0, 0.0, 0.0), joints=J, seq=-1, sent_delay=0.001, mode=0):
    msg = lcmt_onboard_joint_status()
    msg.num_joints = joints
    msg.sample_utime = int(round(sample_t * 1e6))
    msg.utime = int(round((sample_t + sent_delay) * 1e6))
    q = [0.1 * sample_t] * joints
    msg.joint_position_link = msg.joint_position_motor = q
    msg.joint_velocity_link = msg.joint_velocity_motor = [0.0] * joints
    msg.joint_position_commanded = q
    msg.tool_position_measured = list(tool)
    msg.last_command_seq = seq
    msg.guard_mode = mode
    msg.stream_distance_rad = 0.25 * sample_t
    return msg


class Packets:
    """A ``packets`` port's value: every (arrival number, bytes) so far."""

    def __init__(self):
        self.items = ()

    def send(self, *msgs):
        self.items += tuple((len(self.items) + 1 + i, m.encode()) for i, m in enumerate(msgs))
        return self.items


def _predict(state, now, tool, params=PARAMS):
    return record_step(params, state, now=now, horizon_s=0.5, tool=np.asarray(tool, float),
                       q=np.zeros(J), local_t_s=now, view=NAN_VIEW)


def test_a_prediction_is_measured_by_the_sample_of_its_instant():
    state = predictor_initial_state(PARAMS)
    telemetry = Packets()
    for t, tool in ((0.04, (1.0, 0.0, 0.0)), (0.08, (0.0, 2.0, 0.0)), (0.12, (0.0, 0.0, 3.0))):
        state, view = _predict(state, t, tool)
    # 0.04 measured exactly; 0.0805 is off the grid (measures nothing); 0.12 measured.
    state, received = receive_step(PARAMS, state, telemetry.send(
        _status(0.04), _status(0.0805), _status(0.12, tool=(0.0, 0.0, 1.0))), (), 0.2)
    assert [r.t_s for r in received.residuals] == [0.04, 0.12]
    assert [r.residual_m for r in received.residuals] == [1.0, 2.0]
    # The 0.08 prediction is older than the newest sample now: dropped at the next record.
    state, view = _predict(state, 0.16, (0.0, 0.0, 0.0))
    assert sorted(state.ledger) == [16]
    assert view.residual_m == 2.0 and view.telemetry_age_s == pytest.approx(0.04)
    assert view.guard_mode == 0.0 and view.stream_distance_rad == 0.25 * 0.12
    # The same packets again: nothing new (arrival numbers already read).
    again, received = receive_step(PARAMS, state, telemetry.items, (), 0.3)
    assert received == ((), (), ()) and again.newest is state.newest


def test_the_newest_and_the_window_follow_the_instants_not_the_arrivals():
    state = predictor_initial_state(PARAMS)
    telemetry = Packets()
    state, _ = receive_step(PARAMS, state, telemetry.send(
        _status(3.0), _status(0.5), _status(2.5), _status(1.0, joints=2)), (), 3.1)
    # The 2-joint message is another arm's; 0.5 s is more than 2 s before the newest.
    assert state.newest.sample_t_s == 3.0
    assert [s.sample_t_s for s in state.recent] == [2.5, 3.0]
    assert state.last_arrival_t_s == 3.1
    state, _ = receive_step(PARAMS, state, telemetry.send(_status(2.0)), (), 3.2)
    assert state.newest.sample_t_s == 3.0
    assert [s.sample_t_s for s in state.recent] == [2.0, 2.5, 3.0]


def test_the_robots_clock_and_now_on_it():
    clock_params = ClockParams(poll_period_s=0.01, publish_offset_s=0.001,
                               batch_period_s=0.04, window=3)
    params = PARAMS._replace(clock=clock_params)
    state = predictor_initial_state(params)
    assert prediction_now(params, state, 1.0) is None
    telemetry, uplink = Packets(), Packets()
    offsets = []
    for k, wait in enumerate((0.005, 0.4, 0.012, 0.008)):
        local = 0.1 * k + wait
        sent = 100.0 + 0.1 * k
        state, _ = receive_step(params, state, telemetry.send(
            _status(sent - 0.001, sent_delay=0.001, seq=k)), (), local)
        offsets.append(_status(sent - 0.001).utime * 1e-6 - local)
    # The median of the last three offsets, plus half a batch.
    expected = float(np.median(offsets[-3:])) + 0.02
    assert state.clock.robot_minus_local == expected
    assert prediction_now(params, state, 2.0) == GRID * np.ceil((2.0 + expected) / GRID - 1e-9)
    # Packets heard: seq 1 and 3 were named as accepted; their send times on the ground.
    command = lcmt_teleop_joint_command()
    command.num_joints = J
    command.joint_name = ["j"] * J
    command.joint_position_smoothed = command.joint_velocity_smoothed = [0.0] * J
    packets = []
    for seq, ground_t in ((1, 7.0), (3, 7.5), (5, 8.0)):
        msg = copy.deepcopy(command)
        msg.seq, msg.utime = seq, int(ground_t * 1e6)
        packets.append(msg)
    state, _ = receive_step(params, state, telemetry.items, uplink.send(*packets), 1.0)
    accepted = {k: _status(100.0 + 0.1 * k - 0.001).utime * 1e-6 - 0.001 for k in (1, 3)}
    ground = [accepted[1] - 7.0, accepted[3] - 7.5]
    assert state.clock.robot_minus_ground == float(np.median(ground)) - 0.005
    # The first telemetry built the copy at its commanded pose; the clock known, the packets
    # went to the copy in seq order, on the robot's clock, the session's fields cleared.
    assert state.pending == () and state.copies.built and state.copies.log_count == 3
    robot_minus_ground = state.clock.robot_minus_ground
    state, received = receive_step(params, state, telemetry.items, uplink.items, 1.1)
    assert received.actions == ()      # nothing new
    first = predictor_initial_state(params)
    _, received = receive_step(params, first, telemetry.items, uplink.items, 1.0)
    build, *appends = received.actions
    assert isinstance(build, Build)
    np.testing.assert_array_equal(build.q, [0.1 * (100.3 - 0.001)] * J)
    assert [a.message.seq for a in appends] == [1, 3, 5]
    assert [a.send_t_s for a in appends] == [t + robot_minus_ground for t in (7.0, 7.5, 8.0)]
    assert all(a.message.auth_tag_size == 0 and a.message.session_id == 0 for a in appends)


def test_the_clock_functions_against_a_plain_median():
    params = ClockParams(0.01, 0.001, 0.04, 4)
    state = predictor_initial_state(PARAMS._replace(clock=params)).clock
    rng = np.random.default_rng(3)
    offsets, ground = [], []
    for seq in range(12):
        arrival = float(rng.uniform(0, 1))
        sample = receive_sample = _sample_of(_status(5.0 + seq, seq=seq), arrival)
        state = clock_newest(params, state, receive_sample)
        offsets.append(sample.sent_t_s - arrival)
        assert state.robot_minus_local == float(np.median(offsets[-4:])) + 0.02
        state = clock_packet(params, state, seq, 0.5 * seq)
        state = clock_telemetry(params, state, sample)
        ground.append(sample.sent_t_s - 0.001 - 0.5 * seq)
        assert state.robot_minus_ground == float(np.median(ground[-4:])) - 0.005
    # A message naming an accepted packet again changes nothing.
    assert clock_telemetry(params, state, sample) is state


def _sample_of(msg, arrival):
    from telesmooth.link.prediction import telemetry_sample
    return telemetry_sample(msg, arrival, J)


def _oracle_largest(log, window):
    """The largest residual of the log's contiguous newest part within ``window`` of its
    newest one's instant."""
    if not log:
        return float("nan")
    newest, values = log[-1][0], []
    for t, r in reversed(log):
        if t < newest - window:
            break
        values.append(r)
    return max([0.0] + values)


EVENT = st.tuples(
    st.integers(0, 3),            # samples arriving this update
    st.integers(-3, 3),           # their spread (grid steps, reordered when negative)
    st.booleans(),                # one of them off the grid
    st.integers(0, 20),           # an outage: updates with no telemetry
    # The predicted tool's x (its residual |x − 0| is x exactly: no square underflows).
    st.integers(0, 10**6).map(lambda i: i * 1e-6))


@settings(derandomize=True, database=None, deadline=None, max_examples=40)
@given(stream=st.lists(EVENT, min_size=1, max_size=60),
       history=st.sampled_from([3, 1000]), window=st.sampled_from([0.05, 0.5]))
def test_over_random_streams_the_shown_residual_is_the_whole_logs(stream, history, window):
    params = PARAMS._replace(residual_history=history, residual_window_s=window)
    state = predictor_initial_state(params)
    telemetry = Packets()
    log, predicted, next_sample, t = [], {}, 0.0, 0.0
    for count, spread, off_grid, outage, x in stream:
        t = round(t + 0.04 * (1 + outage), 6)
        msgs = []
        for i in range(count):
            instant = round(next_sample + GRID * (abs(spread) * i), 6)
            msgs.append(_status(instant + (0.003 if off_grid and i == 0 else 0.0),
                                tool=(0.0, 0.0, 0.0)))
        next_sample = round(max([next_sample] + [m.sample_utime * 1e-6 for m in msgs])
                            + GRID, 6)
        if spread < 0:
            msgs.reverse()
        given, given_bytes = state, pickle.dumps(state)
        state, received = receive_step(params, state, telemetry.send(*msgs), (), t)
        assert pickle.dumps(given) == given_bytes    # the given state is not changed
        for residual in received.residuals:
            # Measured only against a prediction made for exactly that instant.
            key = round(residual.t_s / GRID)
            assert residual.residual_m == predicted[key]
            log.append((residual.t_s, residual.residual_m))
        del log[:-history]
        newest = state.newest
        if newest is not None:
            assert newest.sample_t_s == max(s.sample_t_s for s in state.recent)
            assert all(a.sample_t_s <= b.sample_t_s for a, b in zip(state.recent,
                                                                    state.recent[1:]))
        state, view = _predict(state, t, (x, 0.0, 0.0), params)
        predicted[round(t / GRID)] = x
        expected = _oracle_largest(log, window)
        assert view.residual_m == expected or (np.isnan(expected) and np.isnan(view.residual_m))


def test_the_drake_system_shows_what_the_step_computes():
    from telesmooth.diagrams.scenario import LoadScenario, initial_position
    from telesmooth.diagrams.teleop import MakePredictorReplica
    from telesmooth.systems.flexible_arm import MakeSimulator
    from telesmooth.systems.robot_predictor import RobotPredictor

    scenario = LoadScenario()
    q0 = initial_position(scenario, None)
    predictor = RobotPredictor(
        lambda start: MakePredictorReplica(scenario, initial_position_rad=start),
        num_joints=J, period_s=0.04, initial_position_rad=q0, sample_period_s=GRID,
        residual_window_s=0.3)
    simulator = MakeSimulator(predictor, scenario.onboard)
    context = simulator.get_mutable_context()
    predictor.get_uplink_message_input_port().FixValue(context, lcmt_teleop_joint_command())
    telemetry = Packets()
    port = predictor.get_telemetry_packets_input_port()
    port.FixValue(context, ())
    simulator.Initialize()
    params = PARAMS._replace(residual_window_s=0.3, resync_period_s=0.04,
                             catchup_budget_s=3.0 * 0.04)
    state, view = predictor_initial_state(params, q0), predictor.view(context)
    rng = np.random.default_rng(5)
    shown, seen = [], []
    for k in range(40):
        # Samples 0.2 s old, every 10 ms, arriving at each 40 ms update; a burst lost.
        instants = [round(0.04 * k - 0.2 - GRID * i, 6) for i in range(4)][::-1]
        msgs = [_status(s, tool=tuple(rng.normal(size=3) * 1e-3))
                for s in instants if s >= 0 and not 0.6 < s < 0.8]
        for m in msgs:
            m.joint_position_link = m.joint_position_motor = list(q0)
            m.joint_position_commanded = list(q0)
        seen.append(telemetry.send(*msgs))
        port.FixValue(context, seen[-1])
        simulator.AdvanceTo(0.04 * k + 0.02)    # the update at 0.04 k
        shown.append({name: predictor.get_output(name).Eval(context).copy() for name in (
            "q_predicted", "tool_predicted", "q_received", "tool_received", "telemetry_age",
            "telemetry_silence", "residual", "robot_guard_mode", "robot_stream_distance")})
    # The same packets through the step, the copy's predictions fed in.
    assert len(predictor.predictions) == 40
    residuals, kinds = [], set()
    for k, (items, values) in enumerate(zip(seen, shown)):
        t = 0.04 * k
        state, received = receive_step(params, state, items, (), t,
                                       lcmt_teleop_joint_command())
        # The fixed message (seq 0) goes to the copy's log once.
        assert _kinds(received.actions) == (["Append"] if k == 0 else [])
        residuals += received.residuals
        now, horizon, tool, q = predictor.predictions[k]
        assert now == prediction_now(params, state, t)
        state, actions = advance_step(params, state, now)
        kinds.update(type(action).__name__ for action in actions)
        assert horizon == now - state.copies.ahead_horizon_from
        state, view = record_step(params, state, now=now, horizon_s=horizon, tool=tool, q=q,
                                  local_t_s=t, view=view)
        for name, field in (("q_predicted", "q_predicted"), ("tool_predicted", "tool_predicted"),
                            ("q_received", "q_received"), ("tool_received", "tool_received"),
                            ("telemetry_age", "telemetry_age_s"),
                            ("telemetry_silence", "telemetry_silence_s"),
                            ("residual", "residual_m"), ("robot_guard_mode", "guard_mode"),
                            ("robot_stream_distance", "stream_distance_rad")):
            np.testing.assert_array_equal(values[name], np.atleast_1d(getattr(view, field)))
    assert kinds == {"AdvanceSynced", "Resync", "StartCatchup", "AdvanceCatchup", "Swap",
                     "AdvanceAhead"}
    assert len(residuals) == len(predictor.residuals) > 10
    assert [r.residual_m for r in residuals] == [r.residual_m for r in predictor.residuals]
    assert predictor.newest_telemetry.sample_t_s == state.newest.sample_t_s


def _kinds(actions):
    return [type(a).__name__ for a in actions]


def test_the_copies_follow_the_telemetry_and_catch_up_within_the_budget():
    params = PARAMS._replace(resync_period_s=0.04, catchup_budget_s=0.12)
    state = predictor_initial_state(params, np.zeros(J))
    telemetry = Packets()
    script = [   # (now, newest sample, the actions, the times they go to)
        (0.50, 0.20, ["AdvanceSynced", "Resync", "StartCatchup", "AdvanceCatchup",
                      "AdvanceAhead"], [0.20, None, None, 0.32, 0.50]),
        # Due again, but a catch-up runs: no re-synchronisation.
        (0.54, 0.24, ["AdvanceSynced", "AdvanceCatchup", "AdvanceAhead"], [0.24, 0.44, 0.54]),
        (0.58, 0.28, ["AdvanceSynced", "AdvanceCatchup", "AdvanceAhead"], [0.28, 0.56, 0.58]),
        # Caught up: shown, and already at now.
        (0.62, 0.32, ["AdvanceSynced", "AdvanceCatchup", "Swap"], [0.32, 0.62, None]),
        (0.66, 0.36, ["AdvanceSynced", "Resync", "StartCatchup", "AdvanceCatchup",
                      "AdvanceAhead"], [0.36, None, None, 0.48, 0.66]),
    ]
    sent = 0.0
    for now, newest, kinds, times in script:
        msgs = []
        while sent <= newest + 1e-9:
            msgs.append(_status(round(sent, 6)))
            sent += GRID
        state, _ = receive_step(params, state, telemetry.send(*msgs), (), now)
        state, actions = advance_step(params, state, now)
        assert _kinds(actions) == kinds
        for action, t in zip(actions, times):
            if t is not None:
                assert action.t_s == pytest.approx(t, abs=1e-12)
            if isinstance(action, Resync):
                assert action.sample.sample_t_s == pytest.approx(newest, abs=1e-12)
        if now == 0.62:
            assert state.copies.ahead_horizon_from == pytest.approx(0.20, abs=1e-12)
            assert state.copies.ahead_t == pytest.approx(0.62, abs=1e-12)
    assert state.copies.catchup_from == pytest.approx(0.36, abs=1e-12)


def test_on_the_bus_the_copy_waits_for_the_packets_it_knows():
    from telesmooth.link.prediction import ClockState, Copies, PredictorState, telemetry_sample

    params = PARAMS._replace(clock=ClockParams(0.01, 0.001), uplink_period_s=0.25)
    samples = tuple(telemetry_sample(_status(round(0.1 * k, 6)), 0.0, J) for k in range(30))
    state = PredictorState(recent=samples, newest=samples[-1],
                           clock=ClockState(robot_minus_local=0.0, robot_minus_ground=0.0),
                           copies=Copies(built=True, start=np.zeros(J)))
    # Nothing sent yet: the copy rests at the newest sample up to now, without running.
    _, actions = advance_step(params, state, 1.05)
    assert _kinds(actions)[:2] == ["RestSynced", "Resync"] and actions[0].t_s == 1.0
    assert isinstance(actions[0], RestSynced)
    # A packet sent at 1.0: known until the next is due (1.25), now until then.
    state = state._replace(copies=state.copies._replace(log_count=1, log_last_seq=0,
                                                        log_last_send_t=1.0))
    _, actions = advance_step(params, state, 1.4)
    assert isinstance(actions[0], AdvanceSynced) and actions[0].t_s == pytest.approx(1.2)
    # The ground quiet for more than two periods: known until now.
    _, actions = advance_step(params, state, 1.6)
    assert actions[0].t_s == pytest.approx(1.6)
    # In one process every sample may be used.
    local = PARAMS._replace(uplink_period_s=0.25)
    _, actions = advance_step(local, state._replace(clock=None), 2.0)
    assert actions[0].t_s == pytest.approx(2.9)


@settings(derandomize=True, database=None, deadline=None, max_examples=60)
@given(ops=st.lists(st.tuples(st.booleans(), st.integers(0, 30), st.integers()), max_size=80))
def test_a_frozen_map_is_a_dict_whose_versions_never_change(ops):
    # Oracle: a plain dict copied at every step; every earlier version still reads as it did.
    versions = [(FrozenMap(), {})]
    for is_set, key, value in ops:
        frozen, plain = versions[-1]
        if is_set:
            frozen, plain = frozen.set(key, value), {**plain, key: value}
        else:
            keys = [k for k in plain if k <= key]
            frozen = frozen.without(keys)
            plain = {k: v for k, v in plain.items() if k > key}
        versions.append((frozen, plain))
    for frozen, plain in versions:
        assert dict(frozen) == plain and len(frozen) == len(plain)
        assert all(frozen[k] == v and k in frozen for k, v in plain.items())
    assert versions[-1][0].without([]) is versions[-1][0]
    assert copy.deepcopy(versions[-1][0]) is versions[-1][0]


def test_a_telemetry_samples_arrays_are_read_only():
    sample = telemetry_sample(_status(0.5, tool=(0.1, 0.2, 0.3)), 0.6, J)
    for array in (sample.q_link, sample.q_motor, sample.v_link, sample.v_motor,
                  sample.tool_position_m, sample.q_commanded):
        with pytest.raises(ValueError, match="read-only"):
            array[0] = 1.0


@pytest.mark.parametrize(("field", "value"), [("residual_window_s", -1.0),
                                              ("residual_window_s", 0.0),
                                              ("residual_window_s", float("nan")),
                                              ("residual_history", -1),
                                              ("residual_history", 2.5)])
def test_the_predictor_refuses_a_residual_window_it_cannot_keep(field, value):
    from telesmooth.systems.robot_predictor import RobotPredictor

    with pytest.raises(ValueError, match=f"RobotPredictor.{field} = "):
        RobotPredictor(lambda start: None, num_joints=J, remote=True, **{field: value})
