"""Property-based fuzzing of the onboard ``JointCommandReceiver`` against an independent model of
which packets are accepted.

The contract, the conventions and the shared generators: tests/fuzz_helpers.py (a bad
input gets a clear ValueError or a held, flagged output; never another exception; what was
accepted is not altered).
"""

from __future__ import annotations

import math

import numpy as np
from fuzz_helpers import (
    DECODE_ERRORS,
    INT32,
    _joint_command,
    _over_the_wire,
    _same_floats,
    fuzz,
)
from hypothesis import given
from hypothesis import strategies as st

from telesmooth.lcm_types import (
    lcmt_teleop_joint_command,
)
from telesmooth.systems.joint_command_receiver import (
    JointCommandReceiver,
    JointCommandReceiverConfig,
)

# ======================================================================================
# Onboard JointCommandReceiver against an independent model
# ======================================================================================

JOINT_POOL = ("shoulder", "elbow", "wrist", "Joint 4")


def _default_joint_command(msg) -> bool:
    """Equal to lcmt_teleop_joint_command() (compared through vars: some messages here
    cannot be encoded)."""
    default = lcmt_teleop_joint_command()
    def plain(value):   # decoded arrays are tuples, constructed ones lists
        return list(value) if isinstance(value, (list, tuple)) else value
    return all(plain(getattr(msg, name)) == plain(getattr(default, name))
               for name in default.__slots__)


class JointReceiverModel:
    """What the receiver's docstrings promise, written without looking at its state layout.

    A packet is examined if it is not the default message, has seq ≥ 0 and its
    (session_id, seq) is newer than the last accepted one's (any before the first), once (the
    same pair held again is not examined again). It is fresh (telesmooth.link.session's
    rule, in process: epoch 0) if it carries epoch 0 and, against the last accepted
    (s₀, q₀) ((0, −1) before the first), its session s is s₀ with seq > q₀, or its counter
    (the high bits above the 32-bit nonce) is counter(s₀) + 1. A packet of an earlier session
    or seq is stale or a duplicate (ignored); a wrong epoch or a session that skips ahead is
    refused (flagged). A fresh packet is accepted if it names exactly the robot's joints in
    order, with one finite position per joint inside [lower, upper]; then it becomes the
    command and clears the rejected flag. Otherwise the flag is raised and the command holds.
    Timeout: more than ``timeout_s`` since the last accepted packet (from t = 0 before any).
    """

    def __init__(self, names, lower, upper, q0, timeout_s):
        self.names, self.lower, self.upper = tuple(names), list(lower), list(upper)
        self.timeout_s = timeout_s
        self.q = list(q0)
        # "last_command_seq: −1 before the first" and "seq ≤ last are ignored".
        self.last_seq, self.last_time, self.rejected, self.examined = -1, 0.0, False, None
        self.last_pair = (0, -1)
        self.timeout = False

    def acceptable(self, msg) -> bool:
        positions = list(msg.joint_position_smoothed)
        return (msg.num_joints == len(self.names) and len(positions) == len(self.names)
                and tuple(msg.joint_name) == self.names
                and all(math.isfinite(v) and lo <= v <= hi
                        for v, lo, hi in zip(positions, self.lower, self.upper)))

    def freshness(self, msg) -> str:
        """"fresh", "old" (stale or duplicate: ignored) or "refused" (flagged)."""
        if int(msg.onboard_epoch) != 0:
            return "refused"
        session, seq = int(msg.session_id), int(msg.seq)
        last_session, last_seq = self.last_pair
        if session == last_session:
            return "fresh" if seq > last_seq else "old"
        counter, last_counter = session // 2**32, last_session // 2**32
        if counter == last_counter + 1:
            return "fresh"
        return "old" if counter <= last_counter else "refused"

    def poll(self, msg, now):
        # The subscriber's default message is not a packet; any other one (even with an
        # empty joint list) is examined once.
        pair = None if msg is None else (msg.session_id, msg.seq)
        newer = self.last_seq < 0 or pair > self.last_pair
        if msg is not None and not _default_joint_command(msg) and msg.seq >= 0 and newer \
                and pair != self.examined:
            self.examined = pair
            fresh = self.freshness(msg)
            if fresh == "fresh" and self.acceptable(msg):
                self.q = [float(v) for v in msg.joint_position_smoothed]
                self.last_seq, self.last_time, self.rejected = msg.seq, now, False
                self.last_pair = (int(msg.session_id), int(msg.seq))
            elif fresh != "old":
                self.rejected = True
        self.timeout = now - self.last_time > self.timeout_s


