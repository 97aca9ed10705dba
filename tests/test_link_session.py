"""Freshness of uplink commands (link/session.py and the receiver's use of it): the onboard
epoch refuses every packet of an earlier onboard run, the session counter lets a restarted
ground in at once and refuses a session that skips ahead, so nothing can lock the real ground
out. The process-level tests are in test_process_sessions.py."""

import numpy as np
import pytest

from telesmooth.lcm_types import lcmt_teleop_joint_command
from telesmooth.link.auth import sign
from telesmooth.link.session import (
    EPOCH_BITS,
    classify_session,
    new_epoch,
    new_ground_nonce,
    next_session,
    session_counter,
    session_id,
)
from telesmooth.systems.joint_command_receiver import (
    REJECTION_CLASSES,
    JointCommandReceiver,
    JointCommandReceiverConfig,
    PacketClass,
    classify_joint_command,
)
from telesmooth.systems.joint_command_sender import JointCommandSender

KEY = b"k" * 32
JOINTS = ("shoulder", "elbow")
LOWER, UPPER = [-3.0, -3.0], [3.0, 3.0]


def _command(seq, session, epoch, q=(0.1, 0.2)):
    msg = lcmt_teleop_joint_command()
    msg.seq, msg.session_id, msg.onboard_epoch = seq, session, epoch
    msg.num_joints = len(JOINTS)
    msg.joint_name = list(JOINTS)
    msg.joint_position_smoothed = list(q)
    msg.joint_velocity_smoothed = [0.0] * len(JOINTS)
    return sign(msg, KEY)


@pytest.mark.parametrize("session, seq, last, expected", [
    (session_id(1, 5), 0, None, "accepted"),            # the first ground of an epoch
    (0, 0, None, "accepted"),                           # in process: session 0
    (session_id(2, 5), 0, None, "session"),             # skips counter 1
    (session_id(1, 5), 8, (session_id(1, 5), 7), "accepted"),
    (session_id(1, 5), 7, (session_id(1, 5), 7), "duplicate"),
    (session_id(1, 5), 6, (session_id(1, 5), 7), "stale"),
    (session_id(2, 9), 0, (session_id(1, 5), 7), "accepted"),     # a restarted ground
    (session_id(2, 9), 500, (session_id(1, 5), 7), "accepted"),   # any seq
    (session_id(1, 9), 500, (session_id(1, 5), 7), "stale"),      # same counter, not ours
    (session_id(0, 0), 500, (session_id(1, 5), 7), "stale"),      # an earlier session
    (session_id(3, 9), 0, (session_id(1, 5), 7), "session"),      # skips ahead
    (session_id(2**21 - 1, 0), 0, (session_id(1, 5), 7), "session"),
])
def test_the_session_rule(session, seq, last, expected):
    assert classify_session(session, seq, last)[0] == expected


def test_session_ids_epochs_and_nonces():
    nonce = new_ground_nonce()
    assert 0 <= nonce < 2**32
    s = next_session(session_id(6, 123), nonce)
    assert session_counter(s) == 7 and s & 0xFFFFFFFF == nonce
    assert next_session(0, nonce) == session_id(1, nonce)
    assert float(session_id(2**21 - 1, 2**32 - 1)) == session_id(2**21 - 1, 2**32 - 1)
    epochs = {new_epoch() for _ in range(50)}
    assert len(epochs) == 50 and all(0 < e < 2**EPOCH_BITS for e in epochs)
    assert all(float(e) == e for e in epochs)      # exact in a float64 Context
    with pytest.raises(ValueError, match="session counter"):
        session_id(2**21, 0)
    with pytest.raises(ValueError, match="session nonce"):
        session_id(1, 2**32)


def _receiver(epoch):
    return JointCommandReceiver(
        JointCommandReceiverConfig(authentication="required"), joint_names=JOINTS,
        lower_rad=LOWER, upper_rad=UPPER, initial_position_rad=[0.0, 0.0], uplink_key=KEY,
        onboard_epoch=epoch)


class _Feed:
    """Feeds packets to a receiver by hand (its forced update)."""

    def __init__(self, receiver):
        self.receiver = receiver
        self.context = receiver.CreateDefaultContext()
        self.packets = []

    def send(self, *messages):
        for msg in messages:
            self.packets.append((len(self.packets), msg.encode()))
        self.receiver.get_packets_input_port().FixValue(self.context, tuple(self.packets))
        self.receiver.CalcForcedUnrestrictedUpdate(self.context,
                                                   self.context.get_mutable_state())
        return self.receiver.rejection_counts(self.context)

    @property
    def q(self):
        return self.receiver.get_q_commanded_output_port().Eval(self.context)


