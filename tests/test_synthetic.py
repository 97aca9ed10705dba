"""Tests for telesmooth.datasets.synthetic: minimum jerk, joint-space and Cartesian generators."""

import dataclasses
import importlib
import itertools

import numpy as np
import pytest
import scipy.signal
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from telesmooth.arms.planar import (
    AIR_BEARING_ARM,
    planar_end_effector_angle,
    planar_forward_kinematics,
)
from telesmooth.datasets.lasa import OperatorSession
from telesmooth.datasets.synthetic import (
    SyntheticOperatorConfig,
    minimum_jerk,
    synthetic_joint_motion,
    synthetic_operator_session,
)

# --- frozen copies of the two generators synthetic_joint_motion replaced (do not edit) ---


def _frozen_core_fixtures_minimum_jerk(t, t0, duration, start, end):
    s = np.clip((t - t0) / duration, 0.0, 1.0)
    return start + (end - start) * (10 * s**3 - 15 * s**4 + 6 * s**5)


def _frozen_operator_recording(num_samples=60, num_joints=2, dt=0.25, noise=1e-3, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(num_samples) * dt
    q = np.zeros((num_samples, num_joints))
    for j in range(num_joints):
        position, t0 = 0.1 * j, 0.0
        q[:, j] = position
        while t0 < t[-1]:
            duration = rng.uniform(2.0, 6.0)
            target = position + rng.uniform(-0.4, 0.4)
            q[:, j] += _frozen_core_fixtures_minimum_jerk(t, t0, duration, 0.0, target - position)
            position, t0 = target, t0 + duration + rng.uniform(0.0, 2.0)
    return q + noise * rng.standard_normal(q.shape)


def _frozen_bench_synthetic_operator(num_samples, num_joints, *, dt_s=0.25, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(num_samples) * dt_s
    q = np.zeros((num_samples, num_joints))
    for j in range(num_joints):
        starts, position = [], 0.0
        t0 = 0.0
        while t0 < t[-1]:
            duration = rng.uniform(2.0, 6.0)
            target = np.clip(position + rng.uniform(-0.4, 0.4), -1.5, 1.5)
            starts.append((t0, duration, target - position))
            position, t0 = target, t0 + duration + rng.uniform(0.0, 2.0)
        for t0, duration, step in starts:
            s = np.clip((t - t0) / duration, 0.0, 1.0)
            q[:, j] += step * (10 * s**3 - 15 * s**4 + 6 * s**5)
    return q + 1e-3 * rng.standard_normal(q.shape)


# --- frozen copy of synthetic_joint_motion as it was before it became O(N) (do not edit) ---
# Its loop body, verbatim, adds every reach's step to the whole time grid: O(N x reaches).
# The O(N) version must give the same arrays bit for bit (signs of zeros included).


def _frozen_minimum_jerk(t, t0, duration, start, end):
    s = np.clip((np.asarray(t) - t0) / duration, 0.0, 1.0)
    start = np.asarray(start)
    end = np.asarray(end)
    point_ndim = np.broadcast(start, end).ndim
    if point_ndim:
        s = s.reshape(s.shape + (1,) * point_ndim)
    position = start + (end - start) * (10 * s**3 - 15 * s**4 + 6 * s**5)
    return np.where(s >= 1.0, end, position)


def _frozen_joint_motion_every_reach_on_every_sample(
    num_samples, num_joints, *, dt_s=0.25, noise_rad=1e-3, seed=0, reach_rad=0.4,
    reach_duration_range_s=(2.0, 6.0), pause_range_s=(0.0, 2.0), joint_offset_step_rad=0.0,
    position_limit_rad=None,
):
    duration_low, duration_high = (float(v) for v in reach_duration_range_s)
    pause_low, pause_high = (float(v) for v in pause_range_s)
    rng = np.random.default_rng(seed)
    t = np.arange(num_samples) * dt_s
    q = np.zeros((num_samples, num_joints))
    for j in range(num_joints):
        # The additions below happen in the same order as in the two generators this
        # replaces (start value first, then each step), so the sums are bitwise equal.
        position, t0 = joint_offset_step_rad * j, 0.0
        q[:, j] = position
        while t0 < t[-1]:
            duration = rng.uniform(duration_low, duration_high)
            target = position + rng.uniform(-reach_rad, reach_rad)
            if position_limit_rad is not None:
                target = np.clip(target, -position_limit_rad, position_limit_rad)
            q[:, j] += _frozen_minimum_jerk(t, t0, duration, 0.0, target - position)
            position, t0 = target, t0 + duration + rng.uniform(pause_low, pause_high)
    return q + noise_rad * rng.standard_normal(q.shape)


# Every (num_samples, num_joints, dt, seed) the test suite passes to operator_recording, plus
# its defaults; noise is always the default 1e-3.
OPERATOR_RECORDING_CALLS = [
    (60, 2, 0.25, 0),
    (40, 2, 0.25, 7),
    (30, 2, 0.25, 8),
    (25, 1, 0.25, 10),
    (120, 3, 0.25, 11),
    (24, 2, 0.01, 1),
    (24, 2, 0.25, 1),
    (24, 2, 1.0, 1),
    (50, 1, 0.25, 2),
    (30, 3, 0.25, 4),
    (40, 2, 0.25, 21),
    (40, 2, 0.25, 22),
    (40, 2, 0.25, 23),
    (12, 2, 0.25, 21),
]

# The benchmark's calls: offline sizes (seed = N; 1e5 left out for time) and the online stream.
BENCH_CALLS = [(100, 6, 100), (1_000, 6, 1_000), (10_000, 6, 10_000), (2_000, 6, 1)]


@pytest.mark.parametrize("num_samples, num_joints, dt, seed", OPERATOR_RECORDING_CALLS)
def test_joint_motion_reproduces_operator_recording_bitwise(num_samples, num_joints, dt, seed):
    expected = _frozen_operator_recording(num_samples, num_joints, dt, 1e-3, seed)
    dut = synthetic_joint_motion(num_samples, num_joints, dt_s=dt, noise_rad=1e-3, seed=seed,
                                 joint_offset_step_rad=0.1)
    assert np.array_equal(dut, expected)


@pytest.mark.parametrize("num_samples, num_joints, dt, seed", OPERATOR_RECORDING_CALLS[:4])
def test_core_fixtures_operator_recording_is_the_frozen_generator(
    num_samples, num_joints, dt, seed
):
    core_fixtures = importlib.import_module("core_fixtures")
    expected = _frozen_operator_recording(num_samples, num_joints, dt, 1e-3, seed)
    actual = core_fixtures.operator_recording(num_samples=num_samples, num_joints=num_joints,
                                              dt=dt, seed=seed)
    assert np.array_equal(actual, expected)
    assert np.array_equal(core_fixtures.operator_recording(), _frozen_operator_recording())


@pytest.mark.parametrize("num_samples, num_joints, seed", BENCH_CALLS)
def test_joint_motion_reproduces_bench_synthetic_operator_bitwise(num_samples, num_joints, seed):
    expected = _frozen_bench_synthetic_operator(num_samples, num_joints, seed=seed)
    dut = synthetic_joint_motion(num_samples, num_joints, dt_s=0.25, seed=seed,
                                 position_limit_rad=1.5)
    assert np.array_equal(dut, expected)
    if num_samples == 10_000:
        # The ±1.5 rad clip is reached in this recording, so the option is exercised.
        assert np.max(np.abs(expected)) > 1.5 - 6e-3


@pytest.mark.parametrize("num_samples, num_joints, seed", BENCH_CALLS[:2])
def test_bench_core_synthetic_operator_is_the_frozen_generator(num_samples, num_joints, seed):
    from telesmooth.scripts.bench_core import synthetic_operator

    expected = _frozen_bench_synthetic_operator(num_samples, num_joints, seed=seed)
    assert np.array_equal(synthetic_operator(num_samples, num_joints, seed=seed), expected)


def _assert_bitwise_equal(actual, expected):
    assert actual.shape == expected.shape and actual.dtype == expected.dtype == np.float64
    assert np.all(np.isfinite(expected))
    # view(uint64) also tells -0.0 from +0.0, which np.array_equal does not.
    np.testing.assert_array_equal(actual.view(np.uint64), expected.view(np.uint64))


# (reach_duration_range_s, pause_range_s) of the grid below.
JOINT_MOTION_RANGES = [
    ((2.0, 6.0), (0.0, 2.0)),  # the defaults
    ((2.0, 6.0), (0.0, 0.0)),  # back to back: the next reach starts where one ends
    ((0.01, 0.02), (0.0, 2.0)),  # reaches shorter than a sample
    ((0.01, 0.02), (0.0, 0.0)),  # several reaches between two samples
    # Reach ends and starts on grid points or an ulp off them; at dt 0.1 and 0.3 some
    # sample t_k = t0_next = t0 + D (rounded) still has (t_k - t0) / D < 1.
    ((0.3, 0.3), (0.0, 0.0)),
    ((0.1, 0.1), (0.1, 0.1)),
    ((0.25, 0.25), (0.0, 0.0)),
]

# (joint_offset_step_rad, position_limit_rad, noise_rad): noise-free runs so that no bit of
# the motion can hide under the noise, and one with noise for the draw order.
JOINT_MOTION_VARIANTS = [(0.1, None, 1e-3), (0.1, None, 0.0), (-0.05, 0.3, 0.0)]


@pytest.mark.parametrize("dt_s", [0.25, 0.01, 0.1, 0.3])
@pytest.mark.parametrize("reach_duration_range_s, pause_range_s", JOINT_MOTION_RANGES,
                         ids=[f"reach{d}-pause{p}" for d, p in JOINT_MOTION_RANGES])
def test_joint_motion_equals_frozen_every_reach_sum_bitwise(
    dt_s, reach_duration_range_s, pause_range_s
):
    # Longest recording with at most ~150 reaches per joint (the frozen version costs
    # N x reaches), up to 2500 samples.
    mean_cycle_s = 0.5 * (sum(reach_duration_range_s) + sum(pause_range_s))
    longest = min(2500, 2 + int(150 * mean_cycle_s / dt_s))
    for seed, num_samples, (offset, limit, noise) in itertools.product(
        (0, 1, 2), sorted({1, 2, 3, min(40, longest), longest}), JOINT_MOTION_VARIANTS
    ):
        kwargs = dict(dt_s=dt_s, noise_rad=noise, seed=seed,
                      reach_duration_range_s=reach_duration_range_s, pause_range_s=pause_range_s,
                      joint_offset_step_rad=offset, position_limit_rad=limit)
        expected = _frozen_joint_motion_every_reach_on_every_sample(num_samples, 3, **kwargs)
        _assert_bitwise_equal(synthetic_joint_motion(num_samples, 3, **kwargs), expected)


def test_joint_motion_equals_frozen_every_reach_sum_bitwise_at_the_bench_rate():
    # 10 ms samples as in the benchmark's online stream, 6 joints, clipped targets.
    kwargs = dict(dt_s=0.01, seed=7, position_limit_rad=1.5)
    expected = _frozen_joint_motion_every_reach_on_every_sample(20_000, 6, **kwargs)
    _assert_bitwise_equal(synthetic_joint_motion(20_000, 6, **kwargs), expected)


@pytest.mark.parametrize("seed", range(10))
def test_joint_motion_keeps_the_sign_of_zero_of_the_every_reach_sum(seed):
    # No motion and no noise: every entry is a zero. Joint 0 starts at -0.1 * 0 = -0.0, which
    # the frozen version's later steps (+0.0 before their reach starts) turn into +0.0; the
    # O(N) version has to add that +0.0 too.
    kwargs = dict(reach_rad=0.0, noise_rad=0.0, seed=seed, joint_offset_step_rad=-0.1)
    expected = _frozen_joint_motion_every_reach_on_every_sample(12, 2, **kwargs)
    _assert_bitwise_equal(synthetic_joint_motion(12, 2, **kwargs), expected)


@st.composite
def _joint_motion_arguments(draw):
    dt_s = draw(st.sampled_from([0.25, 0.01, 0.1, 0.3]) | st.floats(1e-3, 1.0))
    duration_low = draw(st.sampled_from([0.01, 0.1, 0.3, 2.0]) | st.floats(1e-3, 3.0))
    duration_high = duration_low * draw(st.sampled_from([1.0, 2.0]) | st.floats(1.0, 4.0))
    pause_low = draw(st.sampled_from([0.0, 0.1]) | st.floats(0.0, 1.0))
    pause_high = pause_low + draw(st.sampled_from([0.0, 2.0]) | st.floats(0.0, 2.0))
    # At most ~400 reaches per joint, so that the frozen version stays fast.
    longest = min(600, 2 + int(400 * (duration_low + pause_low) / dt_s))
    return draw(st.integers(1, longest)), draw(st.integers(1, 3)), dict(
        dt_s=dt_s,
        noise_rad=draw(st.sampled_from([0.0, 1e-3])),
        seed=draw(st.integers(0, 2**32 - 1)),
        reach_rad=draw(st.sampled_from([0.0, 0.4]) | st.floats(0.0, 2.0)),
        reach_duration_range_s=(duration_low, duration_high),
        pause_range_s=(pause_low, pause_high),
        joint_offset_step_rad=draw(st.sampled_from([0.0, 0.1, -0.1]) | st.floats(-1.0, 1.0)),
        position_limit_rad=draw(st.none() | st.sampled_from([0.3, 1.5]) | st.floats(0.01, 2.0)),
    )


@settings(derandomize=True, database=None, deadline=None, max_examples=200,
          suppress_health_check=[HealthCheck.too_slow])
@given(_joint_motion_arguments())
def test_joint_motion_equals_frozen_every_reach_sum_bitwise_fuzzed(arguments):
    num_samples, num_joints, kwargs = arguments
    expected = _frozen_joint_motion_every_reach_on_every_sample(num_samples, num_joints, **kwargs)
    _assert_bitwise_equal(synthetic_joint_motion(num_samples, num_joints, **kwargs), expected)


def test_position_limit_clips_every_target():
    dut = synthetic_joint_motion(400, 3, noise_rad=0.0, seed=5, position_limit_rad=0.3)
    assert np.max(np.abs(dut)) <= 0.3 + 1e-12
    # Some joint sits exactly on the limit after a clipped reach.
    assert np.any(np.isclose(np.abs(dut), 0.3, rtol=0, atol=1e-12))


def test_joint_motion_noise_free_starts_at_offsets_and_has_bounded_steps():
    dut = synthetic_joint_motion(200, 4, dt_s=0.1, noise_rad=0.0, seed=3,
                                 joint_offset_step_rad=0.25)
    np.testing.assert_array_equal(dut[0], 0.25 * np.arange(4))
    # Peak minimum-jerk speed is 1.875 * reach / shortest duration.
    speed = np.abs(np.diff(dut, axis=0)) / 0.1
    assert speed.max() <= 1.875 * 0.4 / 2.0 + 1e-12


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(num_samples=0), r"num_samples = 0 must be an integer >= 1"),
        (dict(num_joints=1.5), r"num_joints = 1\.5 must be an integer"),
        (dict(dt_s=-0.25), r"dt_s = -0\.25 must be finite and > 0"),
        (dict(noise_rad=-1.0), r"noise_rad = -1\.0 must be finite and >= 0"),
        (dict(reach_duration_range_s=(3.0, 2.0)), r"reach_duration_range_s = \(3\.0, 2\.0\)"),
        (dict(pause_range_s=(-1.0, 2.0)), r"pause_range_s = \(-1\.0, 2\.0\)"),
        (dict(position_limit_rad=0.0), r"position_limit_rad = 0\.0 must be finite and > 0"),
    ],
)
def test_joint_motion_rejects_bad_arguments(kwargs, match):
    arguments = dict(num_samples=10, num_joints=2) | kwargs
    with pytest.raises(ValueError, match=match):
        synthetic_joint_motion(arguments.pop("num_samples"), arguments.pop("num_joints"),
                               **arguments)


