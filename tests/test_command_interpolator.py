"""CommandInterpolator: closed-form ramp/step set-points, command rejection (hold + flag),
recovery, port contract, and validation messages; the set-point evaluated by Drake
(RampSetPoint) against the pure ramp_desired_state; the default poll (10 ms, 0.1 ms after the
10 ms grid); a continuous plant's diagram."""

import logging
import math

import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from telesmooth.systems.command_interpolator import (
    CommandInterpolator,
    CommandInterpolatorConfig,
    RampSetPoint,
    command_violation,
    ramp_desired_state,
)

NAMES = ("shoulder", "elbow")
LOWER = np.array([-1.0, -2.0])
UPPER = np.array([1.0, 2.0])
Q0 = np.array([0.1, -0.2])
POLL = 0.001
RAMP = 0.25
ATOL = 1e-12


def make_dut(interpolation="linear", initial_position_rad=Q0):
    return CommandInterpolator(
        CommandInterpolatorConfig(interpolation=interpolation, poll_period_s=POLL,
                                  poll_offset_s=0.0),
        joint_names=NAMES, lower_rad=LOWER, upper_rad=UPPER,
        initial_position_rad=initial_position_rad)


class Harness:
    """The dut alone in a Simulator; the held command is changed between AdvanceTo calls."""

    def __init__(self, dut, command=Q0):
        self.dut = dut
        self.simulator = Simulator(dut)
        self.context = self.simulator.get_mutable_context()
        self.port = dut.get_q_commanded_input_port()
        self.port.FixValue(self.context, np.asarray(command, dtype=float))
        self.simulator.Initialize()

    def hold_from(self, time_s, command):
        """Advances to ``time_s``, then holds ``command`` on the input from there on."""
        self.simulator.AdvanceTo(time_s)
        self.port.FixValue(self.context, np.asarray(command, dtype=float))

    def desired_at(self, time_s):
        """(q_d, v_d) at ``time_s`` (chosen between polls, so no poll is pending at it)."""
        self.simulator.AdvanceTo(time_s)
        value = self.dut.get_state_desired_output_port().Eval(self.context)
        return value[:2], value[2:]

    def rejected(self):
        return self.dut.get_command_rejected_output_port().Eval(self.context)[0]


def first_poll_after(time_s):
    return math.ceil(time_s / POLL) * POLL


# -- pure functions -----------------------------------------------------------------------


def test_ramp_closed_form_before_during_and_after():
    start, target = np.array([0.0, 1.0]), np.array([0.5, -1.0])
    velocity = (target - start) / 0.25
    q, v = ramp_desired_state(start, target, 2.0, 0.25, 1.9)  # before t0: clipped, no velocity
    np.testing.assert_allclose(q, start, atol=0, rtol=0)
    np.testing.assert_allclose(v, 0.0, atol=0, rtol=0)
    q, v = ramp_desired_state(start, target, 2.0, 0.25, 2.0)  # at t0
    np.testing.assert_allclose(q, start, atol=0, rtol=0)
    np.testing.assert_allclose(v, velocity, atol=0, rtol=0)
    q, v = ramp_desired_state(start, target, 2.0, 0.25, 2.1)  # s = 0.4
    np.testing.assert_allclose(q, [0.2, 0.2], atol=ATOL, rtol=0)
    np.testing.assert_allclose(v, [2.0, -8.0], atol=ATOL, rtol=0)
    q, v = ramp_desired_state(start, target, 2.0, 0.25, 2.25)  # end: exactly the target
    assert np.array_equal(q, target)
    np.testing.assert_allclose(v, 0.0, atol=0, rtol=0)


def test_command_violation_names_joint_and_value():
    assert command_violation(np.array([0.5, 2.0]), LOWER, UPPER, NAMES) is None  # on a limit
    assert command_violation(np.array([0.5, np.nan]), LOWER, UPPER, NAMES) == (
        "q_commanded[1] (elbow) = nan is not finite")
    assert command_violation(np.array([np.inf, 0.0]), LOWER, UPPER, NAMES) == (
        "q_commanded[0] (shoulder) = inf is not finite")
    assert command_violation(np.array([-1.5, 0.0]), LOWER, UPPER, NAMES) == (
        "q_commanded[0] (shoulder) = -1.5 is outside the joint limits [-1.0, 1.0]")


