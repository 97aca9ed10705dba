"""Hard-limited online mode (smoothing/online_hard.py): limits on adversarial streams, the
stoppable set against an independent LP, exact reproduction of feasible streams, validation."""

import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog

from telesmooth.smoothing.online_hard import (
    RULES,
    OnlineHardLimiter,
    online_hard_run,
    stop_position,
    stoppable_polygon,
)

DT = 0.25
RTOL = 1e-9  # allowed relative excess of the recomputed finite differences


def _finite_differences(positions, q_start, dt=DT):
    """(v, a, j) of [q_start × 3, p_0 …] recomputed with numpy, each (N, J)."""
    p = np.asarray(positions, dtype=float)
    history = np.vstack([np.repeat(np.asarray(q_start, dtype=float)[None], 3, axis=0), p])
    v = np.diff(history, 1, axis=0)[2:] / dt
    a = np.diff(history, 2, axis=0)[1:] / dt**2
    j = np.diff(history, 3, axis=0) / dt**3
    return v, a, j


def _assert_within_limits(positions, q_start, v_max, a_max, j_max):
    v, a, j = _finite_differences(positions, q_start)
    assert np.all(np.abs(v) <= np.asarray(v_max) * (1 + RTOL)), np.abs(v).max(axis=0)
    assert np.all(np.abs(a) <= np.asarray(a_max) * (1 + RTOL)), np.abs(a).max(axis=0)
    assert np.all(np.abs(j) <= np.asarray(j_max) * (1 + RTOL)), np.abs(j).max(axis=0)


def _can_stop_lp(velocity, acceleration, v_max, a_max, j_max, horizon, dt=DT):
    """Independent check: is there a jerk sequence u_1 … u_H within the limits that brings the
    FD state (v, a) to v = a = 0 (linprog feasibility, variables u)? The state itself must be
    within the limits too (it was sent)."""
    if abs(acceleration) > a_max or abs(velocity) > v_max:
        return False
    h = horizon
    # a_i = a + dt Σ_{k≤i} u_k ;  v_i = v + dt Σ_{k≤i} a_k = v + i dt a + dt² Σ_{k≤i} (i−k+1) u_k
    lower = np.tril(np.ones((h, h)))
    steps = np.arange(1, h + 1)
    acc_rows = dt * lower
    vel_rows = dt**2 * np.tril(steps[:, None] - steps[None, :] + 1.0)
    acc_free = acceleration * np.ones(h)
    vel_free = velocity + steps * dt * acceleration
    a_ub = [acc_rows, -acc_rows]
    b_ub = [a_max - acc_free, a_max + acc_free]
    if np.isfinite(v_max):
        a_ub += [vel_rows, -vel_rows]
        b_ub += [v_max - vel_free, v_max + vel_free]
    result = linprog(
        np.zeros(h), A_ub=np.vstack(a_ub), b_ub=np.concatenate(b_ub),
        A_eq=np.vstack([acc_rows[-1], vel_rows[-1]]),
        b_eq=np.array([-acc_free[-1], -vel_free[-1]]),
        bounds=[(-j_max, j_max)] * h, method="highs")
    return result.status == 0


# -- the stoppable set -------------------------------------------------------------------------

@pytest.mark.parametrize("limits", [(0.1, 0.05, 0.1), (0.1, 0.05, 0.01), (0.02, 0.05, 0.1),
                                    (0.3, 0.2, 0.05), (0.001, 0.05, 0.1)])
def test_stoppable_polygon_matches_linear_program(limits):
    v_max, a_max, j_max = limits
    dut = stoppable_polygon(v_max, a_max, j_max, DT)
    rng = np.random.default_rng(0)
    horizon = dut.steps + 40
    for angle in rng.uniform(0.0, 2 * np.pi, 24):
        direction = np.array([np.cos(angle) * v_max, np.sin(angle) * a_max])
        gauge = (dut.facets @ direction).max()  # boundary at t = 1/gauge along the ray
        inside, outside = direction * (1 - 1e-3) / gauge, direction * (1 + 1e-3) / gauge
        assert dut.contains(*inside) and not dut.contains(*outside)
        assert _can_stop_lp(*inside, v_max, a_max, j_max, horizon)
        assert not _can_stop_lp(*outside, v_max, a_max, j_max, horizon)