def test_a_restarted_onboard_accepts_no_packet_of_its_previous_run():
    first, second = new_epoch(), new_epoch()
    ground = session_id(1, 77)
    captured = [_command(k, ground, first, (0.01 * k, 0.0)) for k in range(10)]
    before = _Feed(_receiver(first))
    assert before.send(*captured)["accepted"] == 10
    after = _Feed(_receiver(second))         # the onboard process restarted: a new epoch
    counts = after.send(*captured)
    assert counts["accepted"] == 0 and counts["session"] == 10
    np.testing.assert_array_equal(after.q, [0.0, 0.0])
    # Even a captured packet re-signed... cannot be: the attacker has no key. A key holder's
    # far-future session of the new epoch is refused too, and the real ground goes on.
    assert after.send(_command(0, session_id(1, 5), second, (0.3, 0.3)))["accepted"] == 1
    far = _command(0, session_id(2**20, 1), second, (2.0, 2.0))
    counts = after.send(far)
    assert counts["session"] == 11 and counts["accepted"] == 1
    assert after.send(_command(1, session_id(1, 5), second, (0.4, 0.4)))["accepted"] == 2
    np.testing.assert_array_equal(after.q, [0.4, 0.4])
    # A restarted ground (the next counter) is accepted at once, with any seq.
    assert after.send(_command(57, session_id(2, 6), second, (0.5, 0.5)))["accepted"] == 3
    # ... and the first ground's packets are then stale.
    counts = after.send(_command(2, session_id(1, 5), second))
    assert counts["stale"] == 1 and counts["accepted"] == 3
    assert REJECTION_CLASSES[-1] == "session"


def test_classify_names_the_epoch():
    msg = _command(0, session_id(1, 5), 41)
    kind, reason = classify_joint_command(msg, last_accepted=None, joint_names=JOINTS,
                                          lower_rad=LOWER, upper_rad=UPPER, key=KEY,
                                          onboard_epoch=42)
    assert kind == PacketClass.SESSION
    assert "onboard_epoch = 41 is not this onboard run's 42" in reason
    # The epoch is covered by the tag: changing it breaks the signature.
    msg.onboard_epoch = 42
    kind, _ = classify_joint_command(msg, last_accepted=None, joint_names=JOINTS,
                                     lower_rad=LOWER, upper_rad=UPPER, key=KEY,
                                     onboard_epoch=42)
    assert kind == PacketClass.AUTH
    with pytest.raises(ValueError, match="onboard_epoch = -1"):
        _receiver(-1)


def test_the_sender_carries_the_epoch_and_session_and_withholds_without_telemetry():
    dut = JointCommandSender(joint_names=JOINTS, delay_s=0.75, session_id=3, uplink_key=KEY)
    context = dut.CreateDefaultContext()
    dut.get_q_sent_input_port().FixValue(context, [0.1, 0.2])
    dut.get_sequence_number_input_port().FixValue(context, [5.0])
    dut.get_send_time_input_port().FixValue(context, [1.25])
    msg = dut.get_lcm_message_output_port().Eval(context)
    assert (msg.seq, msg.session_id, msg.onboard_epoch) == (5, 3, 0)   # in process
    dut.get_onboard_epoch_input_port().FixValue(context, [0.0])
    dut.get_session_id_input_port().FixValue(context, [float(session_id(2, 9))])
    msg = dut.get_lcm_message_output_port().Eval(context)
    assert msg.seq == -1 and msg.auth_tag_size == 0       # no telemetry: not addressed
    epoch = new_epoch()
    dut.get_onboard_epoch_input_port().FixValue(context, [float(epoch)])
    msg = dut.get_lcm_message_output_port().Eval(context)
    assert (msg.seq, msg.session_id, msg.onboard_epoch) == (5, session_id(2, 9), epoch)
    kind, _ = classify_joint_command(msg, last_accepted=(session_id(1, 4), 80),
                                     joint_names=JOINTS, lower_rad=LOWER, upper_rad=UPPER,
                                     key=KEY, onboard_epoch=epoch)
    assert kind == PacketClass.ACCEPTED
