"""LcmSafeSubscriber: malformed packets are counted and flagged, never raised (memq:// only)."""

import copy as copy_module

import numpy as np
import pytest
from process_fixtures import worker_port
from pydrake.lcm import DrakeLcm
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.lcm import LcmInterfaceSystem, LcmSubscriberSystem

from telesmooth.diagrams.scenario import LoadScenario
from telesmooth.diagrams.teleoperation import MakeGroundDiagram, MakeOnboardDiagram
from telesmooth.lcm_types import (
    lcmt_onboard_joint_status,
    lcmt_teleop_haptic_command,
    lcmt_teleop_joint_command,
)
from telesmooth.lcm_types.channels import (
    ONBOARD_JOINT_STATUS,
    TELEOP_HAPTIC_COMMAND,
    TELEOP_JOINT_COMMAND,
)
from telesmooth.systems.joint_command_receiver import JointCommandReceiver
from telesmooth.systems.lcm_safe_subscriber import LcmSafeSubscriber

JOINTS = ("shoulder", "elbow")


def _command(seq, positions, names=JOINTS):
    msg = lcmt_teleop_joint_command()
    msg.seq, msg.utime, msg.sample_utime = seq, seq * 250_000, seq * 250_000
    msg.num_joints = len(positions)
    msg.joint_name = list(names)
    msg.joint_position_smoothed = list(positions)
    msg.joint_velocity_smoothed = [0.0] * len(positions)
    return msg


def _haptic(utime, pose, enable=True):
    msg = lcmt_teleop_haptic_command()
    msg.utime, msg.num_axes, msg.pose_desired, msg.enable = utime, len(pose), list(pose), enable
    return msg


class Harness:
    """A subscriber (and optionally a receiver) on a private memq:// bus, pumped by an
    LcmInterfaceSystem as in the process diagrams."""

    def __init__(self, *, channel=TELEOP_JOINT_COMMAND, lcm_type=lcmt_teleop_joint_command,
                 with_receiver=False, with_drake_subscriber=False):
        self.lcm = DrakeLcm("memq://")
        self.channel = channel
        builder = DiagramBuilder()
        builder.AddSystem(LcmInterfaceSystem(self.lcm))
        self.dut = builder.AddSystem(LcmSafeSubscriber(channel=channel, lcm_type=lcm_type,
                                                       lcm=self.lcm))
        self.receiver = None
        if with_receiver:
            self.receiver = builder.AddSystem(JointCommandReceiver(
                joint_names=JOINTS, lower_rad=[-2.0, -2.0], upper_rad=[2.0, 2.0],
                initial_position_rad=[0.0, 0.0]))
            builder.Connect(self.dut.get_lcm_message_output_port(),
                            self.receiver.get_lcm_message_input_port())
            builder.Connect(self.dut.get_message_undecodable_output_port(),
                            self.receiver.get_message_undecodable_input_port())
        self.drake_subscriber = None
        if with_drake_subscriber:
            self.drake_subscriber = builder.AddSystem(LcmSubscriberSystem.Make(
                channel, lcm_type, self.lcm))
        self.simulator = Simulator(builder.Build())
        self.simulator.Initialize()
        self.context = self.dut.GetMyContextFromRoot(self.simulator.get_context())

    def send(self, *packets, advance_s=0.02):
        for packet in packets:
            self.lcm.Publish(self.channel, packet if isinstance(packet, bytes) else
                             packet.encode())
        self.simulator.AdvanceTo(self.simulator.get_context().get_time() + advance_s)

    def message(self):
        return self.dut.get_lcm_message_output_port().Eval(self.context)

    def counts(self):
        return (self.dut.get_message_count_output_port().Eval(self.context)[0],
                self.dut.get_undecodable_count_output_port().Eval(self.context)[0],
                self.dut.get_message_undecodable_output_port().Eval(self.context)[0])

    def error(self):
        return self.dut.get_last_decode_error_output_port().Eval(self.context)


def test_ports_and_output_before_any_packet():
    harness = Harness()
    dut = harness.dut
    assert [dut.get_output_port(i).get_name() for i in range(dut.num_output_ports())] == [
        "lcm_message", "message_count", "undecodable_count", "message_undecodable",
        "last_decode_error", "packets", "dropped_count"]
    assert dut.num_input_ports() == 0
    # A DrakeLcm does not tell what it drops: NaN, not a misleading 0.
    assert np.isnan(dut.get_dropped_count_output_port().Eval(harness.context)[0])
    harness.send()
    msg = harness.message()
    assert isinstance(msg, lcmt_teleop_joint_command)
    assert msg.encode() == lcmt_teleop_joint_command().encode()
    assert harness.counts() == (0.0, 0.0, 0.0)
    assert harness.error() == ""


