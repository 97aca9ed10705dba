"""Tests for telesmooth.smoothing.reduced_q: Online-CKS (BMFLS + reduced-Q σ), docs/method.md §4.

Covers the σ invariants (non-increasing, never below σ_min) for every variant/step/trigger,
the reduction to BMFLS when nothing triggers, the literal variant-A update rule, the two step
rules by hand, claim C8 (the second operation with the σ reached is smoother) and the
per-operator σ file.
"""

import json

import numpy as np
import pytest

from telesmooth.smoothing.fixed_lag import FixedLagSmoother
from telesmooth.smoothing.metrics import finite_differences
from telesmooth.smoothing.model import JerkModel
from telesmooth.smoothing.reduced_q import (
    REDUCED_Q_VARIANTS,
    SIGMA_STEP_RULES,
    VIOLATION_TRIGGERS,
    OnlineCks,
    ReducedQConfig,
    decrease_sigma,
)
from telesmooth.smoothing.sigma_store import (
    SIGMA_FILE_FORMAT,
    load_operator_sigma,
    save_operator_sigma,
)

DT = 0.25
R = 1e-6
SIGMA0 = 4e-4
A_MAX = 0.05  # rad/s², docs/method.md §4
J_MAX = 0.1  # rad/s³


def minimum_jerk_reach(start, amplitude, duration_s, dt):
    """Samples 1..n of a minimum-jerk reach from ``start`` by ``amplitude`` over duration_s."""
    n = int(round(duration_s / dt))
    s = np.arange(1, n + 1) / n
    return start + amplitude * (10 * s**3 - 15 * s**4 + 6 * s**5)


# (amplitude [rad], duration [s]) per reach: 0.2–0.5 rad in 5–10 s, 2 s rest around each.
REACHES = ((0.2, 5.0), (-0.5, 10.0), (0.3, 6.0), (0.4, 7.0), (-0.3, 8.0))
REST_SAMPLES = 8


def recorded_motion(seed=0, reaches=REACHES, noise=1e-3):
    """One joint: rest, a few minimum-jerk reaches with rests between, plus N(0, noise²)."""
    q = [0.0] * REST_SAMPLES
    for amplitude, duration in reaches:
        q.extend(minimum_jerk_reach(q[-1], amplitude, duration, DT))
        q.extend([q[-1]] * REST_SAMPLES)
    q = np.array(q)[:, None]
    return q + np.random.default_rng(seed).normal(0.0, noise, q.shape)


def noisy_walk(seed, num_samples=80, num_joints=3, scale=0.01):
    """A rough random walk that breaks tight limits often (many triggers)."""
    rng = np.random.default_rng(seed)
    return np.cumsum(rng.normal(0.0, scale, (num_samples, num_joints)), axis=0)


def make_model(num_joints=1, sigma=SIGMA0):
    return JerkModel.make(DT, sigma, R, num_joints=num_joints)


# --- σ invariants ---


@pytest.mark.parametrize("trigger", VIOLATION_TRIGGERS)
@pytest.mark.parametrize("step_rule", SIGMA_STEP_RULES)
@pytest.mark.parametrize("variant", REDUCED_Q_VARIANTS)
def test_sigma_is_non_increasing_and_never_below_sigma_min(variant, step_rule, trigger):
    z = noisy_walk(seed=1)
    sigma_min = 2e-6
    config = ReducedQConfig(variant=variant, step_rule=step_rule, trigger=trigger,
                            sigma_min=sigma_min, delta_sigma=3e-5, max_retries=20)
    dut = OnlineCks(make_model(3), max_acceleration=[0.02, 0.01, 0.03],
                    max_jerk=[0.05, 0.02, 0.1], config=config)

    run = dut.run(z)

    sigma = np.vstack([np.full((1, 3), SIGMA0), run.sigma])
    steps = np.diff(sigma, axis=0)
    assert steps.max() <= 0.0, "σ increased"
    assert run.sigma.min() >= sigma_min
    np.testing.assert_array_equal(run.final_state.sigma, run.sigma[-1])
    # Not vacuous: the limits were broken and σ did come down on every joint.
    assert run.triggered.any(axis=0).all()
    assert np.all(run.sigma[-1] < SIGMA0)
    assert np.all(np.isfinite(run.outputs))