@st.composite
def joint_receiver_setups(draw):
    n = draw(st.integers(1, 4))
    lower = [draw(st.floats(-4.0, -1e-3)) for _ in range(n)]
    upper = [draw(st.floats(1e-3, 4.0)) for _ in range(n)]
    q0 = [draw(st.floats(lo, hi)) for lo, hi in zip(lower, upper)]
    timeout = draw(st.sampled_from([0.05, 0.3, 1.0]))
    return JOINT_POOL[:n], lower, upper, q0, timeout


JOINT_KINDS = ["valid", "valid", "valid", "count", "names", "nonfinite", "limits", "mismatch",
               "empty", "corrupt", "velocity_nan", "poll"]
INT32_MIN, INT32_MAX = -2**31, 2**31 - 1


def _draw_seq(draw, model):
    last = model.last_seq
    choice = draw(st.sampled_from(["next", "next", "jump", "dup", "stale", "examined", "any"]))
    if choice == "next":
        seq = last + 1
    elif choice == "jump":
        seq = last + draw(st.integers(2, 50))
    elif choice == "dup":
        seq = last
    elif choice == "stale":
        seq = last - draw(st.integers(1, 50))
    elif choice == "examined":
        seq = model.examined[1] if model.examined is not None else last + 1
    else:
        seq = draw(st.one_of(INT32, st.sampled_from([INT32_MIN, INT32_MAX, 0, -1])))
    return min(max(seq, INT32_MIN), INT32_MAX)


