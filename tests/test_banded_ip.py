"""The banded interior point for Offline-CKS against independent solutions.

Oracles: the RTS smoother (its problem without limits), the dense interior point with an
active-set KKT certificate of tests/test_offline.py (written out independently from
docs/method.md §2.3/§2.6), the Drake MathematicalProgram (Clarabel), and at Δt = 0.01 s, where
no dense or generic solver is reliable (cond ≈ 1e17), the KKT conditions checked on the returned
point.
"""

import numpy as np
import pytest
from core_fixtures import operator_recording
from test_offline import _assert_same_states, _dense_qp

from telesmooth.smoothing import offline
from telesmooth.smoothing.banded_ip import BandedIpOptions, BandedQp, solve_banded_qp
from telesmooth.smoothing.kalman import rest_prior, rts_smoother
from telesmooth.smoothing.metrics import VIOLATION_RTOL
from telesmooth.smoothing.model import JerkModel
from telesmooth.smoothing.offline import banded_problem, solve_offline_cks

SIGMA, R = 4e-4, 1e-6
ACC, JERK, VEL = 0.05, 0.1, 0.1


def _setup(dt, num_samples=40, num_joints=2, seed=21):
    z = operator_recording(num_samples=num_samples, num_joints=num_joints, dt=dt, seed=seed)
    return z, JerkModel.make(dt, SIGMA, R, num_joints=num_joints)


@pytest.mark.parametrize("dt", [0.25, 0.01])
def test_problem_without_limits_is_the_rts_smoother(dt):
    """argmin ½‖Ay − c‖² by a dense least-squares solve equals the RTS means."""
    z, model = _setup(dt, num_samples=24, num_joints=1)
    prior = rest_prior(z[0], model)
    a, c, f, *_ = banded_problem(z[:, 0], model, 0, prior, z[0, 0], np.inf, np.inf, np.inf,
                                 "none", False)
    assert f.shape[0] == 0
    # Column scaling keeps the dense solve accurate (the columns span 8 orders at 100 Hz).
    dense = a.toarray()
    norms = np.linalg.norm(dense, axis=0)
    q, rr = np.linalg.qr(dense / norms)
    y = np.linalg.solve(rr, q.T @ c) / norms
    states = model.from_scaled(y.reshape(-1, 4) + [z[0, 0], 0, 0, 0])
    rts = rts_smoother(z, model, prior).mean[:, 0]
    _assert_same_states(states, rts, dt, atol=1e-8 if dt == 0.25 else 1e-6)


@pytest.mark.parametrize("route", ["cholesky", "qr"])
@pytest.mark.parametrize("constraint,vel,rest_at_end", [
    ("state", None, False), ("trajectory", None, False), ("trajectory", VEL, True),
    ("both", None, True)])
def test_matches_the_dense_certified_optimum(route, constraint, vel, rest_at_end):
    z, model = _setup(0.25, seed=22)
    result = solve_offline_cks(z, model, max_acceleration=ACC, max_jerk=JERK, max_velocity=vel,
                               constraint=constraint, rest_at_end=rest_at_end,
                               solver="banded-ip",
                               banded_options=BandedIpOptions(linear_solver=route))
    assert result.is_success, result.solution_results
    assert result.solver_name == "banded-ip"
    for j in range(2):
        dense = _dense_qp(z[:, j], model, j, constraint=constraint, acc=ACC, jerk=JERK,
                          vel=vel, rest_at_end=rest_at_end)
        _assert_same_states(result.states[:, j], dense, 0.25)


@pytest.mark.parametrize("constraint", ["state", "trajectory", "both"])
def test_agrees_with_the_mathematical_program(constraint):
    """Within 1e-6 of the Drake/Clarabel solution (scaled states, rad)."""
    z, model = _setup(0.25, num_samples=120, num_joints=3, seed=5)
    kwargs = dict(max_acceleration=ACC, max_jerk=JERK, constraint=constraint, rest_at_end=True)
    drake = solve_offline_cks(z, model, **kwargs)
    banded = solve_offline_cks(z, model, solver="banded-ip", **kwargs)
    assert drake.is_success and banded.is_success
    assert drake.solver_name == "Clarabel" and banded.solver_name == "banded-ip"
    _assert_same_states(banded.states, drake.states, 0.25, atol=1e-6)
    # The limits bind, or the comparison would only be of two RTS passes.
    rts = rts_smoother(z, model, rest_prior(z[0], model)).mean
    assert np.abs(rts[:, :, 2]).max() > 1.2 * ACC