def test_stoppable_polygon_known_corner():
    # At v = v_max the acceleration may still be j_max Δt (one braking tick brings it to 0),
    # and a = a_max needs two braking ticks, i.e. v ≤ v_max − (a_max − j_max Δt) Δt.
    dut = stoppable_polygon(0.1, 0.05, 0.1, DT)
    assert dut.contains(0.1, 0.025, tolerance=1e-12)
    assert not dut.contains(0.1, 0.025 + 1e-6)
    assert dut.contains(0.1 - 0.00625, 0.05, tolerance=1e-12)
    assert not dut.contains(0.1 - 0.00625 + 1e-6, 0.05)


def test_stoppable_strip_without_velocity_limit():
    dut = stoppable_polygon(np.inf, 0.05, 0.1, DT)
    assert dut.contains(1e6, 0.05) and not dut.contains(0.0, 0.05 * (1 + 1e-9))


def test_stop_position_matches_simulated_bang_bang_stop():
    # F against a fine simulation of the switching policy: jerk −j_max down to −a_max (hold),
    # then +j_max once the remaining speed v equals a²/(2 j_max), until rest.
    a_max, j_max, dt = 0.05, 0.1, 1e-4
    for v, a in [(0.2, 0.03), (0.01, -0.02), (-0.15, 0.0), (0.001, 0.04), (0.05, -0.05)]:
        s = 1.0 if v + a * abs(a) / (2 * j_max) >= 0 else -1.0
        pos, vel, acc = 0.0, s * v, s * a
        while vel > 1e-12 or acc > 1e-12:
            if acc < 0 and vel <= acc * acc / (2 * j_max):
                jerk = j_max
            elif acc > -a_max:
                jerk = -j_max
            else:
                jerk = 0.0
            step = dt
            if jerk == -j_max and acc > -a_max:
                step = min(dt, (acc + a_max) / j_max) or dt
            pos += vel * step + acc * step**2 / 2 + jerk * step**3 / 6
            vel += acc * step + jerk * step**2 / 2
            acc = max(acc + jerk * step, -a_max)
            if jerk == j_max and acc >= 0:
                break
        np.testing.assert_allclose(s * pos, stop_position(0.0, v, a, a_max, j_max),
                                   rtol=1e-3, atol=1e-6)


# -- limits hold on adversarial streams --------------------------------------------------------