def test_garbage_truncated_and_wrong_type_packets_between_good_ones():
    harness = Harness()
    good = [_command(seq, [0.1 * seq, -0.1 * seq]) for seq in range(4)]
    truncated = good[1].encode()[:-3]
    other_type = _haptic(7, [0.8, 0.1, 0.2]).encode()    # valid bytes of another LCM type
    fingerprint = lcmt_teleop_joint_command._get_packed_fingerprint()
    bad_body = fingerprint + b"\x00" * 20 + b"\x7f\xff\xff\xff"   # absurd array length
    steps = [
        (good[0], 0, "", (1, 0, 0)),
        (b"garbage", 0, "shorter than the 8-byte type fingerprint", (1, 1, 1)),
        (good[1], 1, None, (2, 1, 0)),
        (truncated, 1, f"the body does not decode (ValueError: Decode error: "
         f"{len(truncated)} bytes end inside a field", (2, 2, 1)),
        (other_type, 1, "type fingerprint " + other_type[:8].hex() + " is not "
         + fingerprint.hex(), (2, 3, 1)),
        (b"", 1, "shorter than the 8-byte type fingerprint (starts b'')", (2, 4, 1)),
        (bad_body, 1, "the body does not decode", (2, 5, 1)),
        (good[2], 2, None, (3, 5, 0)),
        (good[3], 3, None, (4, 5, 0)),
    ]
    last_error = ""
    for packet, expected_seq, reason, counts in steps:
        harness.send(packet)   # must not raise
        assert harness.message().encode() == good[expected_seq].encode()
        assert harness.counts() == counts
        if reason is not None and reason:
            size = len(packet)
            packet_number = counts[0] + counts[1]
            last_error = (f"{TELEOP_JOINT_COMMAND}: packet {packet_number} ({size} bytes) is "
                          "not a valid lcmt_teleop_joint_command: ")
            assert harness.error().startswith(last_error + reason), harness.error()
        else:
            assert harness.error().startswith(last_error)   # the last error is kept


def test_several_packets_between_two_steps_keep_the_newest_good_one():
    harness = Harness()
    harness.send(_command(0, [0.1, 0.2]), _command(1, [0.3, 0.4]), b"junk")
    assert list(harness.message().joint_position_smoothed) == [0.3, 0.4]
    assert harness.counts() == (2, 1, 1)
    harness.send(b"junk", _command(2, [0.5, 0.6]))
    assert harness.message().seq == 2
    assert harness.counts() == (3, 2, 0)


def test_the_packets_window_is_shared_not_copied_by_a_contexts_copy():
    # Catches: the raw-packet window stored as a plain tuple, which Drake's clone of the
    # abstract state deep-copies at every update (a quarter of the operator process's CPU
    # with a 256-packet window); and a window whose sharing loses or reorders packets.
    harness = Harness()
    harness.send(_command(0, [0.1, 0.2]), b"junk", _command(1, [0.3, 0.4]))
    packets = harness.dut.get_packets_output_port().Eval(harness.context)
    assert [number for number, _ in packets] == [1, 2, 3]
    assert packets[1][1] == b"junk"
    root = harness.simulator.get_context().Clone()
    copied = harness.dut.get_packets_output_port().Eval(harness.dut.GetMyContextFromRoot(root))
    assert copied == packets
    # A deep copy of the window's type does not go through its elements (a plain tuple's
    # does, every element, every update, even though it returns the same tuple in the end).
    visits = []

    class Probe:
        def __deepcopy__(self, memo):
            visits.append(1)
            return self

    window = type(packets)(list(packets) + [Probe()])
    assert copy_module.deepcopy(window) is window
    assert visits == []


