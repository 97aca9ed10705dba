"""The ground station's IK as a pure step (``telesmooth.arms.ik_step``), without Drake, and the
InverseKinematicsSystem holding what the step returns.

A toy arm whose forward kinematics is the identity and whose "solver" answers by rules written
here runs the step against a plain loop re-implementing the rule of the module docstring (the
clutch, the anchor, the held target, the same command not solved again, the verdicts). Over
random streams the state round-trips through the Context's codec, the step never changes the
state it is given, and the target stays finite and within the limits. The Drake system, planar
and 6-DOF, outputs bit for bit what the step computes on the same inputs.
"""

import enum
import functools
import math
from typing import NamedTuple

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from telesmooth.arms.ik_step import (
    SOLVE_OUTCOMES,
    IkInputs,
    IkParams,
    IkStatus,
    ik_failed,
    ik_initial_state,
    ik_solve,
    ik_step,
)
from telesmooth.arms.planar import AIR_BEARING_ARM, planar_pose_point
from telesmooth.safety.state_codec import VectorCodec

LIMIT = 2.0
STEP = 0.2


class ToyStatus(enum.IntEnum):
    SUCCESS = 0
    UNREACHABLE = 1
    JOINT_LIMIT = 2
    JOINT_STEP = 3


class ToyError(NamedTuple):
    position_m: float
    orientation_rad: float
    status: ToyStatus


class ToyResult(NamedTuple):
    q_rad: np.ndarray
    success: bool
    error: ToyError


def _toy_solve(pose, seed, calls):
    """q = pose, with failures by region: z > 2.5 raises; |pose| > 3 unreachable; x > 1.5 a
    limit and y < -1.5 a step (the solver's own verdicts); y > 1.5 a residual too large."""
    calls.append(np.array(pose))
    pose = np.asarray(pose, dtype=float)
    if pose[2] > 2.5:
        raise RuntimeError("toy solver failed")
    status = (ToyStatus.UNREACHABLE if np.linalg.norm(pose) > 3.0 else
              ToyStatus.JOINT_LIMIT if pose[0] > 1.5 else
              ToyStatus.JOINT_STEP if pose[1] < -1.5 else ToyStatus.SUCCESS)
    residual = 1.0 if pose[1] > 1.5 else 0.0
    return ToyResult(pose.copy(), status == ToyStatus.SUCCESS, ToyError(residual, 0.0, status))


def _toy_params(calls):
    return IkParams(
        lower_rad=np.full(3, -LIMIT), upper_rad=np.full(3, LIMIT), max_joint_step_rad=STEP,
        position_tolerance_m=1e-4, orientation_tolerance_rad=1e-3,
        forward_kinematics=lambda q: np.array(q, dtype=float),
        clutch_offset=lambda reference, device: np.asarray(reference) - np.asarray(device),
        apply_clutch_offset=lambda device, offset: np.asarray(device) + np.asarray(offset),
        space_solve=functools.partial(_toy_solve, calls=calls))


def _oracle(stream, q0):
    """The rule of the module docstring as a plain loop over the toy arm: (q, status, engaged,
    pose_commanded) after each update, and how many solves it made."""
    q, offset, engaged, status, solved = np.array(q0), np.zeros(3), True, IkStatus.OK, np.array(q0)
    out, solves = [], 0
    for pose, enable, anchor, q_anchor in stream:
        if math.isnan(enable):
            status, engaged = IkStatus.INVALID_INPUT, False
        elif enable <= 0.5:
            status, engaged = IkStatus.DISENGAGED, False
        elif pose is None or np.isnan(pose).any():
            status = IkStatus.INVALID_INPUT
        else:
            if not engaged:
                if (anchor is not None and anchor > 0.5 and q_anchor is not None
                        and np.isfinite(q_anchor).all() and np.abs(q_anchor).max() <= LIMIT):
                    q = np.array(q_anchor)
                offset = q - pose                   # FK is the identity
            command = pose + offset
            repeated = (engaged and status not in (IkStatus.DISENGAGED, IkStatus.INVALID_INPUT)
                        and np.array_equal(command, solved))
            if not repeated:
                solves, solved = solves + 1, command
                if command[2] > 2.5:
                    status = IkStatus.SOLVER_ERROR
                elif np.linalg.norm(command) > 3.0:
                    status = IkStatus.UNREACHABLE
                elif command[0] > 1.5:
                    status = IkStatus.JOINT_LIMIT
                elif command[1] < -1.5:
                    status = IkStatus.JOINT_STEP
                elif np.abs(command).max() > LIMIT:
                    status = IkStatus.JOINT_LIMIT
                elif command[1] > 1.5:
                    status = IkStatus.UNREACHABLE
                elif np.abs(command - q).max() > STEP:
                    status = IkStatus.JOINT_STEP
                else:
                    status, q = IkStatus.OK, command
            engaged = True
        out.append((q.copy(), status, engaged, solved.copy()))
    return out, solves