# --- minimum jerk ---


def test_minimum_jerk_boundary_and_midpoint_values():
    t0, duration, start, end = 1.5, 2.0, -0.3, 0.9
    times = np.array([0.0, t0, t0 + 0.5 * duration, t0 + duration, 10.0])
    dut = minimum_jerk(times, t0, duration, start, end)
    # Before: start; at t0: start; midpoint: (start + end) / 2 exactly (10/8 - 15/16 + 6/32
    # = 1/2 in binary); at and after the end: end.
    expected = np.array([start, start, start + 0.5 * (end - start), end, end])
    np.testing.assert_array_equal(dut, expected)


def test_minimum_jerk_matches_closed_form_velocity_and_has_rest_ends():
    t0, duration, start, end = 0.5, 2.0, 0.2, -0.6
    h = 1e-4
    # Closed form: v = (end - start) / D * (30 s^2 - 60 s^3 + 30 s^4), peak 1.875 (end-start)/D.
    s = np.linspace(0.05, 0.95, 19)
    t = t0 + s * duration
    fd_velocity = (minimum_jerk(t + h, t0, duration, start, end)
                   - minimum_jerk(t - h, t0, duration, start, end)) / (2 * h)
    velocity = (end - start) / duration * (30 * s**2 - 60 * s**3 + 30 * s**4)
    np.testing.assert_allclose(fd_velocity, velocity, rtol=0, atol=1e-7)
    peak_speed = 1.875 * abs(end - start) / duration
    peak_acceleration = 10 / np.sqrt(3) * abs(end - start) / duration**2
    for t_end in (t0, t0 + duration):
        x = minimum_jerk(t_end + h * np.arange(-2, 3), t0, duration, start, end)
        velocity_fd = (x[3] - x[1]) / (2 * h)
        acceleration_fd = (x[3] - 2 * x[2] + x[1]) / h**2
        # Both are O(h^2) resp. O(h) at a rest end: ~1e-8 and ~1e-4 of their peaks.
        assert abs(velocity_fd) < 1e-6 * peak_speed
        assert abs(acceleration_fd) < 1e-3 * peak_acceleration