def test_each_context_keeps_its_own_counts_and_the_first_to_update_takes_the_packets():
    # The rule of the module docstring, as LcmSubscriberSystem's: the payloads wait outside
    # the Context and go to whichever Context updates first; counts live in the Context.
    harness = Harness()
    harness.send(_command(0, [0.1, 0.2]))
    assert harness.counts() == (1.0, 0.0, 0.0)
    diagram = harness.simulator.get_system()
    fresh_root = diagram.CreateDefaultContext()
    fresh = harness.dut.GetMyContextFromRoot(fresh_root)
    assert harness.dut.get_message_count_output_port().Eval(fresh)[0] == 0.0
    harness.lcm.Publish(harness.channel, _command(1, [0.3, 0.4]).encode())
    second = Simulator(diagram, fresh_root)
    second.Initialize()
    second.AdvanceTo(0.02)
    assert harness.dut.get_message_count_output_port().Eval(fresh)[0] == 1.0
    assert harness.dut.get_lcm_message_output_port().Eval(fresh).seq == 1
    # The simulator's Context took nothing of it: its counts are its own.
    harness.send()
    assert harness.counts() == (1.0, 0.0, 0.0)
    assert harness.message().seq == 0


def test_good_packets_give_the_same_output_at_the_same_time_as_lcm_subscriber_system():
    # An oracle for the timing: Drake's subscriber, fed the same (good) packets.
    harness = Harness(with_drake_subscriber=True)
    drake_context = harness.drake_subscriber.GetMyContextFromRoot(
        harness.simulator.get_context())
    rng = np.random.default_rng(0)
    for seq in range(30):
        if rng.random() < 0.7:
            harness.lcm.Publish(TELEOP_JOINT_COMMAND, _command(seq, rng.uniform(-1, 1, 2))
                                .encode())
        harness.simulator.AdvanceTo(harness.simulator.get_context().get_time()
                                    + float(rng.choice([0.0, 0.001, 0.01])))
        expected = harness.drake_subscriber.get_output_port().Eval(drake_context)
        assert harness.message().encode() == expected.encode(), f"step {seq}"


def test_receiver_holds_and_flags_undecodable_packets():
    harness = Harness(with_receiver=True)
    receiver = harness.receiver
    context = receiver.GetMyContextFromRoot(harness.simulator.get_context())

    def outputs():
        return (list(receiver.get_q_commanded_output_port().Eval(context)),
                receiver.get_command_rejected_output_port().Eval(context)[0],
                receiver.get_last_command_seq_output_port().Eval(context)[0])

    harness.send(_command(0, [0.3, 0.4]))
    assert outputs() == ([0.3, 0.4], 0.0, 0.0)
    harness.send(b"\x00" * 3)
    assert outputs() == ([0.3, 0.4], 1.0, 0.0)              # held and flagged
    harness.send(_command(0, [0.3, 0.4]))                    # a repeat changes nothing
    assert outputs() == ([0.3, 0.4], 1.0, 0.0)
    harness.send(_command(1, [0.5, 0.6]))
    assert outputs() == ([0.5, 0.6], 0.0, 1.0)
    # A good packet followed by garbage within one poll: accepted, and flagged.
    harness.send(_command(2, [0.7, 0.8]), b"garbage", advance_s=0.005)
    harness.send(advance_s=0.02)
    assert outputs() == ([0.7, 0.8], 1.0, 2.0)


def test_constructor_errors_name_the_argument():
    lcm = DrakeLcm("memq://")
    with pytest.raises(ValueError, match=r"channel = '' must be a non-empty string"):
        LcmSafeSubscriber(channel="", lcm_type=lcmt_teleop_joint_command, lcm=lcm)
    with pytest.raises(ValueError, match=r"lcm_type = <class 'int'> is not an lcm-gen"):
        LcmSafeSubscriber(channel="X", lcm_type=int, lcm=lcm)