def test_cholesky_and_qr_routes_agree():
    z, model = _setup(0.1, num_samples=200, num_joints=1, seed=3)
    kwargs = dict(max_acceleration=ACC, max_jerk=JERK, constraint="trajectory",
                  rest_at_end=True, solver="banded-ip")
    states = [solve_offline_cks(z, model, banded_options=BandedIpOptions(linear_solver=route),
                                **kwargs).states for route in ("cholesky", "qr")]
    _assert_same_states(states[0], states[1], 0.1, atol=1e-8)


def _kkt_check(z, model, result_states, constraint, rest_at_end, vel=np.inf):
    """Returns (primal excess, stationarity residual relative to the terms, active rows) of
    the banded problem at the returned point: the multipliers are the least-squares fit of
    −∇f by the active rows (upper rows +F, lower rows −F); a negative one fails the check by
    counting as a residual."""
    prior = rest_prior(z[0], model)
    a, c, f, lower, upper, fixed = banded_problem(z[:, 0], model, 0, prior, z[0, 0], ACC,
                                                  JERK, vel, constraint, rest_at_end)
    y = (model.to_scaled(result_states[:, 0]) - [z[0, 0], 0, 0, 0]).ravel()
    values = f @ y
    excess = max(0.0, np.max(values - upper), np.max(lower - values))
    gradient = a.T @ (a @ y - c)
    free = ~fixed
    active_up = np.flatnonzero(values > upper - 1e-7)
    active_low = np.flatnonzero(values < lower + 1e-7)
    columns = np.hstack([f[active_up].T.toarray(), -f[active_low].T.toarray()])[free]
    scale = np.max(np.abs(a.T) @ (np.abs(a) @ np.abs(y) + np.abs(c)))
    if columns.shape[1] == 0:
        return excess, np.max(np.abs(gradient[free])) / scale, 0
    norms = np.linalg.norm(columns, axis=0)
    multipliers = np.linalg.lstsq(columns / norms, -gradient[free], rcond=None)[0]
    residual = np.max(np.abs(columns / norms @ multipliers + gradient[free]))
    wrong_sign = np.max(np.maximum(-multipliers, 0.0), initial=0.0)
    return excess, max(residual, wrong_sign) / scale, len(active_up) + len(active_low)


@pytest.mark.parametrize("constraint,rest_at_end", [("trajectory", False),
                                                    ("trajectory", True), ("state", False)])
def test_100hz_solution_satisfies_the_kkt_conditions(constraint, rest_at_end):
    """At Δt = 0.01 s Clarabel fails; the square-root route's answer is certified by KKT:
    feasible, and −∇f is a non-negative combination of the active limit rows."""
    z = np.zeros((150, 1))
    z[40:] = 0.05                     # a 50 mrad step: far beyond the limits at 100 Hz
    z += 1e-4 * np.random.default_rng(4).normal(size=z.shape)
    model = JerkModel.make(0.01, SIGMA, R, num_joints=1)
    result = solve_offline_cks(z, model, max_acceleration=ACC, max_jerk=JERK,
                               constraint=constraint, rest_at_end=rest_at_end,
                               solver="banded-ip")
    assert result.is_success, result.solution_results
    excess, stationarity, active = _kkt_check(z, model, result.states, constraint, rest_at_end)
    assert active > 0
    assert excess <= 1e-9
    assert stationarity <= 1e-9
    if constraint == "trajectory":
        p = np.concatenate([np.full(3, z[0, 0]), result.states[:, 0, 0]]
                           + ([np.full(3, result.states[-1, 0, 0])] if rest_at_end else []))
        for order, limit in ((2, ACC), (3, JERK)):
            fd = np.diff(p, n=order) / 0.01**order
            assert np.abs(fd).max() <= limit * (1 + VIOLATION_RTOL)


