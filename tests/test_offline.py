"""Offline-CKS (Drake/Clarabel) against RTS and an independent dense interior-point solve."""

from math import factorial

import numpy as np
import pytest
from core_fixtures import operator_recording
from oracles import solve_dense_qp

from telesmooth.smoothing.kalman import rest_prior, rts_smoother
from telesmooth.smoothing.metrics import VIOLATION_RTOL
from telesmooth.smoothing.model import JerkModel
from telesmooth.smoothing.offline import finite_difference_operator, solve_offline_cks

DT, SIGMA, R = 0.25, 4e-4, 1e-6
ACC, JERK, VEL = 0.05, 0.1, 0.1


def _recording(num_samples=40, num_joints=2, seed=21):
    return operator_recording(num_samples=num_samples, num_joints=num_joints, dt=DT, seed=seed)


def _dense_qp(z, model, joint, *, constraint, acc, jerk, vel=None, rest_at_end=False):
    """The same QP written out densely and independently (docs/method.md §2.3/§2.6), scaled
    variables y_k = T x_k stacked as [y_0, …, y_{N−1}], objective multiplied by r."""
    n = len(z)
    dt, r, sigma = model.dt_s, model.r[joint], model.sigma[joint]
    t = dt ** np.arange(4.0)
    q1 = np.array([[1.0 / ((7 - a - b) * factorial(3 - a) * factorial(3 - b)) for b in range(4)]
                   for a in range(4)])
    phi = np.eye(4) + np.diag([1.0, 1.0, 1.0], 1) + np.diag([0.5, 0.5], 2) + np.diag([1 / 6], 3)
    w = r / (sigma * dt**7) * np.linalg.inv(q1)
    prior = rest_prior(z[:1], JerkModel.make(dt, sigma, r, num_joints=1))
    w0 = r * np.linalg.inv(prior.cov[0] * np.outer(t, t))
    m0 = prior.mean[0] * t
    hessian = np.zeros((4 * n, 4 * n))
    gradient = np.zeros(4 * n)
    hessian[:4, :4] += w0
    gradient[:4] -= w0 @ m0
    d = np.hstack([-phi, np.eye(4)])
    for k in range(n):
        hessian[4 * k, 4 * k] += 1.0
        gradient[4 * k] -= z[k]
        if k:
            hessian[4 * k - 4 : 4 * k + 4, 4 * k - 4 : 4 * k + 4] += d.T @ w @ d
    rows, bounds = [], []

    def add_abs(row, limit):
        rows.extend([row, -row])
        bounds.extend([limit, limit])

    if constraint in ("state", "both"):
        for k in range(n):
            for index, limit in ((2, acc * dt**2), (3, jerk * dt**3)):
                row = np.zeros(4 * n)
                row[4 * k + index] = 1.0
                add_abs(row, limit)
    if constraint in ("trajectory", "both"):
        # Extended positions: 3 history samples (constants z_0), p_0..p_{N−1}, 3 held samples.
        hold = 3 if rest_at_end else 0
        def position_row(e):  # coefficient row and constant for extended index e
            row = np.zeros(4 * n)
            if e < 3:
                return row, z[0]
            k = min(e - 3, n - 1)
            row[4 * k] = 1.0
            return row, 0.0
        stencils = [(2, [1.0, -2.0, 1.0], acc * dt**2), (3, [-1.0, 3.0, -3.0, 1.0], jerk * dt**3)]
        if vel is not None:
            stencils.append((1, [-1.0, 1.0], vel * dt))
        for order, coefficients, limit in stencils:
            for start in range(3 + n + hold - order):
                row, constant = np.zeros(4 * n), 0.0
                for offset, c in enumerate(coefficients):
                    r_e, c_e = position_row(start + offset)
                    row += c * r_e
                    constant += c * c_e
                if np.any(row):
                    rows.extend([row, -row])
                    bounds.extend([limit - constant, limit + constant])
    a_eq = b_eq = None
    if rest_at_end:
        a_eq = np.zeros((3, 4 * n))
        for index in range(3):
            a_eq[index, 4 * (n - 1) + 1 + index] = 1.0
        b_eq = np.zeros(3)
    # The dual residual of a dense double-precision IP stalls near 1e-10 relative here (the
    # Hessian spans ~1e7), as docs/method.md §2.3 notes for the ckbs port; 1e-9 is the
    # honest target.
    a_in, b_in = np.array(rows), np.array(bounds)
    result = solve_dense_qp(hessian, gradient, a_in, b_in, a_eq, b_eq, tol=1e-9)
    x = _polish_active_set(hessian, gradient, a_in, b_in, a_eq, b_eq, result)
    return x.reshape(n, 4) / t


