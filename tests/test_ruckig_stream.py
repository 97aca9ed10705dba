"""Ruckig on a stream (smoothing/ruckig_stream.py): the peer baseline of the experiment."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from telesmooth.smoothing.methods import SmoothingSettings, smooth_recording
from telesmooth.smoothing.metrics import finite_differences
from telesmooth.smoothing.ruckig_stream import ruckig_stream

pytest.importorskip("ruckig")


def bang_bang_position(t, distance, jerk):
    """Closed form of the time-optimal rest-to-rest move with only a jerk limit.

    Jerk +J on [0, τ], −J on [τ, 3τ], +J on [3τ, 4τ] with D = 2Jτ³; integrated exactly piece by
    piece (position, velocity, acceleration carried across the switching times).
    """
    tau = (abs(distance) / (2.0 * jerk)) ** (1.0 / 3.0)
    sign = np.sign(distance)
    switches = [(0.0, jerk), (tau, -jerk), (3 * tau, jerk), (4 * tau, 0.0)]
    out = np.empty_like(t)
    for index, time in enumerate(t):
        p = v = a = 0.0
        for (begin, j), (end, _) in zip(switches, switches[1:] + [(np.inf, 0.0)]):
            if time <= begin:
                break
            h = min(time, end) - begin
            p, v, a = p + v * h + a * h**2 / 2 + j * h**3 / 6, v + a * h + j * h**2 / 2, a + j * h
        out[index] = sign * p
    return out, 4 * tau


def test_a_step_is_the_closed_form_time_optimal_jerk_limited_move():
    dt = 0.25
    distances = np.array([0.3, -0.05])
    jerk = np.array([0.1, 0.2])
    z = np.zeros((80, 2))
    z[1:] = distances  # the operator steps at sample 1 and holds
    states = ruckig_stream(z, dt, max_acceleration=10.0, max_jerk=jerk, start=[0.0, 0.0])
    for joint in range(2):
        # The update for sample k starts at t_{k−1} and ends at t_k; the step is the target
        # from sample 1 on, so the move starts at t_0 and sample k is p(t_k).
        t = dt * np.arange(80)
        expected, duration = bang_bang_position(t, distances[joint], jerk[joint])
        assert duration < t[-1]
        np.testing.assert_allclose(states[:, joint, 0], expected, rtol=0, atol=1e-9)
        assert states[-1, joint, 0] == pytest.approx(distances[joint], abs=1e-12)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(arrays(float, (40, 2), elements=st.floats(-1.0, 1.0)),
       st.sampled_from(["rest", "moving"]), st.sampled_from(["none", "time"]))
def test_finite_differences_of_the_sent_stream_are_within_the_limits(z, target, sync):
    dt, a_max, j_max, v_max = 0.25, np.array([0.05, 0.2]), np.array([0.1, 0.5]), 0.3
    states = ruckig_stream(z, dt, max_acceleration=a_max, max_jerk=j_max, max_velocity=v_max,
                           target=target, synchronization=sync, start=[0.0, 0.0])
    # The robot at rest before the stream; the stream may end while Ruckig still moves (it
    # trails), so nothing is appended after it.
    sent = np.vstack([np.zeros((3, 2)), states[:, :, 0]])
    assert np.all(np.abs(finite_differences(sent, dt, 1)) <= v_max * (1 + 1e-9))
    assert np.all(np.abs(finite_differences(sent, dt, 2)) <= a_max * (1 + 1e-9))
    assert np.all(np.abs(finite_differences(sent, dt, 3)) <= j_max * (1 + 1e-9))
    # The state Ruckig reports is consistent with its positions (velocity within its limit).
    assert np.all(np.abs(states[:, :, 1]) <= v_max * (1 + 1e-9))


def test_smooth_recording_ruckig_is_ruckig_stream_from_the_first_sample():
    rng = np.random.default_rng(1)
    z = np.cumsum(rng.normal(0, 0.01, (30, 3)), axis=0)
    settings_ = SmoothingSettings(max_acceleration=0.05, max_jerk=0.1)
    result = smooth_recording(z, 0.25, "ruckig", settings_)
    states = ruckig_stream(z, 0.25, max_acceleration=0.05, max_jerk=0.1)
    np.testing.assert_array_equal(result.states, states)
    assert result.sent_delay_s == 0.0


@pytest.mark.parametrize("kwargs, message", [
    ({"max_acceleration": np.inf}, r"max_acceleration\[0\] = inf for joint 0 \('j0'\)"),
    ({"max_jerk": [0.1, -1.0]}, r"max_jerk\[1\] = -1.0 for joint 1 \('j1'\)"),
    ({"target": "ahead"}, r"target = 'ahead'"),
    ({"synchronization": "phase"}, r"synchronization = 'phase'"),
    ({"start": [0.0, np.nan]}, r"start"),
])
def test_bad_settings_are_named(kwargs, message):
    arguments = {"max_acceleration": 0.05, "max_jerk": 0.1, **kwargs}
    with pytest.raises(ValueError, match=message):
        ruckig_stream(np.zeros((5, 2)), 0.25, joint_names=("j0", "j1"), **arguments)