def test_onboard_process_survives_garbage_between_uplink_packets():
    # Ground and onboard diagrams on one memq:// bus; a third party injects malformed packets
    # on TELEOP_JOINT_COMMAND. The run completes, every good packet is still accepted, and
    # the telemetry reports the rejections.
    scenario = LoadScenario(scenario_text="{settle_s: 0.0}")
    lcm = DrakeLcm("memq://")
    ground = MakeGroundDiagram(scenario, lcm=lcm)
    onboard = MakeOnboardDiagram(scenario, lcm=lcm)
    status = []
    lcm.Subscribe(ONBOARD_JOINT_STATUS,
                  lambda data: status.append(lcmt_onboard_joint_status.decode(data)))
    builder = DiagramBuilder()
    builder.AddSystem(ground.diagram)
    builder.AddSystem(onboard.diagram)
    simulator = Simulator(builder.Build())
    tick = scenario.uplink.period_s
    arm = scenario.arm_description
    good_packet = _command(0, [0.0] * arm.num_joints, names=arm.joint_names).encode()
    bad_packets = [b"garbage", good_packet[:-5], b"", _haptic(1, [0.7, 0.0, 0.0]).encode()]
    injected_at = []
    for k, packet in enumerate(bad_packets):
        simulator.AdvanceTo((4 * k + 2.5) * tick)    # between two uplink packets
        lcm.Publish(TELEOP_JOINT_COMMAND, packet)
        injected_at.append(simulator.get_context().get_time())
    duration = (4 * len(bad_packets) + 3) * tick
    simulator.AdvanceTo(duration)                    # must not raise
    assert simulator.get_context().get_time() == duration
    lcm.HandleSubscriptions(0)
    context = simulator.get_context()
    subscriber = onboard.diagram.GetSubsystemByName("joint_command_subscriber")
    subscriber_context = subscriber.GetMyContextFromRoot(context)
    assert subscriber.get_undecodable_count_output_port().Eval(subscriber_context)[0] == 4
    # Every uplink packet sent was accepted, in order, despite the garbage in between.
    received_seq = onboard.logs["last_command_seq"].FindLog(context).data()[0]
    last_sent = int(ground.logs["sequence_number"].FindLog(context).data()[0][-1])
    assert set(range(last_sent)) <= set(received_seq.astype(int).tolist())
    # The telemetry raised command_rejected after each injection, until the next packet.
    for t_bad in injected_at:
        after = [m for m in status if t_bad < m.utime * 1e-6 <= t_bad + 0.5 * tick]
        assert after and all(m.command_rejected for m in after[1:]), t_bad
        later = [m for m in status if t_bad + 1.5 * tick < m.utime * 1e-6 <= t_bad + 2 * tick]
        assert later and not any(m.command_rejected for m in later), t_bad
    # And the robot holds what it was last commanded (the uplink's last packet).
    receiver = onboard.onboard.receiver
    uplink = ground.ground.uplink
    q = receiver.get_q_commanded_output_port().Eval(receiver.GetMyContextFromRoot(context))
    q_sent = uplink.get_q_sent_output_port().Eval(uplink.GetMyContextFromRoot(context))
    np.testing.assert_array_equal(q, q_sent)


def test_ground_process_survives_garbage_from_the_haptic_device():
    scenario = LoadScenario(scenario_text="{haptic: {source: lcm}}")
    lcm = DrakeLcm("memq://")
    ground = MakeGroundDiagram(scenario, lcm=lcm)
    simulator = Simulator(ground.diagram)
    simulator.Initialize()
    haptic = ground.ground.haptic
    context = haptic.GetMyContextFromRoot(simulator.get_context())

    def step(packet, t):
        lcm.Publish(TELEOP_HAPTIC_COMMAND, packet)
        simulator.AdvanceTo(t)
        return (list(haptic.get_pose_desired_output_port().Eval(context)),
                haptic.get_enable_output_port().Eval(context)[0],
                haptic.get_message_rejected_output_port().Eval(context)[0])

    assert step(_haptic(1, [0.72, 0.01, 0.0]).encode(), 0.02) == ([0.72, 0.01, 0.0], 1.0, 0.0)
    for t, bad in ((0.04, b"\xff" * 9), (0.06, _haptic(2, [0.7, 0.0, 0.0]).encode()[:-4]),
                   (0.08, _command(0, [0.0, 0.0]).encode())):
        # Clutch off, pose held: a broken device can never move the arm.
        assert step(bad, t) == ([0.72, 0.01, 0.0], 0.0, 1.0)
    assert step(_haptic(3, [0.71, -0.01, 0.0]).encode(), 0.1) == ([0.71, -0.01, 0.0], 1.0, 0.0)


# -- an lcm.LCM (the lcm package), pumped by the subscriber itself ---------------------------

def _pumped_subscriber(bus, **kwargs):
    """A subscriber alone in a diagram on an ``lcm.LCM``; returns (simulator, system)."""
    builder = DiagramBuilder()
    dut = builder.AddSystem(LcmSafeSubscriber(channel=TELEOP_JOINT_COMMAND,
                                              lcm_type=lcmt_teleop_joint_command, lcm=bus,
                                              **kwargs))
    simulator = Simulator(builder.Build())
    simulator.Initialize()
    return simulator, dut