def _polish_active_set(hessian, gradient, a_in, b_in, a_eq, b_eq, result, max_changes=50):
    """Exact optimum certified by KKT, starting from the interior point's active set.

    The IP alone stalls near 1e-6 on these problems (Hessian spread ~1e7). Duplicate rows are
    merged, then the equality-constrained KKT system on the working set is solved and the set
    corrected (drop the most negative multiplier, or add the most violated row) until the point
    is primal feasible with non-negative multipliers: for a strictly convex QP that certifies
    the unique optimum."""
    _, first = np.unique(np.column_stack([a_in, b_in]), axis=0, return_index=True)
    a_in, b_in = a_in[np.sort(first)], b_in[np.sort(first)]
    slack = b_in - a_in @ result.x
    multipliers = np.zeros(len(b_in))
    working = list(np.flatnonzero(slack < 1e-7 * (1.0 + np.abs(b_in).max())))
    scale = 1.0 + np.abs(b_in).max()
    num_eq = 0 if a_eq is None else a_eq.shape[0]
    for _ in range(max_changes):
        rows = a_in[working] if a_eq is None else np.vstack([a_in[working], a_eq])
        rhs = b_in[working] if a_eq is None else np.concatenate([b_in[working], b_eq])
        m = rows.shape[0]
        kkt = np.block([[hessian, rows.T], [rows, np.zeros((m, m))]])
        solution = np.linalg.lstsq(kkt, np.concatenate([-gradient, rhs]), rcond=1e-14)[0]
        x = solution[: len(gradient)]
        multipliers = solution[len(gradient):m + len(gradient) - num_eq]
        violation = a_in @ x - b_in
        if violation.max() > 1e-12 * scale:
            working.append(int(np.argmax(violation)))
            continue
        if _kkt_certified(hessian, gradient, a_in, violation, a_eq, x, scale):
            return x
        working.pop(int(np.argmin(multipliers)))
    raise AssertionError("active-set polish did not certify an optimum")


def _kkt_certified(hessian, gradient, a_in, violation, a_eq, x, scale):
    """Do multipliers λ ≥ 0 on the rows active at x (and free ones on the equalities) exist
    with H x + g + Aᵀλ + A_eqᵀ y = 0? Degenerate (dependent) active rows make λ non-unique,
    so this is a non-negative least-squares question, not a linear solve."""
    from scipy.optimize import nnls

    active = a_in[violation > -1e-10 * scale]
    columns = [active.T] + ([] if a_eq is None else [a_eq.T, -a_eq.T])
    matrix = np.hstack(columns) if columns else np.zeros((len(x), 0))
    target = -(hessian @ x + gradient)
    _, residual = nnls(matrix, target, maxiter=50 * matrix.shape[1] + 100)
    return residual <= 1e-8 * (1.0 + np.abs(gradient).max())


def _assert_same_states(actual, expected, dt, atol=1e-6):
    """Compare in the scaled basis (every component on the position scale)."""
    t = dt ** np.arange(4.0)
    np.testing.assert_allclose(actual * t, expected * t, rtol=0, atol=atol)


def test_without_limits_equals_rts():
    z = _recording()
    model = JerkModel.make(DT, SIGMA, R, num_joints=2)
    rts = rts_smoother(z, model, rest_prior(z[0], model)).mean
    for constraint, limits in (("none", {}), ("state", dict(max_acceleration=1e3, max_jerk=1e3)),
                               ("trajectory", dict(max_acceleration=1e3, max_jerk=1e3))):
        result = solve_offline_cks(z, model, constraint=constraint, **limits)
        assert result.is_success, result.solution_results
        assert result.solver_name == "Clarabel"
        _assert_same_states(result.states, rts, DT, atol=1e-8)


def test_state_box_holds_and_matches_dense_interior_point():
    z = _recording()
    model = JerkModel.make(DT, SIGMA, R, num_joints=2)
    result = solve_offline_cks(z, model, max_acceleration=ACC, max_jerk=JERK, constraint="state")
    assert result.is_success
    states = result.states
    assert np.abs(states[:, :, 2]).max() <= ACC * (1 + 1e-9)
    assert np.abs(states[:, :, 3]).max() <= JERK * (1 + 1e-9)
    # The limits really bind (otherwise the test would only repeat the RTS check).
    rts = rts_smoother(z, model, rest_prior(z[0], model)).mean
    assert np.abs(rts[:, :, 2]).max() > 1.5 * ACC
    assert np.sum(np.abs(states[:, :, 2]) > ACC * (1 - 1e-6)) >= 2
    for j in range(2):
        dense = _dense_qp(z[:, j], model, j, constraint="state", acc=ACC, jerk=JERK)
        _assert_same_states(states[:, j], dense, DT)