def test_minimum_jerk_vector_endpoints_equal_per_coordinate_scalars():
    t = np.linspace(-1.0, 4.0, 101)
    start, end = np.array([0.7, -0.1]), np.array([0.55, 0.2])
    dut = minimum_jerk(t, 0.0, 3.0, start, end)
    assert dut.shape == (101, 2)
    for axis in range(2):
        np.testing.assert_array_equal(dut[:, axis], minimum_jerk(t, 0.0, 3.0, start[axis],
                                                                  end[axis]))


# --- Cartesian synthetic operator ---


@pytest.fixture(scope="module")
def default_session():
    return synthetic_operator_session(SyntheticOperatorConfig())


def _low_pass(x, cutoff_hz, rate_hz):
    sos = scipy.signal.butter(4, cutoff_hz, btype="lowpass", output="sos", fs=rate_hz)
    return scipy.signal.sosfiltfilt(sos, x, axis=0)


def test_session_record_fields(default_session):
    config = SyntheticOperatorConfig()
    dut = default_session
    assert isinstance(dut, OperatorSession)
    assert dut.shape == "synthetic"
    assert dut.demo_index == config.seed
    assert dut.joint_names == AIR_BEARING_ARM.joint_names
    assert dut.t_s.shape == (6001,) and dut.xy_m.shape == (6001, 2)
    assert dut.q_rad.shape == (6001, 3)
    np.testing.assert_array_equal(dut.t_s, np.arange(6001) / 100.0)
    assert dut.mapping.haptic_rate_hz == 100.0
    assert dut.mapping.end_effector_angle_rad == 0.0
    assert (dut.mapping.hold_start_s, dut.mapping.hold_end_s) == (2.0, 4.0)
    for array in (dut.t_s, dut.xy_m, dut.q_rad):
        assert not array.flags.writeable


