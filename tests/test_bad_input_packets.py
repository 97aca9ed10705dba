"""Bad input, class 7: every uplink packet is delivered or counted.

The mechanism (telesmooth.link.udpm_receiver): the onboard process reads the uplink with a
socket of its own whose sized receive buffer is the only queue; every datagram is delivered,
or counted as oversized (the size bound applies before reassembly and before decoding), as an
incomplete fragmented message, as not LCM, as another channel, or as dropped by the kernel
(the socket's drop counter). LcmSafeSubscriber refuses a packet over its size bound unread and
outputs the losses on ``dropped_count``.
"""

import json
import os
import threading
import time

import numpy as np
import pytest

from telesmooth.lcm_types import lcmt_teleop_joint_command
from telesmooth.lcm_types.channels import TELEOP_JOINT_COMMAND
from telesmooth.link.udpm_receiver import MAX_INCOMPLETE_MESSAGES, UdpmReceiver

_LC02 = b"LC02"
_LC03 = b"LC03"


def _url() -> str:
    # A port of our own (other tests use 7667-7999), on this host only.
    return f"udpm://239.255.76.67:{30000 + (os.getpid() * 7 + time.monotonic_ns()) % 9000}?ttl=0"


def _command(seq: int, joints: int = 3) -> bytes:
    msg = lcmt_teleop_joint_command()
    msg.seq = seq
    msg.num_joints = joints
    msg.joint_name = [f"j{k}" for k in range(joints)]
    msg.joint_position_smoothed = [0.0] * joints
    msg.joint_velocity_smoothed = [0.0] * joints
    return msg.encode()


def _short(channel: bytes, payload: bytes, seqno: int = 0) -> bytes:
    return _LC02 + seqno.to_bytes(4, "big") + channel + b"\0" + payload


def _fragment(seqno, size, offset, number, count, data, channel=None) -> bytes:
    head = (_LC03 + seqno.to_bytes(4, "big") + size.to_bytes(4, "big")
            + offset.to_bytes(4, "big") + number.to_bytes(2, "big") + count.to_bytes(2, "big"))
    return head + (channel + b"\0" if channel is not None else b"") + data


@pytest.fixture
def receiver():
    dut = UdpmReceiver(_url(), TELEOP_JOINT_COMMAND, max_message_bytes=1000)
    yield dut
    dut.close()


CHANNEL = TELEOP_JOINT_COMMAND.encode()


# --- the wire format, without the network ---

def test_every_kind_of_datagram_is_counted_once(receiver):
    sender = ("127.0.0.1", 1)
    delivered = []
    for datagram in [_short(CHANNEL, b"ok"),                          # delivered
                     _short(b"OTHER", b"x"),                           # other channel
                     _short(CHANNEL, b"y" * 1001),                     # oversized
                     b"XYZ",                                           # too short
                     b"NOPE" + bytes(20),                              # bad magic
                     _LC02 + bytes(4) + b"x" * 100,                    # channel not ended
                     ]:
        payload = receiver._classify(datagram, sender)
        if payload is not None:
            delivered.append(payload)
    counts = receiver._counts
    assert delivered == [b"ok"]
    assert (counts.delivered, counts.other_channel, counts.oversized, counts.not_lcm) == \
        (1, 1, 1, 3)


def test_fragments_are_reassembled_and_bounded(receiver):
    sender = ("127.0.0.1", 2)
    data = bytes(range(256)) * 3                      # 768 bytes, two fragments
    first, second = data[:500], data[500:]
    assert receiver._classify(_fragment(7, 768, 0, 0, 2, first, CHANNEL), sender) is None
    assert receiver._classify(_fragment(7, 768, 500, 1, 2, second), sender) == data
    # A message larger than the bound: counted once at its first fragment, never held.
    assert receiver._classify(_fragment(8, 10**8, 0, 0, 3, b"x" * 10, CHANNEL), sender) is None
    assert receiver._classify(_fragment(8, 10**8, 10, 1, 3, b"x" * 10), sender) is None
    # The same, its first fragment lost: counted at the first that arrives.
    assert receiver._classify(_fragment(9, 10**8, 10, 1, 3, b"x"), sender) is None
    # Fragments whose first never comes: incomplete once evicted.
    for seqno in range(100, 100 + MAX_INCOMPLETE_MESSAGES + 2):
        receiver._classify(_fragment(seqno, 800, 500, 1, 2, b"z" * 300), sender)
    counts = receiver._counts
    assert counts.delivered == 1 and counts.oversized == 2
    assert counts.incomplete >= 2 and len(receiver._fragments) <= MAX_INCOMPLETE_MESSAGES