def test_a_perturbed_point_is_not_certified():
    """The KKT check above can fail: move the certified 100 Hz optimum a little."""
    z = np.zeros((150, 1))
    z[40:] = 0.05
    model = JerkModel.make(0.01, SIGMA, R, num_joints=1)
    result = solve_offline_cks(z, model, max_acceleration=ACC, max_jerk=JERK,
                               constraint="trajectory", solver="banded-ip")
    assert result.is_success
    states = result.states.copy()
    states[75:, 0, 0] += 1e-7          # 0.1 µrad on half the positions
    excess, stationarity, _ = _kkt_check(z, model, states, "trajectory", False)
    assert excess > 1e-9 or stationarity > 1e-9


def test_options_and_solver_are_checked():
    z, model = _setup(0.25, num_samples=10, num_joints=1)
    with pytest.raises(ValueError, match="solver = 'osqp'"):
        solve_offline_cks(z, model, solver="osqp")
    with pytest.raises(ValueError, match="linear_solver = 'lu'"):
        BandedIpOptions(linear_solver="lu")
    with pytest.raises(ValueError, match="max_iterations = 0"):
        BandedIpOptions(max_iterations=0)
    with pytest.raises(ValueError, match="primal_tolerance = -1"):
        BandedIpOptions(primal_tolerance=-1.0)


def test_iteration_limit_is_reported_not_raised():
    z, model = _setup(0.25, num_samples=60, num_joints=1, seed=9)
    result = solve_offline_cks(z, model, max_acceleration=ACC, max_jerk=JERK,
                               constraint="trajectory", solver="banded-ip",
                               banded_options=BandedIpOptions(max_iterations=2))
    assert not result.is_success
    assert result.solution_results == ("banded-ip: max_iterations",)
    assert np.all(np.isnan(result.states))


def test_unconstrained_problem_returns_the_least_squares_point():
    z, model = _setup(0.25, num_samples=30, num_joints=1)
    prior = rest_prior(z[0], model)
    a, c, f, lower, upper, fixed = banded_problem(z[:, 0], model, 0, prior, z[0, 0], np.inf,
                                                  np.inf, np.inf, "none", False)
    result = solve_banded_qp(a, c, f, lower, upper, fixed, np.zeros(a.shape[1]))
    assert result.converged and result.iterations == 1
    rts = model.to_scaled(rts_smoother(z, model, prior).mean[:, 0]) - [z[0, 0], 0, 0, 0]
    np.testing.assert_allclose(result.y.reshape(-1, 4), rts, atol=1e-8)


def _one_mrad_step():
    """A 1 mrad step in 8 samples at 100 Hz: nearly degenerate (j_max Δt³ = 1e-7 rad)."""
    z = np.zeros((8, 1))
    z[4:] = 1e-3
    return z, JerkModel.make(0.01, SIGMA, R, num_joints=1)


def test_drake_falls_back_to_the_banded_solver_when_clarabel_fails(monkeypatch):
    """Clarabel's failure is forced (whether it fails on its own depends on the last bits of
    the problem's data, so on the machine): the joint's answer is then the banded IP's."""
    z, model = _one_mrad_step()
    kwargs = dict(max_acceleration=ACC, max_jerk=JERK, constraint="trajectory")
    real, calls = offline._solve_joint_drake, []

    def failing(*args):
        calls.append(real(*args))
        return {**calls[-1], "success": False, "result": "forced", "states": None}

    monkeypatch.setattr(offline, "_solve_joint_drake", failing)
    result = solve_offline_cks(z, model, **kwargs)
    assert len(calls) == 1 and result.is_success
    assert result.solver_name == "Clarabel failed (forced), banded-ip fallback"
    assert result.build_time_s[0] >= calls[0]["build_time"]
    direct = solve_offline_cks(z, model, solver="banded-ip", **kwargs)
    np.testing.assert_array_equal(result.states, direct.states)