def test_tremor_power_is_in_its_band_with_the_configured_rms(default_session):
    config = SyntheticOperatorConfig()
    rate = config.haptic_rate_hz
    # Reaches and drift live below ~1 Hz; what is left above 4 Hz is the tremor.
    residual = default_session.xy_m - _low_pass(default_session.xy_m, 4.0, rate)
    frequencies = np.fft.rfftfreq(residual.shape[0], d=1.0 / rate)
    power = np.abs(np.fft.rfft(residual, axis=0)) ** 2
    in_band = (frequencies >= 8.0) & (frequencies <= 12.0)
    for axis in range(2):
        fraction = power[in_band, axis].sum() / power[1:, axis].sum()
        assert fraction > 0.5, f"axis {axis}: only {fraction:.2f} of the power in 8-12 Hz"
        assert 8.0 <= frequencies[np.argmax(power[:, axis])] <= 12.0
        rms = np.sqrt(np.mean(residual[:, axis] ** 2))
        assert abs(rms - config.tremor_rms_m) <= 0.2 * config.tremor_rms_m, rms


def test_noise_free_operator_stays_in_the_box_and_holds_exactly():
    config = SyntheticOperatorConfig(tremor_rms_m=0.0, drift_rate_m_per_sqrt_s=0.0, seed=5)
    dut = synthetic_operator_session(config)
    low = np.subtract(config.workspace_center_m, config.workspace_half_extents_m)
    high = np.add(config.workspace_center_m, config.workspace_half_extents_m)
    # Minimum-jerk profiles are monotone in [0, 1], so reaches between box points stay inside.
    assert np.all(dut.xy_m >= low - 1e-12) and np.all(dut.xy_m <= high + 1e-12)
    start_hold = dut.t_s <= config.hold_start_s
    end_hold = dut.t_s >= config.duration_s - config.hold_end_s
    assert np.all(dut.xy_m[start_hold] == dut.xy_m[0])
    assert np.all(dut.xy_m[end_hold] == dut.xy_m[-1])
    # It does move: several reaches spanning a good part of the box.
    speed = np.linalg.norm(np.diff(dut.xy_m, axis=0), axis=1) * config.haptic_rate_hz
    moving = speed > 1e-3
    num_reaches = int(np.sum(moving[1:] & ~moving[:-1]))
    assert num_reaches >= 8
    assert np.all(np.ptp(dut.xy_m, axis=0) > 0.5 * np.asarray(config.workspace_half_extents_m))