# --- over udpm (this host only, ttl=0) ---

def _drain(dut, expected_total, timeout_s=10.0):
    """Polls until every datagram is accounted for (delivered, counted or dropped)."""
    payloads = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        payloads += dut.poll(4096)
        c = dut.counts(refresh_s=0)
        total = c.delivered + c.oversized + c.other_channel + c.not_lcm + (c.kernel_dropped or 0)
        if total >= expected_total:
            break
        time.sleep(0.01)
    return payloads, dut.counts(refresh_s=0)


def test_a_flood_that_overflows_the_receive_buffer_is_counted_packet_for_packet():
    import lcm

    url = _url()
    dut = UdpmReceiver(url, TELEOP_JOINT_COMMAND, receive_buffer_bytes=32 << 10)
    bus = lcm.LCM(url)
    try:
        garbage, sent_real = os.urandom(200), 0
        for k in range(10_000):                 # nobody reads meanwhile: the buffer overflows
            bus.publish(TELEOP_JOINT_COMMAND, garbage)
            if k % 250 == 0:
                bus.publish(TELEOP_JOINT_COMMAND, _command(k))
                sent_real += 1
        bus.publish("OTHER", b"not ours")
        payloads, counts = _drain(dut, 10_000 + sent_real + 1)
    finally:
        dut.close()
    if counts.kernel_dropped is None:
        pytest.skip("this system does not report a socket's drops")
    real = sum(p != garbage for p in payloads)
    assert counts.kernel_dropped > 0            # the flood did overflow the buffer
    # Conservation: every datagram sent is delivered, another channel's, or a counted drop.
    assert counts.delivered + counts.other_channel + counts.kernel_dropped == \
        10_000 + sent_real + 1
    assert counts.delivered == len(payloads) and counts.not_lcm == counts.oversized == 0
    print(f"flood: {counts.delivered} delivered ({real} of {sent_real} real), "
          f"{counts.kernel_dropped} dropped by the kernel and counted, receive buffer "
          f"{dut.receive_buffer_bytes} bytes")


def test_a_signed_packet_too_large_is_counted_and_the_next_one_arrives():
    import lcm

    url = _url()
    dut = UdpmReceiver(url, TELEOP_JOINT_COMMAND)
    bus = lcm.LCM(url)
    try:
        huge = _command(1, joints=20_000)                 # ~530 KB: 378 fragments
        bus.publish(TELEOP_JOINT_COMMAND, huge)
        bus.publish(TELEOP_JOINT_COMMAND, _command(2))
        payloads, counts = _drain(dut, 2, timeout_s=5.0)
        deadline = time.monotonic() + 5.0
        while counts.oversized + (counts.kernel_dropped or 0) == 0 and \
                time.monotonic() < deadline:
            payloads += dut.poll(4096)
            counts = dut.counts(refresh_s=0)
    finally:
        dut.close()
    assert [lcmt_teleop_joint_command.decode(p).seq for p in payloads] == [2]
    assert counts.oversized + (counts.kernel_dropped or 0) >= 1 and counts.lost >= 1


def test_the_subscriber_refuses_an_oversized_packet_unread_and_outputs_the_losses():
    import lcm
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder

    from telesmooth.systems.lcm_safe_subscriber import LcmSafeSubscriber

    url = _url()
    receiver = UdpmReceiver(url, TELEOP_JOINT_COMMAND, receive_buffer_bytes=32 << 10)
    builder = DiagramBuilder()
    dut = builder.AddSystem(LcmSafeSubscriber(channel=TELEOP_JOINT_COMMAND,
                                              lcm_type=lcmt_teleop_joint_command,
                                              lcm=receiver, max_message_bytes=500))
    simulator = Simulator(builder.Build())
    simulator.Initialize()
    bus = lcm.LCM(url)
    try:
        for k in range(3000):
            bus.publish(TELEOP_JOINT_COMMAND, _command(k))
        bus.publish(TELEOP_JOINT_COMMAND, _command(9, joints=40))   # ~1.1 KB > 500
        time.sleep(0.2)
        for step in range(1, 400):
            simulator.AdvanceTo(0.01 * step)
        context = dut.GetMyContextFromRoot(simulator.get_context())
        messages = dut.get_message_count_output_port().Eval(context)[0]
        dropped = dut.get_dropped_count_output_port().Eval(context)[0]
        counts = receiver.counts(refresh_s=0)
    finally:
        receiver.close()
    assert dut.pumps_its_own_lcm
    if counts.kernel_dropped is None:
        pytest.skip("this system does not report a socket's drops")
    assert messages + dropped == 3001                     # every packet, to the last
    assert counts.oversized == 1 or counts.kernel_dropped > 0


