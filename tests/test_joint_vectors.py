"""Joint-vector validation says the same thing everywhere (telesmooth.arms.joint_vectors).

The helpers' messages are pinned here word for word, then every system, smoother and pipeline
stage that takes a joint vector from its caller (an initial pose, a start pose, a measurement,
joint limits) is given a vector of the wrong length and one with a NaN: each must raise, and
with exactly the message the helpers give (one line; the field as the caller wrote it; the
value cut short; the joint's index and name for a bad entry). A stage that stopped checking,
or checked by hand in its own words again, fails here.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from telesmooth.arms.description import AIR_BEARING_ARM_3DOF
from telesmooth.arms.joint_vectors import check_finite_per_joint, check_joint_vector

NAMES = ("shoulder", "elbow", "wrist")
LIMIT = 2.9670597283903604          # the air-bearing arm's joint limit, rad (all joints)


# --- the helpers ------------------------------------------------------------------------------


def test_wrong_count_names_field_value_and_joints():
    with pytest.raises(ValueError) as error:
        check_finite_per_joint("q_start", [0.0, 0.5], 3, NAMES)
    assert str(error.value) == ("q_start = [0.0, 0.5] has shape (2,); expected (3,), one per "
                                "joint of ('shoulder', 'elbow', 'wrist')")
    with pytest.raises(ValueError) as error:
        check_finite_per_joint("q_start", np.zeros((3, 1)), 3)
    assert str(error.value) == ("q_start = [[0.0], [0.0], [0.0]] has shape (3, 1); expected "
                                "(3,), one per joint")


def test_non_numeric_value_is_named_not_a_numpy_error():
    for value in ("abc", [[1.0, 2.0], [3.0]], [1.0, None, "x"], {"shoulder": 1.0}):
        with pytest.raises(ValueError) as error:
            check_finite_per_joint("q_start", value, 3, NAMES)
        message = str(error.value)
        assert message.startswith(f"q_start = {value!r}"), message
        assert message.endswith(" one per joint of ('shoulder', 'elbow', 'wrist')") or (
            "has shape" in message), message


def test_bad_entry_names_index_joint_and_value():
    for bad in (math.nan, math.inf, -math.inf):
        with pytest.raises(ValueError) as error:
            check_finite_per_joint("measurement", [0.0, 0.0, bad], 3, NAMES)
        assert str(error.value) == (
            f"measurement[2] = {bad!r} for joint 2 ('wrist') must be finite")
    with pytest.raises(ValueError) as error:       # without names: the index alone
        check_finite_per_joint("measurement", [math.nan, 0.0], 2)
    assert str(error.value) == "measurement[0] = nan for joint 0 must be finite"
    with pytest.raises(ValueError) as error:       # the first bad entry is named
        check_finite_per_joint("measurement", [0.0, math.inf, math.nan], 3, NAMES)
    assert str(error.value).startswith("measurement[1] = inf for joint 1 ('elbow')")


def test_long_value_is_cut_short_on_one_line():
    long_value = np.arange(200.0).reshape(200)      # numpy would print it on many lines
    with pytest.raises(ValueError) as error:
        check_finite_per_joint("initial_position_rad", long_value, 3)
    message = str(error.value)
    assert "\n" not in message
    assert message.startswith("initial_position_rad = [0.0, 1.0, 2.0, ")
    assert "… (" in message and len(message) < 160, message
    assert message.endswith("has shape (200,); expected (3,), one per joint")


def test_limits_are_checked_with_the_same_words():
    lower, upper = [-1.0, -2.0, -3.0], [1.0, 2.0, 3.0]
    q = check_joint_vector("q_rad", [1.0, -2.0, 0.0], NAMES, lower=lower, upper=upper)
    assert q.tolist() == [1.0, -2.0, 0.0]          # on a limit is within
    with pytest.raises(ValueError) as error:
        check_joint_vector("q_rad", [0.0, 2.5, 0.0], NAMES, lower=lower, upper=upper)
    assert str(error.value) == ("q_rad[1] = 2.5 for joint 1 ('elbow') must be finite and "
                                "within [-2.0, 2.0] rad")
    with pytest.raises(ValueError) as error:
        check_joint_vector("q_rad", [0.0, 0.0, math.nan], NAMES, lower=lower, upper=upper)
    assert str(error.value) == ("q_rad[2] = nan for joint 2 ('wrist') must be finite and "
                                "within [-3.0, 3.0] rad")
    # Without limits, check_joint_vector is check_finite_per_joint with the names.
    for value in ([0.0, 1.0], [0.0, math.nan, 0.0], "abc"):
        with pytest.raises(ValueError) as by_names:
            check_joint_vector("q_rad", value, NAMES)
        with pytest.raises(ValueError) as by_count:
            check_finite_per_joint("q_rad", value, 3, NAMES)
        assert str(by_names.value) == str(by_count.value)


def test_good_vector_is_a_new_float_array_and_the_input_is_untouched():
    given = np.array([1, 2, 3])
    for q in (check_finite_per_joint("q", given, 3), check_joint_vector("q", given, NAMES),
              check_joint_vector("q", given, NAMES, lower=[0, 0, 0], upper=[5, 5, 5])):
        assert q.dtype == float and q.shape == (3,) and q.tolist() == [1.0, 2.0, 3.0]
        assert not np.shares_memory(q, given)
        q[0] = 9.0
    assert given.tolist() == [1, 2, 3]
    assert check_finite_per_joint("q", (0.5,), np.int64(1)).tolist() == [0.5]


# --- every stage that takes a joint vector ---------------------------------------------------


def _delay_fifo(q):
    from telesmooth.systems.delay_fifo import DelayFifo
    return DelayFifo(num_joints=3, initial_position_rad=q)


def _uplink(q):
    from telesmooth.systems.uplink import Uplink
    return Uplink(num_joints=3, initial_position_rad=q)


def _period_mean(q):
    from telesmooth.systems.period_mean import PeriodMean
    return PeriodMean(num_joints=3, initial_position_rad=q)


def _reduced_q_smoother(q):
    from telesmooth.systems.reduced_q_smoother import ReducedQSmoother
    return ReducedQSmoother(joint_names=NAMES, initial_position_rad=q)


def _limits():
    arm = AIR_BEARING_ARM_3DOF
    return dict(joint_names=arm.joint_names, lower_rad=arm.joint_lower_rad,
                upper_rad=arm.joint_upper_rad)


def _command_interpolator(q):
    from telesmooth.systems.command_interpolator import CommandInterpolator
    return CommandInterpolator(initial_position_rad=q, **_limits())


def _joint_command_receiver(q):
    from telesmooth.systems.joint_command_receiver import JointCommandReceiver
    return JointCommandReceiver(initial_position_rad=q, **_limits())


def _link_guard(q):
    from telesmooth.systems.link_guard import LinkGuard
    return LinkGuard(initial_position_rad=q, max_acceleration=0.2, max_jerk=1.0, **_limits())


def _inverse_kinematics(q):
    from telesmooth.systems.inverse_kinematics import InverseKinematicsSystem
    return InverseKinematicsSystem(arm=AIR_BEARING_ARM_3DOF, initial_position_rad=q)


def _flexible_arm_config(q):
    from telesmooth.systems.flexible_arm import FlexibleArmConfig
    return FlexibleArmConfig(initial_position_rad=q)


def _scenario(q):
    from telesmooth.diagrams.scenario import Scenario
    return Scenario(initial_position_rad=q)


def _rest(seconds=1.0):
    """A recording at rest, 4 Hz, (N, 3)."""
    return np.zeros((int(seconds * 4) + 1, 3))


def _fixed_lag_start(q):
    from telesmooth.smoothing.fixed_lag import FixedLagSmoother
    from telesmooth.smoothing.model import JerkModel
    return FixedLagSmoother(JerkModel.make(0.25, 4e-4, 1e-6, num_joints=3)).initial_state(q)


def _fixed_lag_measurement(q):
    from telesmooth.smoothing.fixed_lag import FixedLagSmoother
    from telesmooth.smoothing.model import JerkModel
    smoother = FixedLagSmoother(JerkModel.make(0.25, 4e-4, 1e-6, num_joints=3))
    return smoother.step(smoother.initial_state(np.zeros(3)), q)


def _offline_cks(q):
    from telesmooth.smoothing.model import JerkModel
    from telesmooth.smoothing.offline import solve_offline_cks
    return solve_offline_cks(_rest(), JerkModel.make(0.25, 4e-4, 1e-6, num_joints=3),
                             start_position=q, joint_names=NAMES)


def _offline_hard(q):
    from telesmooth.smoothing.offline_hard import solve_offline_hard
    return solve_offline_hard(_rest(), 0.25, max_acceleration=0.2, max_jerk=1.0,
                              start_position=q, joint_names=NAMES)


def _foresight(q):
    from telesmooth.smoothing.foresight import best_continuation
    return best_continuation(_rest(), _rest(), 1, 0.25, max_acceleration=0.2, max_jerk=1.0,
                             rest=q, joint_names=NAMES)


def _online_hard_run(q):
    from telesmooth.smoothing.online_hard import online_hard_run
    return online_hard_run(_rest(), 0.25, max_acceleration=0.2, max_jerk=1.0, q_start=q,
                           joint_names=NAMES)


def _online_hard_reset(q):
    from telesmooth.smoothing.online_hard import OnlineHardLimiter
    limiter = OnlineHardLimiter(dt_s=0.25, max_acceleration=0.2, max_jerk=1.0,
                                q_start=np.zeros(3), joint_names=NAMES)
    return limiter.reset(q)


def _validate_joint_path(q):
    from telesmooth.diagrams.offline_validation import validate_joint_path
    from telesmooth.diagrams.scenario import Scenario
    path = _rest()
    return validate_joint_path(path, 0.25 * np.arange(len(path)), Scenario(), start_position=q)


_WHOLE = "one per joint of ('shoulder', 'elbow', 'wrist')"
_WITHIN = f" and within [{-LIMIT!r}, {LIMIT!r}] rad"

# (stage, field as its caller writes it, joint names in its messages, limits checked)
STAGES = [
    (_delay_fifo, "initial_position_rad", False, False),
    (_uplink, "initial_position_rad", False, False),
    (_period_mean, "initial_position_rad", False, False),
    (_reduced_q_smoother, "initial_position_rad", True, False),
    (_command_interpolator, "initial_position_rad", True, True),
    (_joint_command_receiver, "initial_position_rad", True, True),
    (_link_guard, "initial_position_rad", True, True),
    (_inverse_kinematics, "initial_position_rad", True, True),
    (_flexible_arm_config, "FlexibleArmConfig.initial_position_rad", True, True),
    (_scenario, "initial_position_rad", True, True),
    (_fixed_lag_start, "start_position", False, False),
    (_fixed_lag_measurement, "measurement", False, False),
    (_offline_cks, "start_position", True, False),
    (_offline_hard, "start_position", True, False),
    (_foresight, "rest", True, False),
    (_online_hard_run, "q_start", True, False),
    (_online_hard_reset, "q", True, False),
    (_validate_joint_path, "start_position", True, False),
]


@pytest.mark.parametrize("stage,field,named,limited", STAGES,
                         ids=[stage.__name__.lstrip("_") for stage, *_ in STAGES])
def test_every_stage_says_the_same_about_a_bad_joint_vector(stage, field, named, limited):
    with pytest.raises(ValueError) as error:
        stage([0.0, 0.5])
    assert str(error.value) == (f"{field} = [0.0, 0.5] has shape (2,); expected (3,), "
                                f"{_WHOLE if named else 'one per joint'}")
    with pytest.raises(ValueError) as error:
        stage([0.0, math.nan, 0.0])
    joint = "joint 1 ('elbow')" if named else "joint 1"
    assert str(error.value) == (f"{field}[1] = nan for {joint} must be finite"
                                f"{_WITHIN if limited else ''}")
    stage([0.0, 0.5, -0.5])     # and a good vector is taken


def _command_interpolator_limits(**limits):
    from telesmooth.systems.command_interpolator import CommandInterpolator
    return CommandInterpolator(initial_position_rad=np.zeros(3), **{**_limits(), **limits})


def _joint_command_receiver_limits(**limits):
    from telesmooth.systems.joint_command_receiver import JointCommandReceiver
    return JointCommandReceiver(initial_position_rad=np.zeros(3), **{**_limits(), **limits})


def _link_guard_limits(**limits):
    from telesmooth.systems.link_guard import LinkGuard
    return LinkGuard(initial_position_rad=np.zeros(3), max_acceleration=0.2, max_jerk=1.0,
                     **{**_limits(), **limits})


@pytest.mark.parametrize("stage", [_command_interpolator_limits, _joint_command_receiver_limits,
                                   _link_guard_limits],
                         ids=["command_interpolator", "joint_command_receiver", "link_guard"])
@pytest.mark.parametrize("side", ["lower_rad", "upper_rad"])
def test_joint_limits_must_be_finite_and_one_per_joint(stage, side):
    """An infinite limit is refused (a receiver that took one would accept any command on
    that joint), and so is a limit vector of the wrong length."""
    limits = np.array(_limits()[side])
    limits[2] = -np.inf if side == "lower_rad" else np.inf
    with pytest.raises(ValueError) as error:
        stage(**{side: limits})
    assert str(error.value) == (f"{side}[2] = {float(limits[2])!r} for joint 2 ('wrist') must "
                                "be finite")
    with pytest.raises(ValueError) as error:
        stage(**{side: limits[:2]})
    assert str(error.value) == (f"{side} = {limits[:2].tolist()!r} has shape (2,); expected "
                                f"(3,), {_WHOLE}")
    stage()     # the arm's own limits are taken