# -- port contract ------------------------------------------------------------------------


def test_port_contract_and_output_before_first_command():
    dut = make_dut()
    assert dut.num_input_ports() == 2 and dut.num_output_ports() == 3
    assert dut.get_input_port(0).get_name() == "q_commanded"
    assert dut.get_input_port(0).size() == 2
    assert dut.get_input_port(1).get_name() == "command_time"   # optional
    assert dut.get_input_port(1).size() == 1
    assert [dut.get_output_port(i).get_name() for i in range(3)] == [
        "state_desired", "command_rejected", "ramp"]
    assert dut.get_state_desired_output_port().size() == 4
    assert dut.get_command_rejected_output_port().size() == 1
    # Outputs come from state and time only: no algebraic loop through the plant.
    assert not dut.HasAnyDirectFeedthrough()
    context = dut.CreateDefaultContext()
    np.testing.assert_array_equal(
        dut.get_state_desired_output_port().Eval(context), np.concatenate([Q0, [0, 0]]))
    assert dut.get_command_rejected_output_port().Eval(context)[0] == 0.0


def test_holds_initial_position_while_input_equals_it():
    harness = Harness(make_dut(), command=Q0)
    for time_s in (0.0005, 0.1234, 0.7777):
        q, v = harness.desired_at(time_s)
        np.testing.assert_array_equal(q, Q0)
        np.testing.assert_array_equal(v, [0.0, 0.0])
    assert harness.rejected() == 0.0


# -- interpolation ------------------------------------------------------------------------


def test_linear_ramp_against_closed_form():
    harness = Harness(make_dut("linear"))
    a = np.array([0.6, 0.8])
    harness.hold_from(0.1005, a)
    t0 = first_poll_after(0.1005)  # 0.101: the first poll that sees the new command
    q, v = harness.desired_at(0.1009)  # not polled yet: still holding
    np.testing.assert_array_equal(q, Q0)
    np.testing.assert_array_equal(v, [0.0, 0.0])
    for time_s in (0.1013, 0.2015, 0.3455):
        q, v = harness.desired_at(time_s)
        s = (time_s - t0) / RAMP
        np.testing.assert_allclose(q, Q0 + s * (a - Q0), atol=1e-12, rtol=0)
        np.testing.assert_allclose(v, (a - Q0) / RAMP, atol=1e-12, rtol=0)
    start, target, start_time = harness.dut.get_ramp(harness.context)
    np.testing.assert_array_equal(start, Q0)
    np.testing.assert_array_equal(target, a)
    assert start_time == pytest.approx(t0, abs=1e-12)
    q, v = harness.desired_at(t0 + RAMP + 0.0005)  # after the ramp: target, zero velocity
    np.testing.assert_array_equal(q, a)
    np.testing.assert_array_equal(v, [0.0, 0.0])


def test_command_mid_ramp_starts_new_ramp_from_current_set_point():
    harness = Harness(make_dut("linear"))
    a, b = np.array([0.6, 0.8]), np.array([-0.4, 1.2])
    harness.hold_from(0.1005, a)
    harness.hold_from(0.2005, b)
    t0, t1 = first_poll_after(0.1005), first_poll_after(0.2005)
    q1 = Q0 + (t1 - t0) / RAMP * (a - Q0)  # the set-point when b is seen
    q, v = harness.desired_at(t1 + 0.0505)
    np.testing.assert_allclose(q, q1 + 0.0505 / RAMP * (b - q1), atol=1e-12, rtol=0)
    np.testing.assert_allclose(v, (b - q1) / RAMP, atol=1e-12, rtol=0)
    q, v = harness.desired_at(t1 + RAMP + 0.0005)
    np.testing.assert_array_equal(q, b)
    np.testing.assert_array_equal(v, [0.0, 0.0])