def _segment(kind, length, level, scale, rng_seed):
    rng = np.random.default_rng(rng_seed)
    t = np.arange(length)
    if kind == "step":
        return np.full(length, level + scale)
    if kind == "spike":
        out = np.full(length, level)
        out[length // 2] += 5 * scale
        return out
    if kind == "reversal":
        return level + scale * np.where(t % 4 < 2, 1.0, -1.0)
    if kind == "noise":
        return level + scale * rng.normal(size=length)
    if kind == "ramp":  # far beyond any v_max used here
        return level + 2.0 * scale * t
    return np.full(length, level)  # "constant"


@st.composite
def _streams(draw):
    num_joints = draw(st.integers(1, 3))
    segments = draw(st.lists(st.tuples(
        st.sampled_from(["step", "spike", "reversal", "noise", "ramp", "constant"]),
        st.integers(1, 12), st.floats(-1.0, 1.0), st.floats(1e-4, 2.0),
        st.integers(0, 2**31 - 1)), min_size=1, max_size=6))
    columns = []
    for j in range(num_joints):
        column = [_segment(kind, n, level, scale, seed + j) for kind, n, level, scale, seed
                  in segments]
        columns.append(np.concatenate(column))
    estimates = np.stack(columns, axis=1)
    limit = st.floats(0.02, 1.0)
    a_max = np.array(draw(st.lists(limit, min_size=num_joints, max_size=num_joints)))
    j_max = np.array(draw(st.lists(limit, min_size=num_joints, max_size=num_joints)))
    v_max = np.array(draw(st.lists(st.one_of(st.just(np.inf), st.floats(0.01, 0.5)),
                                   min_size=num_joints, max_size=num_joints)))
    q_start = np.array(draw(st.lists(st.floats(-3.0, 3.0), min_size=num_joints,
                                     max_size=num_joints)))
    return estimates, q_start, v_max, a_max, j_max, draw(st.sampled_from(RULES)), draw(
        st.booleans())


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_streams())
def test_limits_hold_and_state_stays_stoppable(stream):
    estimates, q_start, v_max, a_max, j_max, rule, use_lookahead = stream
    dut = OnlineHardLimiter(dt_s=DT, max_acceleration=a_max, max_jerk=j_max,
                            max_velocity=v_max, q_start=q_start, rule=rule)
    sent = []
    for k, estimate in enumerate(estimates):
        lookahead = estimates[k + 1:k + 4] if use_lookahead and k + 4 <= len(estimates) else None
        sent.append(dut.step(estimate, lookahead))
        for j, polygon in enumerate(dut.stoppable_sets):
            # The state is in S (up to the ulps the limiter itself repairs each tick).
            assert polygon.contains(dut.current_velocity[j], dut.current_acceleration[j],
                                    tolerance=1e-9)
    _assert_within_limits(sent, q_start, v_max, a_max, j_max)
    # Stoppable, checked independently of the limiter: a stop within all limits exists.
    v, a, _ = _finite_differences(sent, q_start)
    for j in range(len(q_start)):
        if np.isfinite(v_max[j]):
            horizon = dut.stoppable_sets[j].steps + 5
            assert _can_stop_lp(v[-1, j], a[-1, j], v_max[j] * (1 + 1e-6), a_max[j] * (1 + 1e-6),
                                j_max[j] * (1 + 1e-6), horizon)
    # A constant estimate (the last command) brings the braking rule to rest, within limits.
    if rule == "braking":
        hold = dut.current_position
        tail = [dut.step(hold) for _ in range(300)]
        _assert_within_limits(np.vstack([sent, tail]), q_start, v_max, a_max, j_max)
        v_tail, a_tail, _ = _finite_differences(np.vstack([sent, tail]), q_start)
        scale = np.maximum(1.0, np.abs(hold))
        assert np.all(np.abs(v_tail[-3:]) <= 1e-9 * scale / DT), v_tail[-3:]
        assert np.all(np.abs(a_tail[-3:]) <= 1e-9 * scale / DT**2), a_tail[-3:]


def test_one_step_greedy_without_the_stoppable_set_breaks_the_limits():
    """The set is needed: clamping u_hit to the one-step box (|u| ≤ j, |a'| ≤ a, |v'| ≤ v)
    corners itself at full velocity while still accelerating."""
    v_max, a_max, j_max = 0.09, 0.05, 0.1
    estimates = np.full(40, 2.0)
    p = [0.0, 0.0, 0.0]
    for target in estimates:
        vel = (p[-1] - p[-2]) / DT
        acc = (p[-1] - 2 * p[-2] + p[-3]) / DT**2
        u_hit = ((target - p[-1]) / DT - vel - acc * DT) / DT**2
        lo = max(-j_max, (-a_max - acc) / DT, ((-v_max - vel) / DT - acc) / DT)
        hi = min(j_max, (a_max - acc) / DT, ((v_max - vel) / DT - acc) / DT)
        u = min(max(u_hit, lo), hi) if lo <= hi else 0.5 * (lo + hi)
        acc_new = acc + u * DT
        p.append(p[-1] + (vel + acc_new * DT) * DT)
    v, a, j = _finite_differences(np.array(p[3:])[:, None], [0.0])
    assert (np.abs(v).max() > v_max * 1.01 or np.abs(a).max() > a_max * 1.01
            or np.abs(j).max() > j_max * 1.01)
    # The limiter on the same stream stays within the limits.
    sent = online_hard_run(estimates[:, None], DT, max_acceleration=a_max, max_jerk=j_max,
                           max_velocity=v_max, q_start=[0.0], rule="greedy")
    _assert_within_limits(sent, [0.0], v_max, a_max, j_max)


# -- exact reproduction and tracking ----------------------------------------------------------