_VALUES = [-1.6, -0.1, 0.0, 0.05, 0.1, 0.15, 0.3, 1.6, 1.9, 2.6]
_POSES = st.one_of(st.none(), st.just(np.array([np.nan, 0.0, 0.0])),
                   st.lists(st.sampled_from(_VALUES), min_size=3, max_size=3).map(np.array))
_ENABLES = st.sampled_from([1.0, 1.0, 1.0, 0.0, 0.5, 0.51, float("nan")])
_ANCHORS = st.tuples(st.sampled_from([None, 0.0, 1.0]),
                     st.sampled_from([None, (0.1, 0.0, 0.0), (3.0, 0.0, 0.0),
                                      (np.nan, 0.0, 0.0), (0.0, -0.2, 0.1)]))
_STREAMS = st.lists(st.tuples(_POSES, _ENABLES, _ANCHORS), min_size=1, max_size=40).map(
    lambda items: [(pose, enable, anchor, None if q is None else np.array(q))
                   for pose, enable, (anchor, q) in items])


def _run(stream, q0, calls):
    params = _toy_params(calls)
    state = ik_initial_state(q0, np.zeros(3), q0)
    codec = VectorCodec(state)
    states = []
    for pose, enable, anchor, q_anchor in stream:
        before = codec.pack(state)
        new = ik_step(params, codec.unpack(before), IkInputs(pose, enable, anchor, q_anchor))
        np.testing.assert_array_equal(codec.pack(codec.unpack(codec.pack(new))), codec.pack(new))
        state = codec.unpack(codec.pack(new))
        states.append(state)
    return states


@settings(derandomize=True, database=None, deadline=None, max_examples=150)
@given(stream=_STREAMS)
def test_the_step_follows_the_rule_on_random_streams(stream):
    q0 = np.array([0.0, 0.1, -0.1])
    calls = []
    states = _run(stream, q0, calls)
    expected, solves = _oracle(stream, q0)
    assert len(calls) == solves
    for state, (q, status, engaged, solved) in zip(states, expected):
        np.testing.assert_array_equal(state.q, q)
        assert state.status == status and state.engaged == engaged
        np.testing.assert_array_equal(state.pose_commanded, solved)
        assert np.isfinite(state.q).all() and np.abs(state.q).max() <= LIMIT


@settings(derandomize=True, database=None, deadline=None, max_examples=60)
@given(stream=_STREAMS)
def test_the_step_never_changes_the_state_it_is_given(stream):
    params = _toy_params([])
    state = ik_initial_state(np.zeros(3), np.zeros(3), np.zeros(3))
    codec = VectorCodec(state)
    for pose, enable, anchor, q_anchor in stream:
        before = codec.pack(state)
        new = ik_step(params, state, IkInputs(pose, enable, anchor, q_anchor))
        np.testing.assert_array_equal(codec.pack(state), before)
        if enable <= 0.5 or not math.isfinite(enable):
            np.testing.assert_array_equal(new.q, state.q)
            assert new.engaged is False and ik_failed(new.status) == math.isnan(enable)
        state = new