def test_drift_is_slow_bounded_and_starts_near_zero():
    config = SyntheticOperatorConfig(
        workspace_half_extents_m=(0.0, 0.0), tremor_rms_m=0.0, drift_limit_m=2e-3, seed=2
    )
    dut = synthetic_operator_session(config)
    drift = dut.xy_m - np.asarray(config.workspace_center_m)
    assert np.all(np.abs(drift) <= config.drift_limit_m)
    assert np.all(np.std(drift, axis=0) > 2e-4)  # it does wander (stationary std ~2 mm)
    assert np.all(np.abs(drift[0]) < 1e-4)
    # Slow: nothing above 4 Hz to speak of.
    high = drift - _low_pass(drift, 4.0, config.haptic_rate_hz)
    assert np.sqrt(np.mean(high**2)) < 1e-6


def test_same_seed_is_identical_and_other_seed_differs(default_session):
    again = synthetic_operator_session(SyntheticOperatorConfig())
    np.testing.assert_array_equal(again.xy_m, default_session.xy_m)
    np.testing.assert_array_equal(again.q_rad, default_session.q_rad)
    other = synthetic_operator_session(SyntheticOperatorConfig(seed=1))
    assert np.max(np.abs(other.xy_m - default_session.xy_m)) > 0.01


def test_seed_streams_are_independent():
    # Changing the tremor does not move the reach targets (own random stream).
    base = SyntheticOperatorConfig(drift_rate_m_per_sqrt_s=0.0, seed=4)
    without = synthetic_operator_session(dataclasses.replace(base, tremor_rms_m=0.0))
    with_tremor = synthetic_operator_session(base)
    assert np.max(np.abs(with_tremor.xy_m - without.xy_m)) < 10 * base.tremor_rms_m