@pytest.mark.parametrize("interpolation", ["linear", "zoh"])
def test_a_command_time_places_the_ramp_at_the_instant_the_command_was_issued(interpolation):
    """A command held from 0.1005 s and stamped 0.1005 s is seen by the poll at 0.101 s, but
    its ramp starts at 0.1005 s (closed form), so it reaches the command at 0.1005 + T; the
    second command's ramp starts on the first one at its own stamp, 0.2005 s."""
    harness = Harness(make_dut(interpolation))
    stamp = harness.dut.get_command_time_input_port()
    a, b = np.array([0.6, 0.8]), np.array([-0.4, 1.2])
    harness.hold_from(0.1005, a)
    stamp.FixValue(harness.context, [0.1005])
    q, _ = harness.desired_at(0.1009)      # not polled yet: still holding
    np.testing.assert_array_equal(q, Q0)
    harness.hold_from(0.2005, b)
    stamp.FixValue(harness.context, [0.2005])
    start, target, start_time = harness.dut.get_ramp(harness.context)
    assert start_time == 0.1005 and np.array_equal(target, a)
    if interpolation == "linear":
        np.testing.assert_array_equal(start, Q0)
        q1 = Q0 + 0.1 / RAMP * (a - Q0)    # the set-point at b's stamp, on a's ramp
        for time_s in (0.2013, 0.3503):
            q, v = harness.desired_at(time_s)
            np.testing.assert_allclose(q, q1 + (time_s - 0.2005) / RAMP * (b - q1),
                                       atol=1e-12, rtol=0)
            np.testing.assert_allclose(v, (b - q1) / RAMP, atol=1e-12, rtol=0)
        q, v = harness.desired_at(0.2005 + RAMP)   # reached at exactly stamp + T
        np.testing.assert_array_equal(q, b)
        np.testing.assert_array_equal(v, [0.0, 0.0])
    else:
        q, v = harness.desired_at(0.2013)
        np.testing.assert_array_equal(q, b)
        np.testing.assert_array_equal(v, [0.0, 0.0])
    assert harness.dut.get_ramp(harness.context)[2] == 0.2005


@pytest.mark.parametrize("stamp_s", [np.nan, 0.5, 0.05])
def test_a_command_time_outside_the_last_ramp_start_and_now_is_ignored(stamp_s):
    """A stamp that is not finite, in the future (0.5 s at the poll of 0.101 s), or before
    the ramp in progress began (0.05 s, before the ramp started at the 0.061 s poll) cannot
    move the ramp: it starts at the poll, as without the input."""
    harness = Harness(make_dut("linear"))
    a, b = np.array([0.6, 0.8]), np.array([-0.4, 1.2])
    harness.hold_from(0.0605, b)
    harness.hold_from(0.1005, a)
    harness.dut.get_command_time_input_port().FixValue(harness.context, [stamp_s])
    harness.desired_at(0.1013)
    assert harness.dut.get_ramp(harness.context)[2] == pytest.approx(0.101, abs=1e-12)


def test_set_point_is_continuous_between_and_across_polls():
    harness = Harness(make_dut("linear"))
    a = np.array([0.6, 0.8])
    harness.hold_from(0.1005, a)
    times = np.arange(0.1006, 0.4, 0.00037)  # not aligned with the polls
    positions = np.array([harness.desired_at(t)[0] for t in times])
    largest_jump = np.abs(np.diff(positions, axis=0)).max()
    # |Δq| ≤ |v|·Δt = (0.7/0.25 rad/s)·0.37 ms ≈ 1.04e-3 rad.
    assert largest_jump <= np.abs(a - Q0).max() / RAMP * 0.00037 + 1e-12


def test_zoh_steps_with_zero_velocity():
    harness = Harness(make_dut("zoh"))
    a = np.array([0.6, 0.8])
    harness.hold_from(0.1005, a)
    q, v = harness.desired_at(0.1009)
    np.testing.assert_array_equal(q, Q0)
    for time_s in (0.1011, 0.2333):
        q, v = harness.desired_at(time_s)
        np.testing.assert_array_equal(q, a)
        np.testing.assert_array_equal(v, [0.0, 0.0])


# -- rejection, hold, recovery ------------------------------------------------------------