def _feasible_stream(num_samples, q_start, v_max, a_max, j_max, seed):
    """A stream inside the (0.9 ×) limits: random jerk chosen inside the stoppable set."""
    rng = np.random.default_rng(seed)
    gen = OnlineHardLimiter(dt_s=DT, max_acceleration=0.9 * a_max, max_jerk=0.9 * j_max,
                            max_velocity=0.9 * v_max, q_start=q_start, rule="greedy")
    out = []
    for _ in range(num_samples):
        lo, hi = gen.admissible_jerk()
        u = lo + (hi - lo) * rng.uniform(size=lo.shape)
        pos, vel, acc = gen.current_position, gen.current_velocity, gen.current_acceleration
        out.append(gen.step(pos + (vel + (acc + u * DT) * DT) * DT))
    return np.array(out)


@pytest.mark.parametrize("rule", RULES)
@pytest.mark.parametrize("v_max", [np.inf, 0.1])
def test_feasible_stream_is_reproduced_exactly(rule, v_max):
    q_start = np.array([0.3, -1.2, 2.0])
    a_max, j_max = np.array([0.05, 0.05, 0.2]), np.array([0.1, 0.02, 0.1])
    estimates = _feasible_stream(300, q_start, v_max, a_max, j_max, seed=4)
    _assert_within_limits(estimates, q_start, v_max, 0.9 * a_max, 0.9 * j_max)
    sent = online_hard_run(estimates, DT, max_acceleration=a_max, max_jerk=j_max,
                           max_velocity=v_max, q_start=q_start, rule=rule)
    np.testing.assert_allclose(sent, estimates, rtol=0, atol=1e-12)


@pytest.mark.parametrize("v_max", [np.inf, 0.1])
def test_braking_rule_does_not_overshoot_a_step_and_beats_greedy(v_max):
    estimates = np.zeros((160, 1))
    estimates[4:] = 0.5
    kwargs = dict(max_acceleration=0.05, max_jerk=0.1, max_velocity=v_max, q_start=[0.0])
    braking = online_hard_run(estimates, DT, rule="braking", **kwargs)
    greedy = online_hard_run(estimates, DT, rule="greedy", **kwargs)
    assert braking.max() <= 0.5 + 1e-6  # the band is solved by grid + secant, not exactly
    assert greedy.max() > 0.55
    np.testing.assert_allclose(braking[-1], 0.5, atol=1e-9)
    assert np.abs(braking - estimates).mean() < 0.5 * np.abs(greedy - estimates).mean()


# -- run-time robustness and validation --------------------------------------------------------

def test_non_finite_estimate_brakes_and_is_reported():
    dut = OnlineHardLimiter(dt_s=DT, max_acceleration=0.05, max_jerk=0.1, q_start=[0.0, 0.0],
                            joint_names=["shoulder", "elbow"])
    for _ in range(12):
        dut.step([1.0, 1.0])
    moving = dut.current_velocity[1]
    assert moving > 0.01
    sent = []
    with pytest.warns(RuntimeWarning, match=r"joint 1 \('elbow'\) = nan"):
        for _ in range(60):
            sent.append(dut.step([1.0, np.nan]))
    assert dut.last_held.tolist() == [False, True]
    assert np.all(np.isfinite(sent))
    np.testing.assert_allclose(dut.current_velocity[1], 0.0, atol=1e-12)
    np.testing.assert_allclose(dut.current_acceleration[1], 0.0, atol=1e-12)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        dut.step([1.0, 1.0])
    assert not dut.last_held.any()


def test_reset_returns_to_rest():
    dut = OnlineHardLimiter(dt_s=DT, max_acceleration=0.05, max_jerk=0.1, q_start=[0.0])
    for _ in range(5):
        dut.step([1.0])
    dut.reset([0.7])
    assert dut.current_position.tolist() == [0.7]
    assert dut.current_velocity.tolist() == [0.0] and dut.current_acceleration.tolist() == [0.0]
    assert dut.sent_history.tolist() == [[0.7]] * 4 and dut.ticks == 0
    with pytest.raises(ValueError, match=r"^q = \[0.1, 0.2\] has shape \(2,\); expected \(1,\)"):
        dut.reset([0.1, 0.2])
    with pytest.raises(ValueError, match=r"^q\[0\] = nan for joint 0 must be finite$"):
        dut.reset([np.nan])