def test_sigma_reaches_but_never_passes_sigma_min():
    z = noisy_walk(seed=2, num_samples=120, num_joints=1, scale=0.05)
    sigma_min = 1e-5  # 4e-4 · 0.8^k passes 1e-5 after 17 triggered cycles
    dut = OnlineCks(make_model(), max_acceleration=1e-3, max_jerk=1e-3,
                    config=ReducedQConfig(sigma_min=sigma_min))

    run = dut.run(z)

    assert run.triggered.sum() > 17
    assert run.sigma.min() == sigma_min
    assert run.sigma[-1, 0] == sigma_min


# --- equivalence with BMFLS ---


@pytest.mark.parametrize("trigger", VIOLATION_TRIGGERS)
@pytest.mark.parametrize("variant", REDUCED_Q_VARIANTS)
def test_without_triggers_online_cks_equals_bmfls_exactly(variant, trigger):
    z = noisy_walk(seed=3, num_joints=2)
    model = make_model(2)
    dut = OnlineCks(model, max_acceleration=1e6, max_jerk=1e6, lag=3,
                    config=ReducedQConfig(variant=variant, trigger=trigger))

    run = dut.run(z)
    expected = FixedLagSmoother(model, lag=3).run(z)

    assert not run.triggered.any()
    np.testing.assert_array_equal(run.sigma, np.full_like(run.sigma, SIGMA0))
    np.testing.assert_array_equal(run.outputs, expected)


def test_infinite_limits_are_accepted_and_never_trigger():
    z = noisy_walk(seed=4, num_joints=1)
    dut = OnlineCks(make_model(), max_acceleration=np.inf, max_jerk=np.inf)
    run = dut.run(z)
    assert not run.triggered.any()
    np.testing.assert_array_equal(run.outputs, FixedLagSmoother(make_model(), lag=3).run(z))


# --- variant A: one step per triggered cycle, applied from the next cycle ---


@pytest.mark.parametrize("trigger", VIOLATION_TRIGGERS)
@pytest.mark.parametrize("step_rule", SIGMA_STEP_RULES)
def test_variant_a_changes_sigma_only_after_a_triggered_cycle(step_rule, trigger):
    z = recorded_motion(seed=5)
    config = ReducedQConfig(variant="A", step_rule=step_rule, trigger=trigger,
                            sigma_min=1e-12, delta_sigma=1e-6)
    dut = OnlineCks(make_model(), max_acceleration=A_MAX, max_jerk=J_MAX, config=config)

    run = dut.run(z)

    before = np.concatenate([[SIGMA0], run.sigma[:-1, 0]])
    after = run.sigma[:, 0]
    triggered = run.triggered[:, 0]
    assert 0 < triggered.sum() < len(triggered)  # both kinds of cycles occur
    assert before.min() > 1e-12  # σ_min never reached, so every trigger must change σ
    np.testing.assert_array_equal(after != before, triggered)
    if step_rule == "multiplicative":
        np.testing.assert_allclose(after[triggered], 0.8 * before[triggered], rtol=1e-15)
    else:
        np.testing.assert_allclose(after[triggered], before[triggered] - 1e-6, rtol=1e-12)


def test_variant_a_uses_the_new_sigma_from_the_next_cycle():
    z = recorded_motion(seed=5)
    model = make_model()
    dut = OnlineCks(model, max_acceleration=A_MAX, max_jerk=J_MAX,
                    config=ReducedQConfig(sigma_min=1e-12))
    run = dut.run(z)
    # Replaying BMFLS with σ_k = σ in effect after cycle k−1 reproduces the outputs.
    schedule = np.vstack([[[SIGMA0]], run.sigma[:-1]])
    replay = FixedLagSmoother(model, lag=3).run(z, sigma_schedule=schedule)
    assert run.triggered.any()
    np.testing.assert_allclose(replay, run.outputs, rtol=0, atol=1e-15)