@pytest.mark.parametrize("bad", [[0.3, np.nan], [np.inf, 0.0], [0.3, 2.5], [-1.01, 0.0]])
def test_unsafe_command_keeps_the_target_and_raises_the_flag(bad, caplog):
    harness = Harness(make_dut("linear"))
    a = np.array([0.6, 0.8])
    harness.hold_from(0.1005, a)
    t0 = first_poll_after(0.1005)
    with caplog.at_level(logging.WARNING):
        harness.hold_from(0.2005, bad)  # mid-ramp
        q, v = harness.desired_at(0.2205)
    # The ramp to the last valid target continues unchanged; then the robot holds.
    s = (0.2205 - t0) / RAMP
    np.testing.assert_allclose(q, Q0 + s * (a - Q0), atol=1e-12, rtol=0)
    np.testing.assert_allclose(v, (a - Q0) / RAMP, atol=1e-12, rtol=0)
    assert harness.rejected() == 1.0
    q, v = harness.desired_at(0.6005)  # the bad command is still held on the input
    np.testing.assert_array_equal(q, a)
    np.testing.assert_array_equal(v, [0.0, 0.0])
    assert harness.rejected() == 1.0
    assert harness.dut.get_rejected_command_count(harness.context) == 1  # counted once
    joint = 1 if (np.isnan(bad[1]) or abs(bad[1]) > 2) else 0
    assert f"q_commanded[{joint}] ({NAMES[joint]}) = {float(bad[joint])!r}" in caplog.text


def test_recovery_on_next_valid_command():
    harness = Harness(make_dut("linear"))
    a, b = np.array([0.6, 0.8]), np.array([0.2, 0.4])
    harness.hold_from(0.1005, a)
    harness.hold_from(0.4005, [np.nan, np.nan])
    harness.hold_from(0.5005, [5.0, 0.0])  # a different bad command: counted too
    harness.simulator.AdvanceTo(0.6005)
    assert harness.rejected() == 1.0
    assert harness.dut.get_rejected_command_count(harness.context) == 2
    harness.hold_from(0.7005, b)
    t1 = first_poll_after(0.7005)
    q, v = harness.desired_at(t1 + 0.1)
    np.testing.assert_allclose(q, a + 0.1 / RAMP * (b - a), atol=1e-12, rtol=0)
    np.testing.assert_allclose(v, (b - a) / RAMP, atol=1e-12, rtol=0)
    assert harness.rejected() == 0.0
    assert harness.dut.get_rejected_command_count(harness.context) == 2


def test_resending_the_held_target_clears_the_flag_without_a_new_ramp():
    harness = Harness(make_dut("linear"))
    a = np.array([0.6, 0.8])
    harness.hold_from(0.1005, a)
    harness.hold_from(0.4005, [0.0, np.nan])
    harness.simulator.AdvanceTo(0.45)
    assert harness.rejected() == 1.0
    harness.hold_from(0.5005, a)
    q, v = harness.desired_at(0.5105)
    assert harness.rejected() == 0.0
    np.testing.assert_array_equal(q, a)
    np.testing.assert_array_equal(v, [0.0, 0.0])
    assert harness.dut.get_ramp(harness.context)[2] == pytest.approx(0.101, abs=1e-12)


def test_set_hold_position_validates_and_holds():
    harness = Harness(make_dut("linear"))
    harness.simulator.AdvanceTo(0.3)
    harness.dut.SetHoldPosition(harness.context, [0.5, 0.5])
    harness.port.FixValue(harness.context, [0.5, 0.5])  # the upstream hold agrees
    q, v = harness.desired_at(0.3005)
    np.testing.assert_array_equal(q, [0.5, 0.5])
    np.testing.assert_array_equal(v, [0.0, 0.0])
    assert harness.dut.get_ramp(harness.context)[2] == pytest.approx(0.3, abs=1e-12)
    with pytest.raises(ValueError, match=r"q_commanded\[1\] \(elbow\) = 3.0 is outside"):
        harness.dut.SetHoldPosition(harness.context, [0.5, 3.0])


# -- validation ---------------------------------------------------------------------------


def test_default_config_is_valid():
    config = CommandInterpolatorConfig()
    assert (config.interpolation, config.ramp_duration_s, config.poll_period_s,
            config.poll_offset_s) == ("linear", 0.25, None, 1e-4)
    assert config.poll_timing(None) == (0.01, 1e-4)          # the receiver's rate
    assert config.poll_timing(0.25) == (0.25, 1e-4)          # the uplink's, if known
    assert CommandInterpolatorConfig(poll_period_s=0.002).poll_timing(0.25) == (0.002, 1e-4)