@pytest.mark.parametrize("kwargs, message", [
    (dict(max_acceleration=[0.05, -1.0]),
     r"max_acceleration_rad_per_s2\[1\] = -1.0 for joint 1 \('elbow'\) must be finite and > 0"),
    (dict(max_jerk=[np.nan, 0.1]),
     r"max_jerk_rad_per_s3\[0\] = nan for joint 0 \('shoulder'\) must be finite and > 0"),
    (dict(max_jerk=np.inf), r"max_jerk_rad_per_s3\[0\] = inf .* must be finite and > 0"),
    (dict(max_velocity=[0.0, 1.0]), r"max_velocity_rad_per_s\[0\] = 0.0 .* must be > 0"),
    (dict(max_acceleration=[0.05, 0.05, 0.05]), r"max_acceleration_rad_per_s2 has 3 value"),
    (dict(q_start=[0.0, np.inf]), r"q_start\[1\] = inf for joint 1 \('elbow'\) must be finite"),
    (dict(dt_s=0.0), r"dt_s = 0.0 must be finite and > 0"),
    (dict(rule="fast"), r"rule = 'fast' must be one of"),
])
def test_invalid_settings_name_field_value_and_joint(kwargs, message):
    arguments = dict(dt_s=DT, max_acceleration=0.05, max_jerk=0.1, q_start=[0.0, 0.0],
                     joint_names=["shoulder", "elbow"])
    arguments.update(kwargs)
    with pytest.raises(ValueError, match=message):
        OnlineHardLimiter(**arguments)


