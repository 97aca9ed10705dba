"""LCM translator systems: uplink over memq://, onboard validation and hold, haptic receiver."""

import numpy as np
import pytest
from pydrake.lcm import DrakeLcm
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.lcm import LcmInterfaceSystem, LcmPublisherSystem, LcmSubscriberSystem
from test_ground_chain import TickTable

from telesmooth.lcm_types import (
    lcmt_onboard_joint_status,
    lcmt_teleop_collision_event,
    lcmt_teleop_haptic_command,
    lcmt_teleop_joint_command,
)
from telesmooth.lcm_types.channels import TELEOP_JOINT_COMMAND
from telesmooth.systems.collision_event_sender import CollisionEventSender
from telesmooth.systems.haptic_command_receiver import (
    HapticCommandReceiver,
    HapticCommandReceiverConfig,
)
from telesmooth.systems.joint_command_receiver import (
    JointCommandReceiver,
    JointCommandReceiverConfig,
)
from telesmooth.systems.joint_command_sender import JointCommandSender
from telesmooth.systems.joint_status_sender import JointStatusSender
from telesmooth.systems.uplink import Uplink

JOINTS = ("shoulder", "elbow")
LOWER, UPPER = [-2.0, -2.0], [2.0, 2.0]


def test_uplink_packets_cross_lcm_and_are_accepted_onboard():
    lcm = DrakeLcm("memq://")
    builder = DiagramBuilder()
    builder.AddSystem(LcmInterfaceSystem(lcm))
    table = 0.01 * np.arange(12.0)[:, None] * np.array([[1.0, -1.0]])
    source = builder.AddSystem(TickTable(table))
    uplink = builder.AddSystem(Uplink(num_joints=2))
    sender = builder.AddSystem(JointCommandSender(joint_names=JOINTS, delay_s=0.75))
    publisher = builder.AddSystem(LcmPublisherSystem.Make(
        TELEOP_JOINT_COMMAND, lcmt_teleop_joint_command, lcm, publish_period=0.25,
        publish_offset=0.001))
    subscriber = builder.AddSystem(LcmSubscriberSystem.Make(
        TELEOP_JOINT_COMMAND, lcmt_teleop_joint_command, lcm))
    receiver = builder.AddSystem(JointCommandReceiver(
        joint_names=JOINTS, lower_rad=LOWER, upper_rad=UPPER, initial_position_rad=[0, 0]))
    builder.Connect(source.get_output_port(), uplink.get_q_smoothed_input_port())
    builder.Connect(uplink.get_q_sent_output_port(), sender.get_q_sent_input_port())
    builder.Connect(uplink.get_state_sent_output_port(), sender.get_state_sent_input_port())
    builder.Connect(uplink.get_sequence_number_output_port(),
                    sender.get_sequence_number_input_port())
    builder.Connect(uplink.get_send_time_output_port(), sender.get_send_time_input_port())
    builder.Connect(sender.get_lcm_message_output_port(), publisher.get_input_port())
    builder.Connect(subscriber.get_output_port(), receiver.get_lcm_message_input_port())
    received = []
    lcm.Subscribe(TELEOP_JOINT_COMMAND,
                  lambda data: received.append(lcmt_teleop_joint_command.decode(data)))
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = simulator.get_context()
    receiver_context = receiver.GetMyContextFromRoot(context)
    for k in range(10):
        simulator.AdvanceTo(k * 0.25 + 0.05)
        q = receiver.get_q_commanded_output_port().Eval(receiver_context)
        np.testing.assert_array_equal(q, table[k])
        assert receiver.get_last_command_seq_output_port().Eval(receiver_context)[0] == k
    assert [m.seq for m in received] == list(range(10))
    assert received[4].utime == 1_000_000 and received[4].sample_utime == 250_000
    assert list(received[4].joint_name) == list(JOINTS)