@pytest.mark.parametrize("kwargs,match", [
    ({"interpolation": "cubic"}, r"CommandInterpolatorConfig.interpolation = 'cubic'"),
    ({"ramp_duration_s": 0.0}, r"CommandInterpolatorConfig.ramp_duration_s = 0.0 must be"),
    ({"ramp_duration_s": -0.25}, r"ramp_duration_s = -0.25 must be positive"),
    ({"poll_period_s": float("nan")}, r"CommandInterpolatorConfig.poll_period_s = nan"),
    ({"poll_period_s": "fast"}, r"poll_period_s = 'fast' must be a number"),
    ({"poll_offset_s": 0.01}, r"poll_offset_s = 0.01 must be a number of seconds in "
                              r"\[0, poll period = 0.01\)"),
    ({"poll_period_s": 0.002, "poll_offset_s": 0.003}, r"poll_offset_s = 0.003 must be"),
    ({"poll_offset_s": -1e-4}, r"poll_offset_s = -0.0001 must be"),
    ({"poll_offset_s": float("nan")}, r"poll_offset_s = nan must be"),
    ({"poll_offset_s": "soon"}, r"poll_offset_s = 'soon' must be"),
])
def test_config_errors_name_field_and_value(kwargs, match):
    with pytest.raises(ValueError, match=match):
        CommandInterpolatorConfig(**kwargs)


@pytest.mark.parametrize("kwargs,match", [
    ({"initial_position_rad": [0.0, 2.5]},
     r"initial_position_rad\[1\] = 2.5 for joint 1 \('elbow'\) must be finite and within "
     r"\[-2.0, 2.0\] rad"),
    ({"initial_position_rad": [np.nan, 0.0]},
     r"initial_position_rad\[0\] = nan for joint 0 \('shoulder'\) must be finite"),
    ({"initial_position_rad": [0.0]},
     r"initial_position_rad = \[0.0\] has shape \(1,\); expected \(2,\)"),
    ({"lower_rad": [1.0, -2.0]},
     r"lower_rad\[0\] = 1.0 for joint 0 \('shoulder'\) must be < upper_rad\[0\] = 1.0"),
    ({"upper_rad": [1.0, np.inf]}, r"upper_rad\[1\] = inf for joint 1 \('elbow'\) must be finite"),
    ({"joint_names": ("a", "a")}, r"joint_names = \('a', 'a'\) must be unique"),
    ({"joint_names": ()}, r"joint_names = \(\) must be a non-empty"),
])
def test_constructor_errors_name_field_joint_and_value(kwargs, match):
    arguments = dict(joint_names=NAMES, lower_rad=LOWER, upper_rad=UPPER,
                     initial_position_rad=Q0)
    arguments.update(kwargs)
    with pytest.raises(ValueError, match=match):
        CommandInterpolator(CommandInterpolatorConfig(), **arguments)


def test_wrong_command_size_is_refused_by_the_port():
    dut = make_dut()
    context = dut.CreateDefaultContext()
    with pytest.raises(Exception, match="size"):
        dut.get_q_commanded_input_port().FixValue(context, np.zeros(3))


# -- the set-point evaluated by Drake -----------------------------------------------------


@pytest.mark.parametrize("lead_s", [0.0, 0.005])
def test_ramp_set_point_is_ramp_desired_state_to_the_last_bit(lead_s):
    """Oracle: the pure function, at random ramps and times before, during, at the ends of
    and after each ramp (the symbolic evaluator repeats its operations in the same order)."""
    rng = np.random.default_rng(5)
    n, period = 3, 0.25
    dut = RampSetPoint(n, period, lead_s)
    context = dut.CreateDefaultContext()
    port = dut.get_input_port()
    for _ in range(200):
        start, target = rng.uniform(-2, 2, n), rng.uniform(-2, 2, n)
        start_time = rng.uniform(0.0, 40.0)
        port.FixValue(context, np.concatenate([[start_time], start, target]))
        times = [start_time - lead_s - 0.01, start_time - lead_s,
                 start_time - lead_s + rng.uniform(0, period), start_time + period - lead_s,
                 start_time + period - lead_s + 1e-3]
        for time_s in times:
            context.SetTime(time_s)
            q, v = ramp_desired_state(start, target, start_time, period, time_s + lead_s)
            np.testing.assert_array_equal(dut.get_output_port().Eval(context),
                                          np.concatenate([q, v]))


