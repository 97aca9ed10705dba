"""Property-based fuzzing of the ground ``HapticCommandReceiver`` against an independent model of
which messages are accepted.

The contract, the conventions and the shared generators: tests/fuzz_helpers.py (a bad
input gets a clear ValueError or a held, flagged output; never another exception; what was
accepted is not altered).
"""

from __future__ import annotations

import math

import numpy as np
from fuzz_helpers import (
    FINITE,
    _haptic_command,
    _over_the_wire,
    _same_floats,
    fuzz,
)
from hypothesis import example, given
from hypothesis import strategies as st

from telesmooth.lcm_types import (
    lcmt_teleop_haptic_command,
)
from telesmooth.systems.haptic_command_receiver import (
    HapticCommandReceiver,
    HapticCommandReceiverConfig,
)

# ======================================================================================
# Ground HapticCommandReceiver against an independent model
# ======================================================================================


class HapticReceiverModel:
    """The receiver's docstring: a message is new when its utime differs from the previous
    message's; a new message with the arm's number of axes and finite values becomes the pose
    and its clutch; any other new message is rejected (clutch off, pose held). ``enable`` is
    the last valid message's clutch while it is at most ``timeout_s`` old and the newest
    message was not rejected."""

    def __init__(self, pose0, timeout_s):
        self.pose, self.timeout_s = list(pose0), timeout_s
        self.clutch, self.arrived, self.last_utime, self.rejected = False, None, None, False

    def poll(self, msg, now):
        if msg is None or msg.utime == self.last_utime:
            return
        self.last_utime = msg.utime
        pose = list(msg.pose_desired)
        if msg.num_axes == len(self.pose) and len(pose) == len(self.pose) and \
                all(math.isfinite(v) for v in pose):
            self.pose, self.clutch, self.arrived, self.rejected = pose, bool(msg.enable), now, \
                False
        else:
            self.clutch, self.rejected = False, True

    def enable(self, now) -> float:
        fresh = self.arrived is not None and now - self.arrived <= self.timeout_s
        return float(self.clutch and fresh and not self.rejected)


HAPTIC_KINDS = ["valid", "valid", "valid", "count", "nonfinite", "mismatch", "poll", "silence"]


def _run_haptic(dut, context, model, steps):
    """Feeds (dt, msg-or-None, update?) steps; checks outputs against the model."""
    port = dut.get_lcm_message_input_port()
    now = 0.0
    current = None
    for dt, msg, update in steps:
        now += dt
        context.SetTime(now)
        if msg is not None:
            current = msg
            port.FixValue(context, msg)
        if update:
            dut.CalcForcedDiscreteVariableUpdate(context, context.get_mutable_discrete_state())
            model.poll(current, now)
        pose = np.array(dut.get_pose_desired_output_port().Eval(context))
        assert np.all(np.isfinite(pose))
        assert _same_floats(pose, model.pose), (pose, model.pose)
        assert dut.get_enable_output_port().Eval(context)[0] == model.enable(now)
        assert dut.get_message_rejected_output_port().Eval(context)[0] == float(model.rejected)


@fuzz(80)
@given(m=st.integers(1, 6), timeout=st.sampled_from([0.02, 0.1, 0.5]), data=st.data())
def test_haptic_command_receiver_holds_last_valid_pose_and_flags_rejections(m, timeout, data):
    pose0 = data.draw(st.lists(st.floats(-2, 2), min_size=m, max_size=m))
    dut = HapticCommandReceiver(HapticCommandReceiverConfig(timeout_s=timeout),
                                initial_pose=pose0)
    context = dut.CreateDefaultContext()
    dut.get_lcm_message_input_port().FixValue(context, lcmt_teleop_haptic_command())
    model = HapticReceiverModel(pose0, timeout)
    steps = []
    last_utime = 0
    for _ in range(data.draw(st.integers(1, 25))):
        dt = data.draw(st.sampled_from([0.0, 0.005, 0.01, 0.05, 0.2]))
        kind = data.draw(st.sampled_from(HAPTIC_KINDS))
        if kind in ("poll", "silence"):
            steps.append((dt, None, kind == "poll"))
            continue
        utime = data.draw(st.sampled_from(["next", "next", "same", "older", "any"]))
        utime = {"next": last_utime + data.draw(st.integers(1, 20_000)), "same": last_utime,
                 "older": max(0, last_utime - data.draw(st.integers(1, 20_000))),
                 "any": data.draw(st.integers(0, 2**53 - 1))}[utime]
        last_utime = utime
        pose = data.draw(st.lists(FINITE, min_size=m, max_size=m))
        enable = data.draw(st.booleans())
        if kind == "valid":
            msg = _over_the_wire(_haptic_command(utime, pose, enable))
        elif kind == "count":
            k = data.draw(st.sampled_from([c for c in range(1, m + 3) if c != m]))
            msg = _over_the_wire(_haptic_command(utime, (pose + [0.0] * k)[:k], enable))
        elif kind == "nonfinite":
            pose[data.draw(st.integers(0, m - 1))] = data.draw(
                st.sampled_from([math.nan, math.inf, -math.inf]))
            msg = _over_the_wire(_haptic_command(utime, pose, enable))
        else:   # in-process: num_axes disagrees with the array
            msg = _haptic_command(utime, data.draw(st.sampled_from([pose[:-1], pose + [0.0]])),
                                  enable, num_axes=m)
        steps.append((dt, msg, True))
    _run_haptic(dut, context, model, steps)


