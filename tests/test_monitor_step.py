"""The ground's link monitor as a pure step (``telesmooth.link.monitor``), without Drake.

Scripted telemetry with known answers: the first telemetry of an epoch moves this ground run
to the session after the robot's last accepted one (with its nonce); the packets sent and not
acknowledged in that session; a new flagged rejection or the robot's flag degrades the link
for that poll; old telemetry is lost; a message whose count did not change is not read again.
Over random streams the state round-trips through the Context's codec and the step never
changes the state it is given.
"""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from telesmooth.lcm_types import lcmt_onboard_joint_status
from telesmooth.link.monitor import (
    LINK_STATUSES,
    LinkStatus,
    MonitorInputs,
    MonitorParams,
    monitor_initial_state,
    monitor_step,
)
from telesmooth.link.session import next_session, session_id
from telesmooth.safety.state_codec import VectorCodec

NONCE = 7
PARAMS = MonitorParams(telemetry_timeout_s=1.0, max_unacknowledged=4, session_nonce=NONCE)


def _telemetry(*, epoch=11, session=0, seq=-1, mode=0, invalid=0, rejected=False):
    msg = lcmt_onboard_joint_status()
    msg.onboard_epoch, msg.last_command_session_id, msg.last_command_seq = epoch, session, seq
    msg.guard_mode, msg.rejected_invalid_count, msg.command_rejected = mode, invalid, rejected
    return msg


def test_the_labels():
    assert LINK_STATUSES == ("no-telemetry", "ok", "degraded", "lost")


def test_a_script_of_telemetry():
    state = monitor_initial_state()
    state = monitor_step(PARAMS, state, MonitorInputs(now=0.0, count=0, sent=-1))
    assert state.status == LinkStatus.NO_TELEMETRY
    # The first telemetry: epoch 11, the robot accepted session (3, 99) last.
    robot = session_id(3, 99)
    state = monitor_step(PARAMS, state, MonitorInputs(
        now=0.1, count=1, sent=-1, message=_telemetry(session=robot, seq=20)))
    ours = next_session(robot, NONCE)
    assert (state.epoch, state.session) == (11, ours) and ours == session_id(4, NONCE)
    assert state.status == LinkStatus.OK and state.unacknowledged == 0
    # We sent 6 packets of our session, the robot accepted seq 0 of it: 5 behind > 4.
    state = monitor_step(PARAMS, state, MonitorInputs(
        now=0.2, count=2, sent=5, message=_telemetry(session=ours, seq=0)))
    assert state.unacknowledged == 5 and state.status == LinkStatus.DEGRADED
    state = monitor_step(PARAMS, state, MonitorInputs(
        now=0.3, count=3, sent=5, message=_telemetry(session=ours, seq=4)))
    assert state.unacknowledged == 1 and state.status == LinkStatus.OK
    # A new invalid packet on the robot: degraded for the poll that reads it.
    state = monitor_step(PARAMS, state, MonitorInputs(
        now=0.4, count=4, sent=5, message=_telemetry(session=ours, seq=5, invalid=1)))
    assert state.status == LinkStatus.DEGRADED and state.counts.rejected.invalid == 1
    state = monitor_step(PARAMS, state, MonitorInputs(
        now=0.45, count=4, sent=5, message=_telemetry(mode=2)))   # same count: not read
    assert state.status == LinkStatus.OK and state.guard_mode == 0
    # Silence: lost once the newest telemetry is more than 1 s old.
    state = monitor_step(PARAMS, state, MonitorInputs(now=1.4, count=4, sent=5))
    assert state.status == LinkStatus.OK
    state = monitor_step(PARAMS, state, MonitorInputs(now=1.41, count=4, sent=5))
    assert state.status == LinkStatus.LOST
    # A restarted robot (another epoch): the session follows it.
    state = monitor_step(PARAMS, state, MonitorInputs(
        now=1.5, count=5, sent=5, message=_telemetry(epoch=12, session=0, mode=2)))
    assert (state.epoch, state.session) == (12, next_session(0, NONCE))
    assert state.status == LinkStatus.DEGRADED and state.unacknowledged == 6


def test_without_a_nonce_the_session_stays():
    params = MonitorParams(session_nonce=None)
    state = monitor_initial_state(session_id=5, onboard_epoch=0)
    state = monitor_step(params, state, MonitorInputs(
        now=0.1, count=1, sent=3, message=_telemetry(epoch=11, session=5, seq=1)))
    assert (state.epoch, state.session, state.unacknowledged) == (0, 5, 2)


@settings(derandomize=True, database=None, deadline=None, max_examples=30)
@given(stream=st.lists(st.tuples(st.booleans(), st.integers(0, 3), st.integers(-1, 30),
                                 st.integers(0, 3)), min_size=1, max_size=30))
def test_codec_round_trip_and_purity_over_streams(stream):
    state = monitor_initial_state()
    codec = VectorCodec(state)
    count = 0
    for k, (new, epoch, seq, mode) in enumerate(stream):
        count += new
        vector = codec.pack(state)
        given_state = codec.unpack(vector)
        np.testing.assert_array_equal(codec.pack(given_state), vector)
        state = monitor_step(PARAMS, given_state, MonitorInputs(
            now=0.05 * k, count=count, sent=seq + 2,
            message=_telemetry(epoch=epoch, seq=seq, mode=mode)))
        np.testing.assert_array_equal(codec.pack(given_state), vector)
        assert state.unacknowledged >= 0 and state.status in LinkStatus