def test_a_nearly_degenerate_problem_is_solved_within_its_limits_by_either_solver():
    """On this problem Clarabel stops short at every rung of its ladder on some machines (seen:
    InsufficientProgress, a numerical error) and the banded IP answers; either way the answer
    is a solution and meets the limits it promises."""
    z, model = _one_mrad_step()
    result = solve_offline_cks(z, model, max_acceleration=ACC, max_jerk=JERK,
                               constraint="trajectory")
    assert result.is_success, result.solution_results
    assert result.solver_name == "Clarabel" or result.solver_name.endswith(
        "banded-ip fallback"), result.solver_name
    received = np.concatenate([np.full(3, z[0, 0]), result.states[:, 0, 0]])  # rest before
    for order, limit in ((2, ACC), (3, JERK)):
        fd = np.abs(np.diff(received, n=order)) / model.dt_s**order
        assert fd.max() <= limit * (1 + VIOLATION_RTOL), (order, fd.max(), limit)


def test_joints_in_threads_give_the_same_result_as_one_after_the_other():
    z, model = _setup(0.25, num_samples=60, num_joints=3, seed=31)
    kwargs = dict(max_acceleration=ACC, max_jerk=JERK, constraint="trajectory",
                  solver="banded-ip")
    serial = solve_offline_cks(z, model, threads=1, **kwargs)
    threaded = solve_offline_cks(z, model, threads=3, **kwargs)
    assert serial.is_success and threaded.is_success
    assert np.count_nonzero(serial.solve_time_s) >= 2      # at least two joints were solved
    np.testing.assert_array_equal(threaded.states, serial.states)
    assert threaded.solution_results == serial.solution_results
    with pytest.raises(ValueError, match="threads"):
        solve_offline_cks(z, model, threads=0, **kwargs)


def test_the_reported_measures_are_finite_when_converged():
    z, model = _setup(0.25, seed=23)
    problem = banded_problem(z[:, 0], model, 0, rest_prior(z[0], model), z[0, 0], ACC, JERK,
                             np.inf, "trajectory", False)
    result = solve_banded_qp(*problem, np.zeros(problem[0].shape[1]))
    assert result.converged
    assert 0.0 <= result.dual_residual <= BandedIpOptions().dual_tolerance
    assert 0.0 <= result.gap <= BandedIpOptions().gap_tolerance
    capped = solve_banded_qp(*problem, np.zeros(problem[0].shape[1]),
                             BandedIpOptions(max_iterations=2))
    assert not capped.converged and capped.status == "max_iterations"
    assert np.isfinite(capped.dual_residual) and capped.dual_residual > 0.0


@pytest.mark.parametrize("dt", [0.25, 0.01])
def test_unconstrained_optimum_is_the_rts_smoother(dt):
    """The banded route's start (and ckbs step 1 answer): the RTS means, without RTS."""
    from telesmooth.smoothing.banded_ip import BandedQp

    z, model = _setup(dt, num_samples=200, num_joints=1, seed=27)
    prior = rest_prior(z[0], model)
    problem = banded_problem(z[:, 0], model, 0, prior, z[0, 0], ACC, JERK, np.inf,
                             "trajectory", False)
    qp = BandedQp(*problem, BandedIpOptions())
    states = model.from_scaled(qp.unconstrained_optimum().reshape(-1, 4) + [z[0, 0], 0, 0, 0])
    rts = rts_smoother(z, model, prior).mean[:, 0]
    _assert_same_states(states, rts, dt, atol=1e-8 if dt == 0.25 else 1e-6)


def test_a_joint_whose_unconstrained_optimum_meets_the_limits_is_returned_as_is():
    z, model = _setup(0.25, num_samples=60, num_joints=2, seed=29)
    loose = solve_offline_cks(z, model, max_acceleration=1e3, max_jerk=1e3, solver="banded-ip")
    assert loose.is_success and loose.solution_results == ("kSolutionFound",) * 2
    np.testing.assert_array_equal(loose.objective, 0.0)
    rts = rts_smoother(z, model, rest_prior(z[0], model)).mean
    _assert_same_states(loose.states[:, 0], rts[:, 0], 0.25, atol=1e-8)
    _assert_same_states(loose.states[:, 1], rts[:, 1], 0.25, atol=1e-8)