def test_nothing_changed_returns_the_same_state_and_a_repeat_is_not_solved():
    calls = []
    params = _toy_params(calls)
    state = ik_initial_state(np.zeros(3), np.zeros(3), np.zeros(3))
    pose = np.array([0.1, 0.0, 0.0])
    state = ik_step(params, state, IkInputs(pose, 1.0))
    assert state.status == IkStatus.OK and len(calls) == 1
    assert ik_step(params, state, IkInputs(pose.copy(), 1.0)) is state
    assert len(calls) == 1
    released = ik_step(params, state, IkInputs(pose, 0.0))
    assert released is not state and released.status == IkStatus.DISENGAGED
    assert ik_step(params, released, IkInputs(pose, 0.0)) is released
    # Re-engaged at another device pose: re-indexed onto the held target, solved, no
    # jump (to rounding).
    again = ik_step(params, released, IkInputs(np.array([1.0, 1.0, 1.0]), 1.0))
    np.testing.assert_allclose(again.q, state.q, rtol=0, atol=1e-15)
    assert again.status == IkStatus.OK and again.engaged and len(calls) == 2
    np.testing.assert_array_equal(again.offset, state.q - np.array([1.0, 1.0, 1.0]))


def test_an_anchor_is_taken_only_at_re_engagement_and_only_if_valid():
    params = _toy_params([])
    start = ik_initial_state(np.zeros(3), np.zeros(3), np.zeros(3))
    released = ik_step(params, start, IkInputs(np.zeros(3), 0.0))
    anchor = np.array([0.5, -0.5, 0.25])
    taken = ik_step(params, released, IkInputs(np.full(3, 0.3), 1.0, 1.0, anchor))
    np.testing.assert_array_equal(taken.q, anchor)
    np.testing.assert_array_equal(taken.pose_commanded, anchor)
    for flag, q_anchor in ((0.0, anchor), (1.0, np.array([2.5, 0.0, 0.0])),
                           (1.0, np.array([np.nan, 0.0, 0.0])), (None, anchor), (1.0, None)):
        held = ik_step(params, released, IkInputs(np.full(3, 0.3), 1.0, flag, q_anchor))
        np.testing.assert_array_equal(held.q, np.zeros(3))
    engaged = ik_step(params, start, IkInputs(np.full(3, 0.1), 1.0, 1.0, anchor))
    np.testing.assert_array_equal(engaged.q, np.full(3, 0.1))     # engaged: no anchor


def test_the_planar_closed_form_verdicts():
    arm = AIR_BEARING_ARM
    params = IkParams(
        lower_rad=np.array(arm.joint_lower_rad), upper_rad=np.array(arm.joint_upper_rad),
        max_joint_step_rad=STEP, position_tolerance_m=1e-4, orientation_tolerance_rad=1e-3,
        forward_kinematics=None, clutch_offset=None, apply_clutch_offset=None, planar_arm=arm)
    q = np.array([0.1, 1.2, -0.6])
    near = q + 0.05
    solution, status = ik_solve(params, np.array(planar_pose_point(near, arm.link_lengths_m)), q)
    assert status == IkStatus.OK
    np.testing.assert_allclose(solution, near, atol=1e-12)
    far = q + np.array([0.0, 0.4, 0.0])
    assert ik_solve(params, np.array(planar_pose_point(far, arm.link_lengths_m)), q)[1] == \
        IkStatus.JOINT_STEP
    assert ik_solve(params, np.array([5.0, 0.0, 0.0]), q)[1] == IkStatus.UNREACHABLE


def test_the_statuses():
    assert [int(s) for s in IkStatus] == list(range(7))
    assert {s for s in IkStatus if ik_failed(s)} == set(IkStatus) - {IkStatus.OK,
                                                                      IkStatus.DISENGAGED}
    assert SOLVE_OUTCOMES == set(IkStatus) - {IkStatus.DISENGAGED, IkStatus.INVALID_INPUT}


def test_the_state_round_trips_through_the_codec():
    for n, offset, m in ((3, np.array([0.1, -0.2, 0.3]), 3),
                         (6, np.array([0.1, 0.2, 0.3, 0.5, 0.5, -0.5, 0.5]), 6)):
        state = ik_initial_state(np.linspace(-1, 1, n) / 3, offset, np.arange(m) / 7.0)
        state = state._replace(engaged=False, status=IkStatus.JOINT_STEP)
        codec = VectorCodec(state)
        back = codec.unpack(codec.pack(state))
        assert back.status is IkStatus.JOINT_STEP and back.engaged is False
        for field in ("q", "offset", "pose_commanded"):
            np.testing.assert_array_equal(getattr(back, field), getattr(state, field))
        np.testing.assert_array_equal(codec.pack(back), codec.pack(state))