def test_invalid_shapes():
    dut = OnlineHardLimiter(dt_s=DT, max_acceleration=0.05, max_jerk=0.1, q_start=[0.0, 0.0])
    with pytest.raises(ValueError, match=r"estimate_now has shape \(3,\); expected \(2,\)"):
        dut.step([0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"lookahead has shape \(2,\)"):
        dut.step([0.0, 0.0], lookahead=[0.0, 0.0])
    with pytest.raises(ValueError, match=r"estimates must have shape"):
        online_hard_run(np.zeros(5), DT, max_acceleration=0.05, max_jerk=0.1)
    with pytest.raises(ValueError, match=r"lookahead has shape \(5, 3\)"):
        online_hard_run(np.zeros((5, 2)), DT, max_acceleration=0.05, max_jerk=0.1,
                        lookahead=np.zeros((5, 3)))
    with pytest.raises(ValueError, match=r"estimates\[0:1\]\[0, 1\] = nan"):
        online_hard_run(np.array([[0.0, np.nan]]), DT, max_acceleration=0.05, max_jerk=0.1)


# --- as a smoothing method (smoothing.methods) ---


def test_online_hard_method_is_online_cks_through_the_limiter():
    from telesmooth.smoothing.methods import (
        SmoothingSettings,
        finite_difference_states,
        smooth_recording,
    )
    from telesmooth.smoothing.metrics import finite_differences

    rng = np.random.default_rng(4)
    z = np.cumsum(rng.normal(0.0, 0.02, (120, 3)), axis=0)
    settings_ = SmoothingSettings(max_acceleration=[0.05, 0.1, 0.2], max_jerk=0.1,
                                  max_velocity=0.3)
    hard = smooth_recording(z, 0.25, "online-hard", settings_)
    online = smooth_recording(z, 0.25, "online-cks", settings_)
    expected = online_hard_run(online.positions, 0.25, max_acceleration=[0.05, 0.1, 0.2],
                               max_jerk=0.1, max_velocity=0.3, q_start=z[0])
    np.testing.assert_array_equal(hard.positions, expected)
    assert hard.sent_delay_s == online.sent_delay_s == 0.75
    sent = np.vstack([np.repeat(z[:1], 3, axis=0), hard.positions])
    assert np.all(np.abs(finite_differences(sent, 0.25, 1)) <= 0.3 * (1 + 1e-9))
    assert np.all(np.abs(finite_differences(sent, 0.25, 2)) <= np.array([0.05, 0.1, 0.2])
                  * (1 + 1e-9))
    assert np.all(np.abs(finite_differences(sent, 0.25, 3)) <= 0.1 * (1 + 1e-9))
    # The states are the sent sequence's backward differences (an independent loop).
    states = finite_difference_states(hard.positions, z[0], 0.25)
    np.testing.assert_array_equal(states, hard.states)
    for k in (0, 1, 2, 57):
        window = sent[k:k + 4]  # p_{k-3} … p_k
        assert states[k, :, 1] == pytest.approx((window[3] - window[2]) / 0.25, abs=1e-12)
        assert states[k, :, 2] == pytest.approx(
            (window[3] - 2 * window[2] + window[1]) / 0.25**2, abs=1e-10)
        assert states[k, :, 3] == pytest.approx(
            (window[3] - 3 * window[2] + 3 * window[1] - window[0]) / 0.25**3, abs=1e-9)


def test_state_vector_round_trip_continues_identically():
    rng = np.random.default_rng(9)
    stream = np.cumsum(rng.normal(0.0, 0.05, (60, 2)), axis=0)
    reference = OnlineHardLimiter(dt_s=0.25, max_acceleration=0.05, max_jerk=0.1,
                                  max_velocity=0.2, q_start=[0.0, 0.0])
    expected = [reference.step(r) for r in stream]
    first = OnlineHardLimiter(dt_s=0.25, max_acceleration=0.05, max_jerk=0.1, max_velocity=0.2,
                              q_start=[0.0, 0.0])
    out = [first.step(r) for r in stream[:25]]
    # A fresh limiter (another process, a Drake Context) continues from the saved state.
    second = OnlineHardLimiter(dt_s=0.25, max_acceleration=0.05, max_jerk=0.1,
                               max_velocity=0.2, q_start=[5.0, 5.0])
    second.set_state_vector(first.get_state_vector())
    assert second.ticks == 25
    out += [second.step(r) for r in stream[25:]]
    np.testing.assert_array_equal(np.array(out), np.array(expected))
    with pytest.raises(ValueError, match="state vector has shape"):
        second.set_state_vector(np.zeros(3))


def test_large_hulls_by_qhull_equal_the_monotone_chain():
    """Above _LARGE_HULL points the hull is Qhull's: the same vertices (as a set, in
    counter-clockwise order) as the monotone chain on points of a convex polygon's Minkowski
    sum with a segment (the stoppable-set recursion's input), collinear points dropped."""
    from telesmooth.safety import limiter

    rng = np.random.default_rng(7)
    angles = np.sort(rng.uniform(0, 2 * np.pi, 400))
    polygon = np.column_stack([np.cos(angles), 0.3 * np.sin(angles)])
    segment = np.array([0.01, 0.002])
    points = np.vstack([polygon + segment, polygon - segment,
                        0.5 * (polygon[:50] + polygon[1:51])])       # interior and edge points
    assert len(points) > limiter._LARGE_HULL
    fast = limiter._convex_hull(points)
    chain_points = np.unique(np.round(points, 15), axis=0)
    original, limiter._LARGE_HULL = limiter._LARGE_HULL, 10**9
    try:
        slow = limiter._convex_hull(chain_points)
    finally:
        limiter._LARGE_HULL = original
    assert {tuple(p) for p in fast} == {tuple(p) for p in slow}
    area = 0.5 * np.sum(fast[:, 0] * np.roll(fast[:, 1], -1)
                        - np.roll(fast[:, 0], -1) * fast[:, 1])
    assert area > 0                                                  # counter-clockwise


def test_extreme_limit_ratios_give_a_certified_polygon_in_seconds():
    """a_max/(j_max Δt) ≈ 440: hundreds of vertices (the Qhull path); the polygon certifies
    itself (stoppable_polygon raises otherwise) and contains rest."""
    dut = stoppable_polygon(6.64, 0.0518, 0.00118, 0.1)
    assert len(dut.vertices) > 100
    assert dut.contains(0.0, 0.0)