def test_no_python_runs_when_the_set_point_is_read():
    """The set-point is the output of the C++ evaluator: reading it at many times calls no
    Python function (profiled); the Python gate runs only at its polls (one periodic event,
    10 ms from 0.1 ms). A Python output callback computing it would run at every read."""
    import sys

    dut = CommandInterpolator(CommandInterpolatorConfig(), joint_names=NAMES, lower_rad=LOWER,
                              upper_rad=UPPER, initial_position_rad=Q0)
    assert type(dut.GetSubsystemByName("ramp_set_point")).__name__ == "SymbolicVectorSystem"
    poll = dut.gate.GetUniquePeriodicDiscreteUpdateAttribute()
    assert (poll.period_sec(), poll.offset_sec()) == (0.01, 1e-4)
    harness = Harness(dut)
    harness.hold_from(0.1005, [0.6, 0.8])
    harness.simulator.AdvanceTo(0.2)              # a ramp in progress
    context, port = harness.context, dut.get_state_desired_output_port()
    python_calls = []

    def profile(frame, event, arg):
        if event == "call":
            python_calls.append(frame.f_code.co_name)

    values = []
    times = [float(t) for t in np.linspace(0.2, 0.3, 40)]
    sys.setprofile(profile)
    try:
        for time_s in times:
            context.SetTime(time_s)
            values.append(tuple(port.Eval(context)))
    finally:
        sys.setprofile(None)
    assert python_calls == []
    assert len(set(values)) == 40      # re-evaluated at every time indeed


def test_default_poll_sees_a_command_on_the_10_ms_grid_a_tenth_of_a_millisecond_later():
    dut = CommandInterpolator(CommandInterpolatorConfig(), joint_names=NAMES, lower_rad=LOWER,
                              upper_rad=UPPER, initial_position_rad=Q0)
    harness = Harness(dut)
    a = np.array([0.6, 0.8])
    harness.hold_from(0.25, a)                  # as the uplink's tick at 0.25 s would
    q, _ = harness.desired_at(0.25005)           # before the poll at 0.2501 s
    np.testing.assert_array_equal(q, Q0)
    q, v = harness.desired_at(0.2502)
    assert harness.dut.get_ramp(harness.context)[2] == pytest.approx(0.2501, abs=1e-12)
    np.testing.assert_allclose(q, Q0 + 0.0001 / RAMP * (a - Q0), atol=1e-12, rtol=0)
    np.testing.assert_allclose(v, (a - Q0) / RAMP, atol=1e-12, rtol=0)


def test_works_in_a_diagram_with_continuous_state():
    """A continuous plant's diagram integrates; the evaluator then needs a state of its own
    (drake 1.51's SymbolicVectorSystem aborts when asked for derivatives without one)."""
    from pydrake.systems.framework import DiagramBuilder
    from pydrake.systems.primitives import Integrator

    builder = DiagramBuilder()
    dut = builder.AddSystem(CommandInterpolator(
        CommandInterpolatorConfig(), joint_names=NAMES, lower_rad=LOWER, upper_rad=UPPER,
        initial_position_rad=Q0, continuous_diagram=True))
    integrator = builder.AddSystem(Integrator(4))   # integrates the set-point: q_d and v_d
    builder.Connect(dut.get_state_desired_output_port(), integrator.get_input_port())
    builder.ExportInput(dut.get_q_commanded_input_port())
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.get_mutable_integrator().set_target_accuracy(1e-9)
    context = simulator.get_mutable_context()
    a = np.array([0.6, 0.8])
    diagram.get_input_port().FixValue(context, a)
    simulator.AdvanceTo(1.0)
    # The poll at 0.1 ms starts a ramp reaching a at 0.2501 s: ∫q_d dt over [0, 1] s.
    t0 = 1e-4
    expected = Q0 * t0 + (Q0 + a) / 2 * RAMP + a * (1.0 - t0 - RAMP)
    state = integrator.GetMyContextFromRoot(context).get_continuous_state_vector().CopyToVector()
    # The integrator steps across the jumps of v_d at the ramp's end (not an event time).
    np.testing.assert_allclose(state[:2], expected, rtol=0, atol=1e-7)
    np.testing.assert_allclose(state[2:], a - Q0, rtol=0, atol=1e-6)   # ∫v_d = the travel