@pytest.mark.parametrize("rest_at_end", [False, True])
def test_both_solvers_report_the_same_objective(rest_at_end):
    """The cost above the RTS smoother's, whatever the solver (with the rest at the end too)."""
    z, model = _setup(0.25, num_samples=40, num_joints=2, seed=33)
    kwargs = dict(max_acceleration=ACC, max_jerk=JERK, constraint="trajectory",
                  rest_at_end=rest_at_end)
    drake = solve_offline_cks(z, model, **kwargs)
    banded = solve_offline_cks(z, model, solver="banded-ip", **kwargs)
    assert drake.is_success and banded.is_success
    _assert_same_states(banded.states[:, 0], drake.states[:, 0], 0.25, atol=1e-6)
    np.testing.assert_allclose(banded.objective, drake.objective, rtol=1e-4, atol=1e-12)
    assert np.all(banded.objective >= 0.0)


@pytest.mark.parametrize("constraint", ["state", "trajectory"])
def test_agrees_with_the_mathematical_program_to_a_microradian(constraint):
    """Within a microradian of the Drake/Clarabel positions with the default tolerances, on the
    benchmark's data."""
    from telesmooth.scripts.bench_core import MAX_ACCELERATION, MAX_JERK, synthetic_operator
    from telesmooth.smoothing.model import DEFAULT_DT_S, DEFAULT_R, DEFAULT_SIGMA

    z = synthetic_operator(1000, 3, seed=1000)
    model = JerkModel.make(DEFAULT_DT_S, DEFAULT_SIGMA, DEFAULT_R, num_joints=3)
    kwargs = dict(max_acceleration=MAX_ACCELERATION, max_jerk=MAX_JERK, constraint=constraint)
    drake = solve_offline_cks(z, model, **kwargs)
    banded = solve_offline_cks(z, model, solver="banded-ip", **kwargs)
    assert drake.is_success and banded.is_success
    assert np.any(banded.objective > 0)          # the limits bind
    assert np.max(np.abs(banded.states[:, :, 0] - drake.states[:, :, 0])) <= 1e-6


def test_a_regularised_step_that_fails_twice_in_one_iteration_falls_back_to_qr():
    # Very tight tolerances drive the normal equations to the edge of definiteness: the
    # regularised Cholesky + CG then misses the predictor's and the corrector's right-hand
    # sides of the same iteration; both must go to the square-root route (a corrector left
    # on the failed Cholesky ends in "numerical_failure").
    from telesmooth.scripts.bench_core import MAX_ACCELERATION, MAX_JERK, synthetic_operator
    from telesmooth.smoothing.model import DEFAULT_DT_S, DEFAULT_R, DEFAULT_SIGMA

    z = synthetic_operator(1000, 6, seed=1000)
    model = JerkModel.make(DEFAULT_DT_S, DEFAULT_SIGMA, DEFAULT_R, num_joints=6)
    tight = BandedIpOptions(dual_tolerance=1e-11, gap_tolerance=1e-15, primal_tolerance=1e-12,
                            max_iterations=200)
    result = solve_offline_cks(z, model, max_acceleration=MAX_ACCELERATION, max_jerk=MAX_JERK,
                               constraint="trajectory", solver="banded-ip",
                               banded_options=tight)
    assert result.is_success, result.solution_results