@pytest.mark.parametrize("vel,rest_at_end", [(None, False), (VEL, False), (VEL, True)])
def test_trajectory_mode_has_zero_fd_violations_and_matches_dense_interior_point(vel, rest_at_end):
    z = _recording(seed=22)
    model = JerkModel.make(DT, SIGMA, R, num_joints=2)
    result = solve_offline_cks(z, model, max_acceleration=ACC, max_jerk=JERK, max_velocity=vel,
                               constraint="trajectory", rest_at_end=rest_at_end)
    assert result.is_success
    p = result.states[:, :, 0]
    tail = np.repeat(p[-1:], 3, axis=0) if rest_at_end else np.zeros((0, 2))
    extended = np.vstack([np.repeat(z[:1], 3, axis=0), p, tail])
    for order, limit in ((2, ACC), (3, JERK)) + (((1, vel),) if vel else ()):
        fd = np.diff(extended, n=order, axis=0) / DT**order
        assert np.abs(fd).max() <= limit * (1 + VIOLATION_RTOL), (order, np.abs(fd).max())
        # The raw recording breaks the same limits, so the constraints are doing work.
        assert np.abs(np.diff(z, n=order, axis=0) / DT**order).max() > 1.2 * limit
    if rest_at_end:
        np.testing.assert_allclose(result.states[-1, :, 1:], 0.0, atol=1e-9)
    for j in range(2):
        dense = _dense_qp(z[:, j], model, j, constraint="trajectory", acc=ACC, jerk=JERK,
                          vel=vel, rest_at_end=rest_at_end)
        _assert_same_states(result.states[:, j], dense, DT)


def test_both_modes_together():
    z = _recording(seed=23)
    model = JerkModel.make(DT, SIGMA, R, num_joints=2)
    result = solve_offline_cks(z, model, max_acceleration=ACC, max_jerk=JERK, constraint="both")
    assert result.is_success
    assert np.abs(result.states[:, :, 2]).max() <= ACC * (1 + 1e-9)
    dense = _dense_qp(z[:, 1], model, 1, constraint="both", acc=ACC, jerk=JERK)
    _assert_same_states(result.states[:, 1], dense, DT)


def test_finite_difference_operator_by_hand():
    # Positions e = [c, c, c, p0, p1, p2, p2, p2, p2]; second differences with a variable.
    a, c = finite_difference_operator(3, 2, history=3, hold_at_end=3)
    np.testing.assert_array_equal(
        a.toarray(), [[1, 0, 0], [-2, 1, 0], [1, -2, 1], [0, 1, -1]])
    np.testing.assert_array_equal(c, [-1, 1, 0, 0])
    a, c = finite_difference_operator(4, 3)
    np.testing.assert_array_equal(a.toarray(), [[-1, 3, -3, 1]])
    assert finite_difference_operator(2, 3)[0].shape == (0, 2)


def test_per_joint_limits_and_validation():
    z = _recording(num_samples=12)
    model = JerkModel.make(DT, SIGMA, R, num_joints=2, joint_names=("shoulder", "elbow"))
    with pytest.raises(ValueError, match="constraint = 'soft' must be one of"):
        solve_offline_cks(z, model, constraint="soft")
    with pytest.raises(ValueError,
                       match=r"max_jerk_rad_per_s3\[1\] = -0.1 for joint 1 \('elbow'\)"):
        solve_offline_cks(z, model, max_acceleration=ACC, max_jerk=[0.1, -0.1],
                          joint_names=("shoulder", "elbow"))
    with pytest.raises(ValueError, match=r"measurements\[4, 0\] = nan"):
        bad = z.copy()
        bad[4, 0] = np.nan
        solve_offline_cks(bad, model)
    # A limit per joint by name: only the elbow is limited.
    result = solve_offline_cks(z, model, max_acceleration={"shoulder": 1e3, "elbow": 0.01},
                               max_jerk=1e3, constraint="state",
                               joint_names=("shoulder", "elbow"))
    assert np.abs(result.states[:, 1, 2]).max() <= 0.01 * (1 + 1e-9)