# --- the step rules by hand ---


def test_multiplicative_step_by_hand():
    config = ReducedQConfig(step_rule="multiplicative", rho=0.8)
    sigma = np.array([4e-4, 1.2e-7, 1.0e-7, 5e-8])
    result = decrease_sigma(sigma, 1e-7, config)
    # 0.8·4e-4 = 3.2e-4; 0.8·1.2e-7 = 9.6e-8 → clipped to 1e-7; at σ_min stays; below σ_min
    # (a stored σ smaller than this run's σ_min) is never raised.
    np.testing.assert_allclose(result, [3.2e-4, 1e-7, 1e-7, 5e-8], rtol=1e-15)


def test_multiplicative_step_with_per_joint_sigma_min():
    config = ReducedQConfig(rho=0.5)
    result = decrease_sigma([1.0, 1.0, 1.0], np.array([0.1, 0.6, 2.0]), config)
    np.testing.assert_allclose(result, [0.5, 0.6, 1.0], rtol=1e-15)


def test_additive_step_by_hand():
    config = ReducedQConfig(step_rule="additive")
    sigma = np.array([4e-4, 2e-5, 1.5e-5, 1e-5])
    result = decrease_sigma(sigma, 1e-5, config, delta_sigma=1e-5)
    np.testing.assert_allclose(result, [3.9e-4, 1e-5, 1e-5, 1e-5], rtol=1e-12)


def test_default_additive_step_is_sigma0_over_40_and_default_sigma_min_ratio():
    z = noisy_walk(seed=6, num_joints=1, scale=0.05)
    dut = OnlineCks(make_model(), max_acceleration=1e-3, max_jerk=1e-3,
                    config=ReducedQConfig(step_rule="additive"))
    run = dut.run(z)
    # After m triggered cycles σ = max(σ_0 − m σ_0/40, 2.5e-4 σ_0) (defaults, 1e-7 here).
    triggers = np.cumsum(run.triggered[:, 0])
    assert triggers[-1] >= 40
    expected = np.maximum(SIGMA0 - SIGMA0 / 40 * triggers, 1e-7)
    np.testing.assert_allclose(run.sigma[:, 0], expected, rtol=1e-9)
    assert run.sigma[-1, 0] == pytest.approx(1e-7, rel=1e-12)


# --- variants B: retries within the cycle ---


@pytest.mark.parametrize("variant", ("B1", "B2"))
def test_b_variants_retry_until_the_output_is_within_limits_or_sigma_min(variant):
    z = recorded_motion(seed=7)
    sigma_min = 1e-7
    dut = OnlineCks(make_model(), max_acceleration=A_MAX, max_jerk=J_MAX,
                    config=ReducedQConfig(variant=variant, sigma_min=sigma_min))
    state = dut.initial_state(z[0])
    for k in range(len(z)):
        previous = state.sigma.copy()
        state, output, triggered = dut.step(state, z[k])
        if triggered[0]:
            # Retried: σ dropped by at least one step (or was already at σ_min).
            assert state.sigma[0] <= max(0.8 * previous[0], sigma_min) * (1 + 1e-15)
        else:
            assert state.sigma[0] == previous[0]
    assert state.sigma[0] < SIGMA0


# --- claim C8: the next operation with the σ reached is smoother ---

# Reaches that break a_max/j_max (peak 5.77 A/T², 60 A/T³): the first operation drives σ down.
C8_REACHES = ((0.4, 5.0), (-0.5, 7.0), (0.3, 5.0), (0.5, 8.0), (-0.4, 6.0))
# Gentler reaches (also 0.2–0.5 rad in 5–10 s): the first operation stops at σ ≈ 1e-5.
GENTLE_REACHES = ((0.3, 6.0), (-0.5, 8.0), (0.4, 5.0), (0.2, 10.0), (-0.35, 7.0))


