"""The laser tracker's pure step (``telesmooth.arms.tracker``) against values written here, and
the LaserTracker system holding what the step returns."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from telesmooth.arms.tracker import TrackerParams, tracker_noise, tracker_step
from telesmooth.safety.state_codec import VectorCodec

# A made-up plant of 2 flexible joints whose positions are ordered [defl 0, motor 0, motor 1,
# defl 1] and velocities follow (so the indices are not the plant's usual interleaving).
PARAMS = TrackerParams(period_s=0.01, noise_m=0.0, seed=5, num_positions=4,
                       motor_index=np.array([1, 2]), deflection_index=np.array([0, 3]),
                       motor_velocity_index=np.array([5, 6]),
                       deflection_velocity_index=np.array([4, 7]))


@settings(derandomize=True, database=None, deadline=None, max_examples=40)
@given(state=st.lists(st.floats(-3.0, 3.0), min_size=8, max_size=8),
       tool=st.lists(st.floats(-2.0, 2.0), min_size=3, max_size=3),
       time=st.floats(0.0, 100.0))
def test_a_sample_is_the_time_the_tool_and_the_joints_in_their_order(state, tool, time):
    sample = tracker_step(PARAMS, np.array(state), time, np.array(tool))
    d0, m0, m1, d1, vd0, vm0, vm1, vd1 = state
    expected = [time, *tool, m0 + d0, m1 + d1, m0, m1]
    np.testing.assert_array_equal(sample.measurement, expected)
    np.testing.assert_array_equal(sample.velocity, [vm0 + vd0, vm1 + vd1, vm0, vm1])
    codec = VectorCodec(sample)
    np.testing.assert_array_equal(codec.pack(codec.unpack(codec.pack(sample))),
                                  codec.pack(sample))


@pytest.mark.parametrize("time, k", [(0.0, 0), (0.0299999999, 3), (0.03, 3), (7.305, 730),
                                     (7.3150001, 732)])
def test_sample_ks_noise_depends_on_seed_and_k_only(time, k):
    noisy = dataclasses.replace(PARAMS, noise_m=2e-4)
    expected = 2e-4 * np.random.default_rng([5, k]).standard_normal(3)
    np.testing.assert_array_equal(tracker_noise(noisy, time), expected)
    sample = tracker_step(noisy, np.zeros(8), time, np.array([1.0, 2.0, 3.0]))
    np.testing.assert_array_equal(sample.measurement[1:4], np.array([1.0, 2.0, 3.0]) + expected)
    assert not np.any(tracker_noise(PARAMS, time))


def test_the_drake_system_holds_the_steps_sample_with_drakes_tool_point():
    from telesmooth.arms.planar import AIR_BEARING_ARM, planar_forward_kinematics
    from telesmooth.systems.flexible_arm import FlexibleJointArm

    arm = FlexibleJointArm(tracker_in_diagram=False)
    tracker, plant = arm.tracker, arm.plant
    context = tracker.CreateDefaultContext()
    rng = np.random.default_rng(4)
    state = rng.normal(scale=0.3, size=plant.num_multibody_states())
    tracker.get_plant_state_input_port().FixValue(context, state)
    context.SetTime(0.37)
    tracker.Sample(context)
    q = state[:plant.num_positions()]
    measurement = tracker.get_measurement_output_port().Eval(context)
    # The step given the tool point in closed form (the planar arm's, in its plane z = 0).
    tool = np.append(planar_forward_kinematics(q[0::2] + q[1::2],
                                               AIR_BEARING_ARM.link_lengths_m), 0.0)
    expected = tracker_step(tracker._params, state, 0.37, tool)
    np.testing.assert_allclose(measurement, expected.measurement, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(measurement[[0, *range(4, len(measurement))]],
                                  expected.measurement[[0, *range(4, len(measurement))]])
    np.testing.assert_array_equal(tracker.get_velocity_measured_output_port().Eval(context),
                                  expected.velocity)
    np.testing.assert_array_equal(tracker.get_q_link_output_port().Eval(context),
                                  q[0::2] + q[1::2])
    assert tracker.get_sample_time_output_port().Eval(context)[0] == 0.37