# --- the Drake system against the step ---


@pytest.mark.parametrize("planar", [True, False], ids=["planar", "space"])
def test_the_drake_system_outputs_what_the_step_computes(planar):
    from telesmooth.arms.description import AIR_BEARING_ARM_3DOF, SPACE_ARM_6DOF
    from telesmooth.arms.space_arm_ik import SpaceArmKinematics, solve_space_arm_ik
    from telesmooth.systems.inverse_kinematics import (
        InverseKinematicsConfig,
        InverseKinematicsSystem,
        apply_clutch_offset,
        clutch_offset,
        planar_arm_from_description,
    )

    arm = AIR_BEARING_ARM_3DOF if planar else SPACE_ARM_6DOF
    q0 = np.array([0.1, 1.2, -0.6]) if planar else np.array([0.3, 0.4, -1.0, 0.3, 0.2, 0.1])
    config = InverseKinematicsConfig()
    dut = InverseKinematicsSystem(config, arm=arm, initial_position_rad=q0)
    context = dut.CreateDefaultContext()
    kinematics = None if planar else SpaceArmKinematics(arm)
    params = IkParams(
        lower_rad=arm.joint_lower_rad, upper_rad=arm.joint_upper_rad,
        max_joint_step_rad=config.max_joint_step_rad,
        position_tolerance_m=config.position_tolerance_m,
        orientation_tolerance_rad=config.orientation_tolerance_rad,
        forward_kinematics=dut.forward_kinematics_pose,
        clutch_offset=functools.partial(clutch_offset, planar=planar),
        apply_clutch_offset=functools.partial(apply_clutch_offset, planar=planar),
        planar_arm=planar_arm_from_description(arm) if planar else None, elbow=config.elbow,
        space_solve=None if planar else functools.partial(
            solve_space_arm_ik, kinematics, position_tolerance_m=config.position_tolerance_m,
            orientation_tolerance_rad=config.orientation_tolerance_rad,
            max_joint_step_rad=config.max_joint_step_rad,
            max_iterations=config.max_iterations))
    pose0 = dut.forward_kinematics_pose(q0)
    offset0 = np.zeros(3) if planar else np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
    state = ik_initial_state(q0, offset0, pose0)
    rng = np.random.default_rng(5)
    statuses = set()
    for k in range(120):
        drift = 0.002 * k * np.ones(pose0.size) if k % 31 < 20 else 0.3 * rng.normal(
            size=pose0.size)
        pose = pose0 + drift if k % 17 != 5 else np.full(pose0.size, np.nan)
        enable = 0.0 if 40 <= k < 45 or 80 <= k < 83 else (np.nan if k == 60 else 1.0)
        anchor = 1.0 if k >= 80 else 0.0
        q_anchor = q0 + 0.01
        dut.get_pose_desired_input_port().FixValue(context, pose)
        dut.get_enable_input_port().FixValue(context, [enable])
        dut.get_anchor_input_port().FixValue(context, [anchor])
        dut.get_q_anchor_input_port().FixValue(context, q_anchor)
        context.SetDiscreteState(dut.EvalUniquePeriodicDiscreteUpdate(context))
        state = ik_step(params, state, IkInputs(pose, enable, anchor, q_anchor))
        statuses.add(state.status)
        np.testing.assert_array_equal(dut.get_q_target_output_port().Eval(context), state.q)
        np.testing.assert_array_equal(dut.get_pose_commanded_output_port().Eval(context),
                                      state.pose_commanded)
        assert dut.get_ik_status_output_port().Eval(context)[0] == float(state.status)
        assert dut.get_ik_failed_output_port().Eval(context)[0] == float(ik_failed(state.status))
        assert dut.ik_state(context).engaged == state.engaged
    assert {IkStatus.OK, IkStatus.DISENGAGED, IkStatus.INVALID_INPUT} <= statuses
    assert statuses - {IkStatus.OK, IkStatus.DISENGAGED, IkStatus.INVALID_INPUT}