def _command(seq, positions, names=JOINTS):
    msg = lcmt_teleop_joint_command()
    msg.seq, msg.utime = seq, seq * 250_000
    msg.num_joints = len(positions)
    msg.joint_name = list(names)
    msg.joint_position_smoothed = list(positions)
    msg.joint_velocity_smoothed = [0.0] * len(positions)
    return msg


def test_receiver_rejects_unsafe_packets_and_holds():
    dut = JointCommandReceiver(JointCommandReceiverConfig(timeout_s=0.6), joint_names=JOINTS,
                               lower_rad=LOWER, upper_rad=UPPER,
                               initial_position_rad=[0.1, 0.2])
    context = dut.CreateDefaultContext()
    port = dut.get_lcm_message_input_port()

    def deliver(msg, t):
        context.SetTime(t)
        port.FixValue(context, msg)
        dut.CalcForcedUnrestrictedUpdate(context, context.get_mutable_state())
        return (dut.get_q_commanded_output_port().Eval(context).copy(),
                dut.get_command_rejected_output_port().Eval(context)[0],
                dut.get_last_command_seq_output_port().Eval(context)[0])

    assert deliver(lcmt_teleop_joint_command(), 0.0)[2] == -1   # nothing yet: initial pose
    q, rejected, seq = deliver(_command(0, [0.3, 0.4]), 0.01)
    np.testing.assert_array_equal(q, [0.3, 0.4])
    assert (rejected, seq) == (0.0, 0.0)
    for bad in (_command(1, [np.nan, 0.4]), _command(2, [0.3, 2.5]),
                _command(3, [0.3, 0.4], names=("elbow", "shoulder")),
                _command(4, [0.3, 0.4, 0.5], names=JOINTS + ("wrist",))):
        q, rejected, seq = deliver(bad, 0.02)
        np.testing.assert_array_equal(q, [0.3, 0.4])
        assert rejected == 1.0 and seq == 0.0
    q, rejected, seq = deliver(_command(5, [0.5, 0.6]), 0.03)
    np.testing.assert_array_equal(q, [0.5, 0.6])
    assert (rejected, seq) == (0.0, 5.0)
    q, rejected, seq = deliver(_command(2, [1.0, 1.0]), 0.04)   # stale: ignored
    np.testing.assert_array_equal(q, [0.5, 0.6])
    assert dut.get_command_timeout_output_port().Eval(context)[0] == 0.0
    deliver(_command(5, [0.5, 0.6]), 0.7)                        # silence: 0.67 s > 0.6 s
    assert dut.get_command_timeout_output_port().Eval(context)[0] == 1.0
    np.testing.assert_array_equal(dut.get_q_commanded_output_port().Eval(context), [0.5, 0.6])


def test_receiver_constructor_errors_name_joint_and_value():
    with pytest.raises(ValueError, match=r"initial_position_rad\[1\] = 3.0 for joint 1 "
                                         r"\('elbow'\) must be finite and within"):
        JointCommandReceiver(joint_names=JOINTS, lower_rad=LOWER, upper_rad=UPPER,
                             initial_position_rad=[0.0, 3.0])
    with pytest.raises(ValueError, match=r"timeout_s = -1"):
        JointCommandReceiverConfig(timeout_s=-1)


def _haptic(utime, pose, enable=True):
    msg = lcmt_teleop_haptic_command()
    msg.utime, msg.num_axes, msg.pose_desired, msg.enable = utime, len(pose), list(pose), enable
    return msg