def _draw_joint_message(draw, kind, model):
    names, lower, upper = list(model.names), model.lower, model.upper
    n = len(names)
    seq = _draw_seq(draw, model)
    valid_q = [draw(st.one_of(st.floats(lo, hi), st.sampled_from([lo, hi])))
               for lo, hi in zip(lower, upper)]
    if kind == "valid":
        return _over_the_wire(_joint_command(seq, names, valid_q))
    if kind == "velocity_nan":   # velocities are not checked; positions are valid
        return _over_the_wire(_joint_command(seq, names, valid_q, [math.nan] * n))
    if kind == "count":
        m = draw(st.sampled_from([k for k in range(1, n + 3) if k != n]))
        extra = [f"extra{k}" for k in range(max(0, m - n))]
        q = (valid_q + [0.0] * m)[:m]
        return _over_the_wire(_joint_command(seq, (names + extra)[:m], q))
    if kind == "names":
        variants = [[*names[:-1], names[-1].upper()], [*names[:-1], names[-1] + " "],
                    [*names[:-1], ""], [*names[:-1], "other"]]
        if n > 1:
            variants.append(names[::-1])
        return _over_the_wire(_joint_command(seq, draw(st.sampled_from(variants)), valid_q))
    if kind == "nonfinite":
        q = list(valid_q)
        q[draw(st.integers(0, n - 1))] = draw(st.sampled_from([math.nan, math.inf, -math.inf]))
        return _over_the_wire(_joint_command(seq, names, q))
    if kind == "limits":
        q = list(valid_q)
        j = draw(st.integers(0, n - 1))
        q[j] = draw(st.sampled_from([
            float(np.nextafter(upper[j], math.inf)), float(np.nextafter(lower[j], -math.inf)),
            upper[j] + 1.0, lower[j] - 10.0, 1e308, -1e308, 5e-324 + upper[j] * 2]))
        return _over_the_wire(_joint_command(seq, names, q))
    if kind == "mismatch":   # in-process message whose count disagrees with its arrays
        bad_q = draw(st.sampled_from([valid_q[:-1], valid_q + [0.0]]))
        return _joint_command(seq, names, bad_q, [0.0] * len(bad_q), num_joints=n)
    if kind == "empty":      # an empty joint list: documented as not examined
        return _over_the_wire(_joint_command(seq, [], []))
    if kind == "corrupt":    # a damaged valid packet that still decodes
        encoded = bytearray(_joint_command(seq, names, valid_q).encode())
        for bit in draw(st.lists(st.integers(64, 8 * len(encoded) - 1), min_size=1,
                                 max_size=3)):
            encoded[bit // 8] ^= 1 << (bit % 8)
        try:
            return lcmt_teleop_joint_command.decode(bytes(encoded))
        except DECODE_ERRORS:
            return None
    raise AssertionError(kind)


def _check_joint_outputs(dut, context, model, lower, upper):
    q = np.array(dut.get_q_commanded_output_port().Eval(context))
    assert np.all(np.isfinite(q)), q
    assert np.all(q >= lower) and np.all(q <= upper), (q, lower, upper)
    assert _same_floats(q, model.q), (q, model.q)
    seq = dut.get_last_command_seq_output_port().Eval(context)[0]
    assert seq == model.last_seq
    assert dut.get_command_rejected_output_port().Eval(context)[0] == float(model.rejected)
    assert dut.get_command_timeout_output_port().Eval(context)[0] == float(model.timeout)


@fuzz(80)
@given(setup=joint_receiver_setups(), data=st.data())
def test_joint_command_receiver_holds_last_accepted_and_flags_rejections(setup, data):
    names, lower, upper, q0, timeout = setup
    dut = JointCommandReceiver(JointCommandReceiverConfig(timeout_s=timeout), joint_names=names,
                               lower_rad=lower, upper_rad=upper, initial_position_rad=q0)
    context = dut.CreateDefaultContext()
    port = dut.get_lcm_message_input_port()
    model = JointReceiverModel(names, lower, upper, q0, timeout)
    port.FixValue(context, lcmt_teleop_joint_command())   # what the subscriber gives first
    current = None
    now = 0.0
    for _ in range(data.draw(st.integers(1, 25))):
        now += data.draw(st.sampled_from([0.0, 0.01, 0.04, 0.25, 0.6]))
        kind = data.draw(st.sampled_from(JOINT_KINDS))
        if kind != "poll":
            msg = _draw_joint_message(data.draw, kind, model)
            if msg is not None:
                current = msg
                port.FixValue(context, msg)
        context.SetTime(now)
        dut.CalcForcedUnrestrictedUpdate(context, context.get_mutable_state())
        model.poll(current, now)
        _check_joint_outputs(dut, context, model, lower, upper)


@fuzz(25)
@given(setup=joint_receiver_setups(), data=st.data())
def test_joint_command_receiver_in_a_simulator_with_periodic_polling(setup, data):
    from pydrake.systems.analysis import Simulator

    names, lower, upper, q0, timeout = setup
    dut = JointCommandReceiver(JointCommandReceiverConfig(timeout_s=timeout), joint_names=names,
                               lower_rad=lower, upper_rad=upper, initial_position_rad=q0)
    simulator = Simulator(dut)
    context = simulator.get_mutable_context()
    port = dut.get_lcm_message_input_port()
    port.FixValue(context, lcmt_teleop_joint_command())
    simulator.Initialize()
    model = JointReceiverModel(names, lower, upper, q0, timeout)
    now = 0.0
    for _ in range(data.draw(st.integers(1, 10))):
        kind = data.draw(st.sampled_from([k for k in JOINT_KINDS if k != "poll"]))
        msg = _draw_joint_message(data.draw, kind, model)
        if msg is None:
            continue
        port.FixValue(context, msg)
        now += data.draw(st.sampled_from([0.015, 0.05, 0.3]))   # at least one poll
        simulator.AdvanceTo(now)
        model.poll(msg, now)
        q = np.array(dut.get_q_commanded_output_port().Eval(context))
        assert np.all(np.isfinite(q)) and np.all(q >= lower) and np.all(q <= upper)
        assert _same_floats(q, model.q)
        assert dut.get_last_command_seq_output_port().Eval(context)[0] == model.last_seq
        assert dut.get_command_rejected_output_port().Eval(context)[0] == float(model.rejected)