def two_operations(trigger, seed=0, reaches=C8_REACHES):
    """The same recorded motion twice, the second starting from the σ the first reached
    (docs/method.md §4 settings: r = 1e-6, σ_0 = 4e-4, ρ = 0.8, σ_min = 1e-7,
    limits 0.05 / 0.1)."""
    z = recorded_motion(seed, reaches=reaches)
    config = ReducedQConfig(variant="A", step_rule="multiplicative", rho=0.8, sigma_min=1e-7,
                            trigger=trigger)
    dut = OnlineCks(make_model(), max_acceleration=A_MAX, max_jerk=J_MAX, lag=3, config=config)
    first = dut.run(z)
    second = dut.run(z, sigma0=first.final_state.sigma)
    return first, second


def fd_jerk(run):
    """|FD jerk| of the sent positions x̂_{k−3|k}[0], shape (N − 3, J)."""
    return np.abs(finite_differences(run.outputs[:, :, 0], DT, 3))


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
@pytest.mark.parametrize("trigger", VIOLATION_TRIGGERS)
def test_claim_c8_second_operation_is_smoother(trigger, seed):
    first, second = two_operations(trigger, seed)

    # σ never increases from one operation to the next.
    assert first.final_state.sigma[0] < SIGMA0
    assert second.sigma.max() <= first.final_state.sigma[0]
    # Smoother: lower max FD jerk, fewer triggered cycles, fewer cycles over j_max.
    assert fd_jerk(second).max() < fd_jerk(first).max()
    assert second.triggered.sum() < first.triggered.sum()
    assert (fd_jerk(second) > J_MAX).sum() < (fd_jerk(first) > J_MAX).sum()


@pytest.mark.parametrize("trigger", VIOLATION_TRIGGERS)
def test_claim_c8_gentle_motion_has_lower_fd_jerk(trigger):
    first, second = two_operations(trigger, seed=0, reaches=GENTLE_REACHES)
    assert second.sigma.max() <= first.final_state.sigma[0] < SIGMA0
    assert fd_jerk(second).max() < fd_jerk(first).max()


@pytest.mark.xfail(
    strict=True,
    reason="C8 'fewer triggered cycles' does not hold for every motion with the default "
    "state trigger (algorithmic, not a code bug): here the first operation stops at "
    "σ = 1.1e-5 after 16 triggers; the second one starts there, goes to σ_min and triggers "
    "40 times, because at low σ the lag-3 output's acceleration *state* lags and overshoots "
    "during a reach, although the sent positions are smoother (max FD jerk 0.137 → 0.091)",
)
def test_claim_c8_gentle_motion_state_trigger_triggers_less():
    first, second = two_operations("state", seed=0, reaches=GENTLE_REACHES)
    assert second.triggered.sum() < first.triggered.sum()


# --- per-operator σ persistence ---

JOINTS = ["shoulder", "elbow", "wrist"]


def test_sigma_file_round_trip_is_exact(tmp_path):
    path = tmp_path / "sigma.json"
    sigma = np.array([1.0 / 3.0 * 1e-4, 2.0e-5, 3.3e-7])
    save_operator_sigma(path, "alice", JOINTS, sigma)

    loaded = load_operator_sigma(path, "alice", JOINTS)

    np.testing.assert_array_equal(loaded, sigma)
    data = json.loads(path.read_text())
    assert data["format"] == SIGMA_FILE_FORMAT
    assert not (tmp_path / "sigma.json.tmp").exists()


def test_sigma_file_is_read_by_joint_name(tmp_path):
    path = tmp_path / "sigma.json"
    save_operator_sigma(path, "alice", JOINTS, [1e-4, 2e-4, 3e-4])
    loaded = load_operator_sigma(path, "alice", ["wrist", "shoulder", "elbow"])
    np.testing.assert_array_equal(loaded, [3e-4, 1e-4, 2e-4])