def _packet_seqs(simulator, dut):
    context = dut.GetMyContextFromRoot(simulator.get_context())
    packets = dut.get_packets_output_port().Eval(context)
    return [lcmt_teleop_joint_command.decode(data).seq for _, data in packets
            if data != b"garbage"]


def test_an_lcm_package_bus_is_pumped_by_the_subscriber_and_keeps_every_packet():
    import lcm as lcm_module

    bus = lcm_module.LCM("memq://")
    simulator, dut = _pumped_subscriber(bus)
    assert dut.pumps_its_own_lcm
    for k in range(100):                      # one burst, between two steps
        bus.publish(TELEOP_JOINT_COMMAND, _command(k, [0.01 * k, 0.0]).encode())
    bus.publish(TELEOP_JOINT_COMMAND, b"garbage")
    simulator.AdvanceTo(0.01)
    context = dut.GetMyContextFromRoot(simulator.get_context())
    assert _packet_seqs(simulator, dut) == list(range(100))
    assert len(dut.get_packets_output_port().Eval(context)) == 101
    assert dut.get_message_count_output_port().Eval(context)[0] == 100
    assert dut.get_undecodable_count_output_port().Eval(context)[0] == 1
    assert dut.get_lcm_message_output_port().Eval(context).seq == 99   # newest good one
    bus.publish(TELEOP_JOINT_COMMAND, _command(100, [1.0, 0.0]).encode())
    simulator.AdvanceTo(0.02)
    assert dut.get_message_count_output_port().Eval(context)[0] == 101


def test_a_udpm_burst_reaches_the_onboard_subscriber_whole():
    # 40 packets sent back to back over udpm (ttl=0): the lcm.LCM path sees every one; the
    # DrakeLcm path (one queued message per subscription) is measured side by side.
    import time

    import lcm as lcm_module

    url = f"udpm://239.255.76.67:{worker_port(7980, 15)}?ttl=0"
    sender = lcm_module.LCM(url)
    simulator, dut = _pumped_subscriber(lcm_module.LCM(url))
    small_simulator, small = _pumped_subscriber(lcm_module.LCM(url), queue_capacity=3)
    drake_lcm = DrakeLcm(url)
    builder = DiagramBuilder()
    builder.AddSystem(LcmInterfaceSystem(drake_lcm))
    drake_dut = builder.AddSystem(LcmSafeSubscriber(
        channel=TELEOP_JOINT_COMMAND, lcm_type=lcmt_teleop_joint_command, lcm=drake_lcm))
    drake_simulator = Simulator(builder.Build())
    drake_simulator.Initialize()
    for k in range(40):
        sender.publish(TELEOP_JOINT_COMMAND, _command(k, [0.0, 0.0]).encode())
    # LCM's reader threads move the packets from the sockets into the queues: wait (step
    # the big queue's simulator) until its queue has them all, on a busy machine as well.
    deadline, t = time.monotonic() + 20.0, 0.0
    while len(_packet_seqs(simulator, dut)) < 40 and time.monotonic() < deadline:
        time.sleep(0.05)
        t += 0.01
        simulator.AdvanceTo(t)
    time.sleep(0.2)                   # the other two subscriptions' threads likewise
    for sim in (small_simulator, drake_simulator):
        sim.AdvanceTo(0.01)
    assert _packet_seqs(simulator, dut) == list(range(40))
    # The queue capacity is what keeps them: a queue of 3 keeps only part of the burst.
    assert len(_packet_seqs(small_simulator, small)) < 40
    print(f"burst of 40 over udpm: lcm.LCM path {len(_packet_seqs(simulator, dut))}, "
          f"queue_capacity=3 {len(_packet_seqs(small_simulator, small))}, DrakeLcm path "
          f"{len(_packet_seqs(drake_simulator, drake_dut))}")


def test_lcm_and_queue_errors_name_the_argument():
    import lcm as lcm_module

    with pytest.raises(ValueError, match=r"queue_capacity = 0 must be an integer >= 1"):
        LcmSafeSubscriber(channel="X", lcm_type=lcmt_teleop_joint_command,
                          lcm=lcm_module.LCM("memq://"), queue_capacity=0)
    with pytest.raises(ValueError, match=r"lcm = 'udpm://' must be a pydrake DrakeLcm or an "
                                         r"lcm.LCM"):
        LcmSafeSubscriber(channel="X", lcm_type=lcmt_teleop_joint_command, lcm="udpm://")
