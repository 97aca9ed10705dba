"""Property-based fuzzing of the live path: bytes on the LCM channel → subscriber → receiver, in
the process diagrams.

The contract, the conventions and the shared generators: tests/fuzz_helpers.py (a bad
input gets a clear ValueError or a held, flagged output; never another exception; what was
accepted is not altered).
"""

from __future__ import annotations

import numpy as np
from fuzz_helpers import (
    DECODE_ERRORS,
    _decode,
    _haptic_command,
    _joint_command,
    fuzz,
)
from hypothesis import assume, example, given
from hypothesis import strategies as st

from telesmooth.lcm_types import (
    decode_exact,
    lcmt_teleop_haptic_command,
    lcmt_teleop_joint_command,
)
from telesmooth.systems.haptic_command_receiver import (
    HapticCommandReceiver,
)

# ======================================================================================
# The live path: bytes on the LCM channel -> subscriber -> receiver (a whole process)
# ======================================================================================


# Regression (fixed): diagrams/teleoperation.py MakeOnboardDiagram (and AddOperatorTargets for
# the live haptic device) connect a plain LcmSubscriberSystem, which decodes inside the
# simulator's event handling; one malformed packet on TELEOP_JOINT_COMMAND (e.g. b'garbage' ->
# ValueError('Decode error'), or a truncated valid packet -> struct.error) makes every later
# Simulator.AdvanceTo raise, i.e. the onboard process dies (exit 2, or a traceback for
# struct.error) instead of holding the last accepted command and raising command_rejected. The
# same holds for TELEOP_HAPTIC_COMMAND in the ground process.
@fuzz(15)
@example(kind="joint", payload=b"garbage")
@example(kind="haptic", payload=b"")
@given(kind=st.sampled_from(["joint", "haptic"]),
       payload=st.one_of(st.binary(max_size=40), st.sampled_from([b"", b"garbage"])))
def test_malformed_packets_on_the_channel_do_not_stop_the_receiver(kind, payload):
    # The process diagrams themselves: onboard (TELEOP_JOINT_COMMAND) and a ground station
    # with a live haptic device (TELEOP_HAPTIC_COMMAND), on a private memq:// bus.
    from pydrake.lcm import DrakeLcm
    from pydrake.systems.analysis import Simulator

    from telesmooth.diagrams.scenario import LoadScenario
    from telesmooth.diagrams.teleoperation import MakeGroundDiagram, MakeOnboardDiagram

    lcm = DrakeLcm("memq://")
    if kind == "joint":
        lcm_type, channel = lcmt_teleop_joint_command, "TELEOP_JOINT_COMMAND"
        handles = MakeOnboardDiagram(LoadScenario(), lcm=lcm)
        receiver = handles.onboard.receiver
        subscriber = handles.diagram.GetSubsystemByName("joint_command_subscriber")
        arm = handles.scenario.arm_description
        names = list(arm.joint_names)
        middle = (np.asarray(arm.joint_lower_rad) + np.asarray(arm.joint_upper_rad)) / 2
        first, second = middle + 0.01, middle - 0.02
        packets = [_joint_command(seq, names, list(q)) for seq, q in enumerate((first, second))]
        output = receiver.get_q_commanded_output_port()
        rejected = receiver.get_command_rejected_output_port()
    else:
        lcm_type, channel = lcmt_teleop_haptic_command, "TELEOP_HAPTIC_COMMAND"
        handles = MakeGroundDiagram(LoadScenario(scenario_text="{haptic: {source: lcm}}"),
                                    lcm=lcm)
        receiver = handles.ground.haptic
        assert isinstance(receiver, HapticCommandReceiver)
        subscriber = handles.diagram.GetSubsystemByName("haptic_subscriber")
        first, second = [0.72, 0.01, 0.0], [0.71, -0.01, 0.0]
        packets = [_haptic_command(utime, pose) for utime, pose in ((1, first), (2, second))]
        output = receiver.get_pose_desired_output_port()
        rejected = receiver.get_message_rejected_output_port()
    assume(payload[:8] != lcm_type._get_packed_fingerprint())
    simulator = Simulator(handles.diagram)
    simulator.Initialize()
    root = simulator.get_context()
    context = receiver.GetMyContextFromRoot(root)
    subscriber_context = subscriber.GetMyContextFromRoot(root)
    lcm.Publish(channel, packets[0].encode())
    simulator.AdvanceTo(0.05)
    np.testing.assert_array_equal(output.Eval(context), first)
    assert rejected.Eval(context)[0] == 0.0
    lcm.Publish(channel, payload)
    simulator.AdvanceTo(0.1)    # must not raise: the robot holds, and says so
    np.testing.assert_array_equal(output.Eval(context), first)
    assert rejected.Eval(context)[0] == 1.0
    assert subscriber.get_undecodable_count_output_port().Eval(subscriber_context)[0] == 1.0
    error = subscriber.get_last_decode_error_output_port().Eval(subscriber_context)
    assert error.startswith(f"{channel}: packet 2 ({len(payload)} bytes) is not a valid "
                            f"{lcm_type.__name__}: "), error
    lcm.Publish(channel, packets[1].encode())   # the next good packet gets through
    simulator.AdvanceTo(0.15)
    np.testing.assert_array_equal(output.Eval(context), second)
    assert rejected.Eval(context)[0] == 0.0
    assert subscriber.get_message_count_output_port().Eval(subscriber_context)[0] == 2.0


def test_every_cut_of_a_signed_command_and_an_extra_byte_are_refused_exactly():
    # Exhaustive: every prefix of a signed command (the HMAC tag last, where the generated
    # decoder reads a short tag without complaint) and one extra byte are decode errors.
    msg = lcmt_teleop_joint_command()
    msg.seq, msg.session_id, msg.num_joints = 5, 77, 2
    msg.joint_name = ["shoulder", "elbow"]
    msg.joint_position_smoothed = [0.1, 0.2]
    msg.joint_velocity_smoothed = [0.0, 0.0]
    msg.auth_tag = bytes(range(32))
    msg.auth_tag_size = 32
    encoded = msg.encode()
    assert lcmt_teleop_joint_command.decode(encoded[:-1]).auth_tag == bytes(range(31))
    for cut in range(len(encoded)):
        assert isinstance(_decode(lcmt_teleop_joint_command, encoded[:cut]), DECODE_ERRORS), cut
    assert isinstance(_decode(lcmt_teleop_joint_command, encoded + b"\x00"), DECODE_ERRORS)
    assert decode_exact(lcmt_teleop_joint_command, encoded).auth_tag == bytes(range(32))