@pytest.mark.parametrize("chunk_rows", [1, 3, 7, 1 << 15])
def test_band_helpers_against_dense_matrices(monkeypatch, chunk_rows):
    """_gram_band (the band of AᵀA from A's rows, in chunks of rows, repeated entries of a
    row summed first), _RepeatingBand, _half_bandwidth and _max_step against dense /
    brute-force computations."""
    from scipy import sparse

    from telesmooth.smoothing import banded_ip
    from telesmooth.smoothing.banded_ip import (
        _gram_band,
        _half_bandwidth,
        _max_step,
        _RepeatingBand,
    )
    monkeypatch.setattr(banded_ip, "_CHUNK_ROWS", chunk_rows)
    monkeypatch.setattr(banded_ip, "_GRAM_CHUNK_ROWS", chunk_rows)
    rng = np.random.default_rng(5)
    a = sparse.random(30, 20, density=0.0, random_state=1, format="lil")
    for row in range(30):                       # rows spanning at most 6 columns
        start = rng.integers(0, 15)
        for col in rng.choice(np.arange(start, start + 6), size=3, replace=False):
            a[row, col] = rng.standard_normal()
    a = a.tocsr()
    f = sparse.csr_matrix(np.eye(20)[[2, 5]] - np.eye(20)[[11, 6]])  # spans 9 and 1
    dense = (a.T @ a).toarray()
    rows, cols = np.nonzero(dense)
    assert _half_bandwidth(a, f) == max(int(np.max(np.abs(rows - cols))), 9)
    band = _gram_band(a, 7)
    for offset in range(8):
        np.testing.assert_allclose(band[: 20 - offset, offset], np.diag(dense, -offset),
                                   rtol=1e-14, atol=1e-14)
        np.testing.assert_array_equal(band[20 - offset:, offset], 0.0)
    # A CSR row repeating a column (row 1: column 3 twice, then column 4): MᵀM of the sum.
    duplicated = sparse.csr_matrix(([1.0, 2.0, 8.0, 4.0], [3, 3, 4, 2], [0, 0, 3, 4]),
                                   shape=(3, 6))
    assert not duplicated.has_canonical_format
    gram = (sparse.csr_matrix(duplicated.toarray()).T @ duplicated.toarray())
    twice = _gram_band(duplicated, 3)
    for offset in range(4):
        np.testing.assert_array_equal(twice[: 6 - offset, offset], np.diag(gram, -offset))
    assert twice[3, 0] == 9.0 and twice[3, 1] == 24.0 and twice[2, 0] == 16.0
    # The repeating-block storage gives the band back exactly, whatever repeats.
    periodic = np.tile(rng.standard_normal((4, 5)), (30, 1))
    periodic[:4] += 1.0
    periodic[-8:-5] -= 2.0
    for full in (periodic, rng.standard_normal((120, 5)), rng.standard_normal((6, 5))):
        stored = _RepeatingBand(full)
        np.testing.assert_array_equal(stored.expand(np.empty_like(full)), full)
    assert _RepeatingBand(periodic).rows.tolist() == [0, 28]
    values = (rng.uniform(0.1, 1.0, 50), rng.uniform(0.1, 1.0, 7))
    steps = (rng.standard_normal(50), np.abs(rng.standard_normal(7)))
    brute = min(-v / d for vs, ds in zip(values, steps) for v, d in zip(vs, ds) if d < 0)
    assert _max_step(values, steps) == brute
    assert _max_step((np.ones(3),), (np.ones(3),)) == np.inf
    assert _max_step((np.zeros(0),), (np.zeros(0),)) == np.inf


def _solver_of_a_4hz_joint():
    """solve(options) of one joint's trajectory-mode problem: 1000 samples at 4 Hz."""
    from telesmooth.datasets.synthetic import synthetic_joint_motion
    from telesmooth.smoothing.model import DEFAULT_DT_S, DEFAULT_R, DEFAULT_SIGMA

    z = synthetic_joint_motion(1000, 6, dt_s=DEFAULT_DT_S, noise_rad=1e-3, seed=1000,
                               position_limit_rad=1.5)[:, 1]
    model = JerkModel.make(DEFAULT_DT_S, DEFAULT_SIGMA, DEFAULT_R, num_joints=1)
    problem = banded_problem(z, model, 0, rest_prior(z[:1], model), z[0], 0.05, 0.1, np.inf,
                             "trajectory", False)

    def solve(options):
        qp = BandedQp(*problem, options)
        return qp.run(qp.unconstrained_optimum())

    return solve