def _haptic_dut(pose0=(0.7, 0.0, 0.0), timeout=0.1):
    dut = HapticCommandReceiver(HapticCommandReceiverConfig(timeout_s=timeout),
                                initial_pose=list(pose0))
    context = dut.CreateDefaultContext()
    dut.get_lcm_message_input_port().FixValue(context, lcmt_teleop_haptic_command())
    return dut, context, HapticReceiverModel(pose0, timeout)


# Regression (fixed): systems/haptic_command_receiver.py HapticCommandReceiver._update_pose
# treats every message with num_axes <= 0 as 'no message' (is_new requires num_axes > 0), so a
# device message with zero axes is neither rejected nor flagged, contrary to the docstring
# ('message_rejected: 1 if the newest message had the wrong number of axes'): after a valid
# enabled message (utime 1) at t=0.01, a message (utime 2, num_axes 0) at t=0.02 leaves
# message_rejected = 0 and enable = 1 (expected 1 and 0).
@fuzz(30)
@example(utime=2, num_axes=0, dt=0.01)
@given(utime=st.integers(2, 2**53), num_axes=st.sampled_from([0, -1, -5]),
       dt=st.sampled_from([0.0, 0.01, 0.05]))
def test_haptic_receiver_rejects_messages_without_axes(utime, num_axes, dt):
    dut, context, model = _haptic_dut()
    bad = _haptic_command(utime, [], True, num_axes=num_axes)
    _run_haptic(dut, context, model, [(0.01, _haptic_command(1, [0.8, 0.1, 0.2]), True),
                                      (dt, bad, True)])


# Regression (fixed): systems/haptic_command_receiver.py HapticCommandReceiver starts with 'last
# seen utime' = -1.0 as a sentinel, so a first message with utime == -1 (a valid int64 on the
# wire) is taken as already seen and never examined: the pose stays at initial_pose and enable
# stays 0 for as long as that message is the newest (expected: pose = the message's, enable =
# 1).
@fuzz(20)
@example(pose=[0.8, 0.1, 0.2], utime=-1)
@given(pose=st.lists(st.floats(-2, 2), min_size=3, max_size=3),
       utime=st.sampled_from([-1, 0, -2**63, 2**63 - 1]))
def test_haptic_receiver_accepts_a_first_message_with_utime_minus_one(pose, utime):
    # Any int64 utime, also 0 (only the default-constructed message means "nothing yet").
    dut, context, model = _haptic_dut()
    _run_haptic(dut, context, model, [(0.0, None, True),
                                      (0.01, _haptic_command(utime, pose), True),
                                      (0.01, None, True)])
    assert dut.get_enable_output_port().Eval(context)[0] == 1.0


# Regression (fixed): systems/haptic_command_receiver.py keeps the last seen utime in a float64
# discrete state and compares with numpy, so distinct int64 utimes above 2**53 that round to the
# same double are taken as the same message: after utime 2**53 is accepted, a new message with
# utime 2**53 + 1 (other pose) is ignored, the pose is stale and the clutch times out.
@fuzz(20)
@example(base=2**53, offset=1)
@given(base=st.sampled_from([2**53, 2**62 + 1, -2**63, 2**63 - 2**11, -2**53 - 2]),
       offset=st.integers(1, 2**10))
def test_haptic_receiver_distinguishes_large_utimes(base, offset):
    dut, context, model = _haptic_dut()
    _run_haptic(dut, context, model, [
        (0.01, _over_the_wire(_haptic_command(base, [0.8, 0.1, 0.2])), True),
        (0.01, _over_the_wire(_haptic_command(base + offset, [0.9, 0.1, 0.2])), True),
        (0.01, _over_the_wire(_haptic_command(base, [0.7, 0.1, 0.2])), True)])
    np.testing.assert_array_equal(dut.get_pose_desired_output_port().Eval(context),
                                  [0.7, 0.1, 0.2])