def test_haptic_receiver_disengages_on_silence_and_bad_messages():
    dut = HapticCommandReceiver(HapticCommandReceiverConfig(timeout_s=0.1),
                                initial_pose=[0.7, 0.0, 0.0])
    context = dut.CreateDefaultContext()
    port = dut.get_lcm_message_input_port()

    def deliver(msg, t):
        context.SetTime(t)
        port.FixValue(context, msg)
        dut.CalcForcedDiscreteVariableUpdate(context, context.get_mutable_discrete_state())
        return (dut.get_pose_desired_output_port().Eval(context).copy(),
                dut.get_enable_output_port().Eval(context)[0])

    pose, enable = deliver(lcmt_teleop_haptic_command(), 0.0)
    np.testing.assert_array_equal(pose, [0.7, 0.0, 0.0])
    assert enable == 0.0                                   # no device yet: clutch off
    pose, enable = deliver(_haptic(1, [0.8, 0.1, 0.2]), 0.01)
    np.testing.assert_array_equal(pose, [0.8, 0.1, 0.2])
    assert enable == 1.0
    pose, enable = deliver(_haptic(2, [0.8, np.nan, 0.2]), 0.02)
    np.testing.assert_array_equal(pose, [0.8, 0.1, 0.2])
    assert enable == 0.0 and dut.get_message_rejected_output_port().Eval(context)[0] == 1.0
    pose, enable = deliver(_haptic(3, [0.9, 0.1, 0.2]), 0.03)
    assert enable == 1.0
    context.SetTime(0.2)                                   # 0.17 s of silence
    assert dut.get_enable_output_port().Eval(context)[0] == 0.0
    pose, enable = deliver(_haptic(4, [0.9, 0.1]), 0.21)  # wrong number of axes
    assert enable == 0.0
    np.testing.assert_array_equal(pose, [0.9, 0.1, 0.2])


def test_status_and_collision_messages_carry_their_inputs():
    status = JointStatusSender(num_joints=2)
    context = status.CreateDefaultContext()
    context.SetTime(0.5)
    status.get_q_link_input_port().FixValue(context, [0.1, 0.2])
    status.get_q_motor_input_port().FixValue(context, [0.11, 0.19])
    status.get_position_measured_input_port().FixValue(context, [1.0, 0.5, 0.0])
    status.get_command_timeout_input_port().FixValue(context, [1.0])
    msg = status.get_lcm_message_output_port().Eval(context)
    assert isinstance(msg, lcmt_onboard_joint_status)
    assert (msg.utime, msg.seq, msg.num_joints) == (500_000, 50, 2)
    assert list(msg.joint_position_motor) == [0.11, 0.19]
    assert list(msg.tool_position_measured) == [1.0, 0.5, 0.0]
    assert (msg.last_command_seq, msg.command_rejected, msg.command_timeout) == (-1, False, True)
    lcmt_onboard_joint_status.decode(msg.encode())

    event = CollisionEventSender()
    context = event.CreateDefaultContext()
    context.SetTime(1.25)
    event.get_collision_detected_input_port().FixValue(context, [1.0])
    event.get_holding_input_port().FixValue(context, [1.0])
    event.get_min_distance_input_port().FixValue(context, [-0.004])
    event.get_sequence_number_input_port().FixValue(context, [5.0])
    msg = event.get_lcm_message_output_port().Eval(context)
    assert isinstance(msg, lcmt_teleop_collision_event)
    assert (msg.utime, msg.seq, msg.collision_detected, msg.holding) == (1_250_000, 5, True, True)
    assert msg.min_distance_m == -0.004


def test_uplink_key_errors_name_the_field():
    required = JointCommandReceiverConfig(authentication="required")
    with pytest.raises(ValueError, match="uplink_key = None but .*authentication = 'required'"):
        JointCommandReceiver(required, joint_names=JOINTS, lower_rad=LOWER, upper_rad=UPPER,
                             initial_position_rad=[0.0, 0.0])
    with pytest.raises(ValueError, match="uplink_key: 5 bytes, need at least 16"):
        JointCommandReceiver(required, joint_names=JOINTS, lower_rad=LOWER, upper_rad=UPPER,
                             initial_position_rad=[0.0, 0.0], uplink_key=b"short")
    with pytest.raises(ValueError, match="uplink_key: must be bytes, got str"):
        JointCommandSender(joint_names=JOINTS, delay_s=0.75, uplink_key="0" * 32)
    with pytest.raises(ValueError, match="authentication = 'maybe'"):
        JointCommandReceiverConfig(authentication="maybe")