def test_two_operators_are_kept_in_one_file(tmp_path):
    path = tmp_path / "sigma.json"
    save_operator_sigma(path, "alice", JOINTS, [1e-4, 2e-4, 3e-4])
    save_operator_sigma(path, "bob", JOINTS, [4e-5, 5e-5, 6e-5])
    save_operator_sigma(path, "alice", JOINTS, [1e-5, 2e-5, 3e-5])  # update alice only

    np.testing.assert_array_equal(load_operator_sigma(path, "alice", JOINTS), [1e-5, 2e-5, 3e-5])
    np.testing.assert_array_equal(load_operator_sigma(path, "bob", JOINTS), [4e-5, 5e-5, 6e-5])
    assert sorted(json.loads(path.read_text())["operators"]) == ["alice", "bob"]


def test_unknown_operator_is_rejected(tmp_path):
    path = tmp_path / "sigma.json"
    save_operator_sigma(path, "alice", JOINTS, 1e-4)
    save_operator_sigma(path, "bob", JOINTS, 1e-4)
    with pytest.raises(ValueError) as error:
        load_operator_sigma(path, "carol", JOINTS)
    message = str(error.value)
    assert "operator = 'carol' has no stored sigma" in message
    assert "known: ['alice', 'bob']" in message


def test_joint_missing_from_file_is_rejected(tmp_path):
    path = tmp_path / "sigma.json"
    save_operator_sigma(path, "alice", JOINTS[:2], [1e-4, 2e-4])
    with pytest.raises(ValueError, match=r"no value given for joint\(s\) \['wrist'\]"):
        load_operator_sigma(path, "alice", JOINTS)


def test_extra_joint_in_file_is_rejected(tmp_path):
    path = tmp_path / "sigma.json"
    save_operator_sigma(path, "alice", JOINTS, [1e-4, 2e-4, 3e-4])
    with pytest.raises(ValueError, match=r"unknown joint name\(s\) \['wrist'\]"):
        load_operator_sigma(path, "alice", JOINTS[:2])


@pytest.mark.parametrize("value", [0.0, -1e-4, "NaN", "Infinity", '"1e-4"'])
def test_non_positive_or_non_finite_sigma_in_file_is_rejected(tmp_path, value):
    path = tmp_path / "sigma.json"
    path.write_text(
        f'{{"format": "{SIGMA_FILE_FORMAT}", '
        f'"operators": {{"alice": {{"shoulder": 1e-4, "elbow": {value}}}}}}}'
    )
    with pytest.raises(ValueError) as error:
        load_operator_sigma(path, "alice", ["shoulder", "elbow"])
    message = str(error.value)
    assert "operator 'alice', joint 'elbow'" in message
    assert "must be finite and > 0" in message


def test_saving_non_positive_sigma_is_rejected(tmp_path):
    path = tmp_path / "sigma.json"
    with pytest.raises(ValueError, match=r"sigma\[1\] = -1e-05 for joint 1 \('elbow'\)"):
        save_operator_sigma(path, "alice", JOINTS, [1e-4, -1e-5, 1e-4])
    assert not path.exists()


@pytest.mark.parametrize("name", ["", "  ", None])
def test_saving_without_operator_name_is_rejected(tmp_path, name):
    with pytest.raises(ValueError, match="must be a non-empty name"):
        save_operator_sigma(tmp_path / "sigma.json", name, JOINTS, 1e-4)


def test_corrupt_json_is_rejected_and_not_overwritten(tmp_path):
    path = tmp_path / "sigma.json"
    path.write_text('{"format": "telesmooth-operator-sigma/1", "operators": {')
    with pytest.raises(ValueError, match="not a valid sigma file"):
        load_operator_sigma(path, "alice", JOINTS)
    with pytest.raises(ValueError, match="not a valid sigma file"):
        save_operator_sigma(path, "alice", JOINTS, 1e-4)
    assert path.read_text().endswith('"operators": {')  # the user's file is left alone