def test_an_oversized_packet_on_any_bus_is_refused_without_decoding():
    import lcm as lcm_module
    from pydrake.systems.analysis import Simulator
    from pydrake.systems.framework import DiagramBuilder

    from telesmooth.systems.lcm_safe_subscriber import LcmSafeSubscriber

    bus = lcm_module.LCM("memq://")
    builder = DiagramBuilder()
    dut = builder.AddSystem(LcmSafeSubscriber(channel=TELEOP_JOINT_COMMAND,
                                              lcm_type=lcmt_teleop_joint_command, lcm=bus,
                                              max_message_bytes=500))
    simulator = Simulator(builder.Build())
    simulator.Initialize()
    bus.publish(TELEOP_JOINT_COMMAND, _command(1, joints=40))
    bus.publish(TELEOP_JOINT_COMMAND, _command(2))
    simulator.AdvanceTo(0.01)
    context = dut.GetMyContextFromRoot(simulator.get_context())
    assert dut.get_message_count_output_port().Eval(context)[0] == 1
    assert dut.get_undecodable_count_output_port().Eval(context)[0] == 1
    packets = dut.get_packets_output_port().Eval(context)
    assert [len(data) for _, data in packets][0] == 0     # not kept either
    assert np.isnan(dut.get_dropped_count_output_port().Eval(context)[0])


@pytest.mark.process
def test_the_onboard_process_accounts_for_every_packet_of_a_flood(tmp_path, monkeypatch,
                                                                  capsys):
    """CLI level: `telesmooth onboard` on a udpm bus receives 10⁴ garbage packets with 40
    unsigned commands among them; its onboard_counts.json accounts for every one: the
    receiver's classes plus the packets lost before decoding add up to what was sent."""
    import lcm

    import telesmooth.scripts.processes as processes
    from telesmooth.scripts.cli import main

    monkeypatch.chdir(tmp_path)
    url = _url()
    sent = {"packets": 0}
    listening, flooded = threading.Event(), threading.Event()
    log = processes._log

    def spy(message):
        if message.startswith("onboard: listening"):
            listening.set()
        log(message)

    monkeypatch.setattr(processes, "_log", spy)

    def flood():
        bus = lcm.LCM(url)
        assert listening.wait(120)                     # the uplink socket is open
        garbage = os.urandom(200)
        for k in range(10_000):
            bus.publish(TELEOP_JOINT_COMMAND, garbage)
            sent["packets"] += 1
            if k % 250 == 0:
                bus.publish(TELEOP_JOINT_COMMAND, _command(k // 250))
                sent["packets"] += 1
        flooded.set()

    thread = threading.Thread(target=flood)
    thread.start()
    # Long enough that the flood (a fraction of a second when idle) ends while the onboard
    # still listens on a busy machine too: a packet sent after it closed its socket would be
    # neither examined nor lost.
    duration_s = 8
    status = main(["onboard", "--lcm-url", url, "--no-auth", "--duration", str(duration_s),
                   "--realtime", "1", "--out", "out"])
    assert flooded.is_set(), "the flood outlasted the onboard: the count below would not close"
    thread.join()
    assert status == 0, capsys.readouterr().err
    counts = json.loads((tmp_path / "out" / "onboard_counts.json").read_text())
    lost = counts.pop("lost_before_decoding")
    if lost is None:
        pytest.skip("this system does not report a socket's drops")
    examined = sum(counts.values())
    # Nothing vanishes: every packet sent was examined by the receiver or counted as lost.
    # The kernel's count is per socket, so it may also hold datagrams of other channels on
    # the port (the process's own 100 Hz telemetry: at most duration x 100 Hz of them).
    assert 0 <= examined + lost - sent["packets"] <= 100 * duration_s, (json.dumps(counts), lost)
    # Our commands carry no epoch (the onboard draws its own: refused as "session") and name
    # other joints: each is examined and counted in one of these classes, or lost.
    real = counts["accepted"] + counts["invalid"] + counts["session"]
    assert real <= 40 and 40 - real <= lost
    print(f"onboard under a flood: {examined} packets examined ({real} of 40 commands), "
          f"{lost} lost before decoding and counted, of {sent['packets']} sent")