@pytest.mark.parametrize("where", ["factorisation", "solve"])
def test_a_breakdown_within_ten_times_the_gap_tolerance_ends_the_solve(monkeypatch, where):
    """When the normal equations lose definiteness at an iterate already within 10× of the gap
    tolerance, that iterate is returned instead of finishing by the slow QR route, and it is
    the optimum to 1e-7 rad (reference: the QR route, which never stops at a breakdown).

    Nothing here depends on one LAPACK build's rounding. Whether a given recording breaks
    down by itself differs between builds, so the breakdown is forced: the factorisation, or
    the solve with its factor, fails whenever the solver may stop there. Whether some iterate
    lands within 10× of a fixed tolerance differs too (here the last gap is 1.54e-15 against
    the default 1e-15; elsewhere it is below it), so the tolerance is set from a normal run's
    last gap g: with tolerance g/2 the iterate that ended that run is within 10× of it, and
    the forced run, identical up to its first acceptable iterate, must stop there or before."""
    from numpy.linalg import LinAlgError

    solve = _solver_of_a_4hz_joint()

    reference = solve(BandedIpOptions(linear_solver="qr"))
    assert reference.converged and reference.linear_solver == "qr"
    normal = solve(BandedIpOptions())
    assert normal.converged and 0.0 < normal.gap <= 10 * BandedIpOptions().gap_tolerance
    options = BandedIpOptions(gap_tolerance=normal.gap / 2)

    factorize = BandedQp.factorize
    attempts = []

    def breaks_where_it_may_stop(self, weights, switch_to_qr=True):
        attempts.append(switch_to_qr)
        if not switch_to_qr and where == "factorisation":  # only where it may stop
            raise LinAlgError("forced: not positive definite")
        solve = factorize(self, weights, switch_to_qr)
        if switch_to_qr:
            return solve

        def fails(*_):   # the factor made, but it cannot reach the right-hand side
            raise LinAlgError("forced: the regularised factor missed the right-hand side")

        return fails

    monkeypatch.setattr(BandedQp, "factorize", breaks_where_it_may_stop)
    stopped = solve(options)
    assert attempts.count(False) == 1, attempts
    assert stopped.converged and stopped.linear_solver == "cholesky"
    assert options.gap_tolerance < stopped.gap <= 10 * options.gap_tolerance
    np.testing.assert_allclose(stopped.y[0::4], reference.y[0::4], rtol=0, atol=1e-7)


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")   # the forced steps
def test_the_best_acceptable_iterate_is_returned_when_the_steps_after_it_lose_ground(
        monkeypatch):
    """Once an iterate meets every tolerance and the gap to within 10×, steps that lose
    ground after it (forced here: every later Newton step is a random 1e-3 move, so the
    iteration runs out) end the solve at that iterate, converged, instead of failing with
    max_iterations;
    it is the optimum to 1e-7 rad (reference: the QR route). Without an acceptable iterate
    the failure stays a failure."""
    solve = _solver_of_a_4hz_joint()

    reference = solve(BandedIpOptions(linear_solver="qr"))
    normal = solve(BandedIpOptions())
    options = BandedIpOptions(gap_tolerance=normal.gap / 2, max_iterations=60)
    factorize = BandedQp.factorize
    stalled = []
    rng = np.random.default_rng(0)

    def stalls_once_acceptable(self, weights, switch_to_qr=True):
        if switch_to_qr and not stalled:
            return factorize(self, weights, switch_to_qr)
        # From the first acceptable iterate on, steps that only lose ground.
        stalled.append(True)
        return lambda *rhs: 1e-3 * rng.standard_normal(self.n)

    monkeypatch.setattr(BandedQp, "factorize", stalls_once_acceptable)
    stopped = solve(options)
    assert len(stalled) > 1 and stopped.converged and stopped.status == "converged"
    assert options.gap_tolerance < stopped.gap <= 10 * options.gap_tolerance
    np.testing.assert_allclose(stopped.y[0::4], reference.y[0::4], rtol=0, atol=1e-7)
    # No acceptable iterate (the gap tolerance cannot be met to 10× in 3 steps): a failure.
    monkeypatch.setattr(BandedQp, "factorize", factorize)
    assert not solve(BandedIpOptions(max_iterations=3)).converged