@pytest.mark.parametrize("angle_rad", [0.0, 0.4])
def test_inverse_kinematics_round_trips(angle_rad):
    dut = synthetic_operator_session(
        SyntheticOperatorConfig(duration_s=20.0, end_effector_angle_rad=angle_rad, seed=3)
    )
    xy = planar_forward_kinematics(dut.q_rad, AIR_BEARING_ARM.link_lengths_m)
    np.testing.assert_allclose(xy, dut.xy_m, rtol=0, atol=1e-9)
    phi = planar_end_effector_angle(dut.q_rad)
    np.testing.assert_allclose(phi, angle_rad, rtol=0, atol=1e-9)


def test_unreachable_workspace_raises_clearly():
    config = SyntheticOperatorConfig(workspace_center_m=(1.05, 0.0), duration_s=10.0)
    with pytest.raises(ValueError, match=r"not reachable.*first unreachable sample is k = \d+.*"
                                         r"workspace_center_m = \(1\.05, 0\.0\)"):
        synthetic_operator_session(config)


@pytest.mark.parametrize(
    "field, value, match",
    [
        ("duration_s", 0.0, r"duration_s = 0\.0 must be finite and > 0"),
        ("haptic_rate_hz", float("nan"), r"haptic_rate_hz = nan"),
        ("workspace_center_m", (0.7,), r"workspace_center_m = \(0\.7,\) must have two entries"),
        ("workspace_half_extents_m", (0.1, -0.2),
         r"workspace_half_extents_m\[1\] = -0\.2 must be >= 0"),
        ("reach_duration_range_s", (0.0, 2.0), r"reach_duration_range_s = \(0\.0, 2\.0\)"),
        ("pause_range_s", (2.0, 1.0), r"pause_range_s = \(2\.0, 1\.0\)"),
        ("tremor_rms_m", -1e-4, r"tremor_rms_m = -0\.0001 must be finite and >= 0"),
        ("tremor_band_hz", (8.0, 60.0), r"tremor_band_hz = \(8\.0, 60\.0\).*50\.0"),
        ("drift_cutoff_hz", 9.0, r"drift_cutoff_hz = 9\.0 must be > 0 and below"),
        ("drift_limit_m", 0.0, r"drift_limit_m = 0\.0 must be finite and > 0"),
        ("hold_end_s", -1.0, r"hold_end_s = -1\.0 must be finite and >= 0"),
        ("end_effector_angle_rad", float("inf"), r"end_effector_angle_rad = inf"),
        ("seed", -3, r"seed = -3 must be a non-negative integer"),
        ("seed", 1.5, r"seed = 1\.5 must be a non-negative integer"),
        ("duration_s", 7.0, r"duration_s = 7\.0 leaves 1\.0 s between"),
    ],
)
def test_config_rejects_bad_fields(field, value, match):
    with pytest.raises(ValueError, match=match):
        SyntheticOperatorConfig(**{field: value})


def test_config_defaults_are_valid_and_normalised():
    dut = SyntheticOperatorConfig(workspace_center_m=[0.7, 0], tremor_band_hz=np.array([8, 12]))
    assert dut.workspace_center_m == (0.7, 0.0)
    assert dut.tremor_band_hz == (8.0, 12.0)
    assert dut.num_samples == 6001
    hash(dut)  # frozen and hashable, usable as a cache key