@pytest.mark.parametrize(
    "data, fragment",
    [
        ({"format": "telesmooth-operator-sigma/2", "operators": {}}, "format must be"),
        ({"operators": {}}, "format must be"),
        ([1, 2], "format must be"),
        ({"format": SIGMA_FILE_FORMAT, "operators": []}, "'operators' must be a mapping"),
        ({"format": SIGMA_FILE_FORMAT, "operators": {"alice": 1e-4}},
         "operator 'alice' must map joint names to sigma"),
    ],
)
def test_wrong_file_format_is_rejected(tmp_path, data, fragment):
    path = tmp_path / "sigma.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=fragment):
        load_operator_sigma(path, "alice", JOINTS)


def test_stored_sigma_starts_the_next_operation(tmp_path):
    path = tmp_path / "sigma.json"
    z = recorded_motion(seed=0)
    dut = OnlineCks(make_model(), max_acceleration=A_MAX, max_jerk=J_MAX,
                    config=ReducedQConfig(sigma_min=1e-7), joint_names=["elbow"])
    first = dut.run(z)
    save_operator_sigma(path, "alice", ["elbow"], first.final_state.sigma)

    second = dut.run(z, sigma0=load_operator_sigma(path, "alice", ["elbow"]))
    direct = dut.run(z, sigma0=first.final_state.sigma)

    np.testing.assert_array_equal(second.outputs, direct.outputs)
    assert second.sigma.max() <= first.final_state.sigma[0]


# --- configuration validation ---


@pytest.mark.parametrize(
    "kwargs, fragment",
    [
        ({"variant": "C"}, "variant = 'C' must be one of ('A', 'B1', 'B2')"),
        ({"variant": "a"}, "variant = 'a'"),
        ({"step_rule": "exponential"}, "step_rule = 'exponential' must be one of"),
        ({"trigger": "velocity"}, "trigger = 'velocity' must be one of ('state', 'fd')"),
        ({"rho": 0.0}, "rho = 0.0 must be in (0, 1)"),
        ({"rho": 1.0}, "rho = 1.0 must be in (0, 1)"),
        ({"rho": 1.5}, "rho = 1.5 must be in (0, 1)"),
        ({"rho": -0.2}, "rho = -0.2 must be in (0, 1)"),
        ({"rho": float("nan")}, "rho = nan must be in (0, 1)"),
        ({"sigma_min": -1e-7}, "sigma_min = -1e-07 must be finite and > 0"),
        ({"sigma_min": 0.0}, "sigma_min = 0.0 must be finite and > 0"),
        ({"delta_sigma": -1e-5}, "delta_sigma = -1e-05 must be finite and > 0"),
        ({"max_retries": -1}, "max_retries = -1 must be an integer >= 0"),
        ({"max_retries": 2.5}, "max_retries = 2.5 must be an integer >= 0"),
    ],
)
def test_invalid_config_names_the_field(kwargs, fragment):
    with pytest.raises(ValueError) as error:
        ReducedQConfig(**kwargs)
    assert fragment in str(error.value)


def test_invalid_limits_name_the_joint():
    with pytest.raises(ValueError) as error:
        OnlineCks(make_model(2), max_acceleration=[0.05, -0.1], max_jerk=0.1,
                  joint_names=["shoulder", "elbow"])
    assert "max_acceleration_rad_per_s2[1] = -0.1 for joint 1 ('elbow') must be > 0" in str(
        error.value)


@pytest.mark.parametrize("kwargs, field", [({"rho": "0.5"}, "rho"), ({"rho": None}, "rho"),
                                           ({"max_retries": "x"}, "max_retries")])
def test_non_numeric_config_values_name_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        ReducedQConfig(**kwargs)
