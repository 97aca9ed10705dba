"""Tests proving the dense reference QP solver (tests/oracles.py) right.

Each test compares against an independent answer: closed-form linear KKT solves, a
closed-form box solution, or brute-force enumeration of active sets.
"""

import dataclasses
import itertools

import numpy as np
import oracles
import pytest


def random_spd(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.standard_normal((n, n))
    return q @ q.T / n + 0.5 * np.eye(n)


def feasible_problem(rng, n, m, p, spread=3.0):
    """Random QP whose feasible set has interior around x0 and whose unconstrained
    minimiser x0 + spread·z usually violates some rows (so constraints become active)."""
    hessian = random_spd(rng, n)
    a_ineq = rng.standard_normal((m, n))
    x0 = rng.standard_normal(n)
    b_ineq = a_ineq @ x0 + rng.uniform(0.05, 1.0, m)
    a_eq = rng.standard_normal((p, n))
    b_eq = a_eq @ x0
    gradient = -hessian @ (x0 + spread * rng.standard_normal(n))
    return hessian, gradient, a_ineq, b_ineq, a_eq, b_eq


def kkt_solve(hessian, gradient, a_eq, b_eq):
    """Closed form of min ½xᵀHx + gᵀx s.t. E x = d: [[H, Eᵀ], [E, 0]] [x; y] = [−g; d]."""
    n, p = hessian.shape[0], a_eq.shape[0]
    kkt = np.block([[hessian, a_eq.T], [a_eq, np.zeros((p, p))]])
    sol = np.linalg.solve(kkt, np.concatenate([-gradient, b_eq]))
    return sol[:n], sol[n:]


def enumerate_active_sets(hessian, gradient, a_ineq, b_ineq, a_eq, b_eq, feas_tol=1e-9):
    """Brute force: for every subset S of inequality rows treat S as equalities, solve the
    KKT system, keep candidates with A x ≤ b and λ_S ≥ 0. For SPD H every accepted one is the
    unique optimum. Returns (x, λ full length, y, list of accepted active sets)."""
    n, m, p = hessian.shape[0], a_ineq.shape[0], a_eq.shape[0]
    found = []
    for size in range(0, min(m, n - p) + 1):
        for subset in itertools.combinations(range(m), size):
            rows = list(subset)
            e = np.vstack([a_ineq[rows], a_eq])
            if np.linalg.matrix_rank(e) < e.shape[0]:
                continue
            x, mult = kkt_solve(hessian, gradient, e, np.concatenate([b_ineq[rows], b_eq]))
            lam = np.zeros(m)
            lam[rows] = mult[:size]
            if np.all(a_ineq @ x <= b_ineq + feas_tol) and np.all(lam >= -feas_tol):
                found.append((x, lam, mult[size:], rows))
    assert found, "enumeration found no optimum (problem should be feasible)"
    for x, *_ in found[1:]:
        np.testing.assert_allclose(x, found[0][0], atol=1e-9, rtol=0)
    return found[0][0], found[0][1], found[0][2], [f[3] for f in found]


def assert_kkt(res, hessian, gradient, a_ineq, b_ineq, a_eq, b_eq, atol):
    x, lam, y = res.x, res.ineq_multipliers, res.eq_multipliers
    stationarity = hessian @ x + gradient + a_ineq.T @ lam + a_eq.T @ y
    np.testing.assert_allclose(stationarity, 0.0, atol=atol, rtol=0)
    np.testing.assert_allclose(a_eq @ x, b_eq, atol=atol, rtol=0)
    slack = b_ineq - a_ineq @ x
    assert slack.min() >= -atol
    assert lam.min() >= -atol
    np.testing.assert_allclose(lam * slack, 0.0, atol=atol, rtol=0)


@pytest.mark.parametrize("seed,n", [(0, 1), (1, 3), (2, 10), (3, 60)])
def test_unconstrained_matches_linear_solve(seed, n):
    rng = np.random.default_rng(seed)
    hessian, gradient = random_spd(rng, n), rng.standard_normal(n)
    res = oracles.solve_dense_qp(hessian, gradient)
    assert res.converged
    np.testing.assert_allclose(res.x, np.linalg.solve(hessian, -gradient), atol=1e-10, rtol=1e-10)
    assert res.ineq_multipliers.shape == (0,) and res.eq_multipliers.shape == (0,)


@pytest.mark.parametrize("seed,n,p", [(10, 2, 1), (11, 5, 2), (12, 20, 7), (13, 80, 30)])
def test_equality_only_matches_kkt_solve(seed, n, p):
    rng = np.random.default_rng(seed)
    hessian, gradient = random_spd(rng, n), rng.standard_normal(n)
    a_eq, b_eq = rng.standard_normal((p, n)), rng.standard_normal(p)
    res = oracles.solve_dense_qp(hessian, gradient, a_eq=a_eq, b_eq=b_eq)
    x_ref, y_ref = kkt_solve(hessian, gradient, a_eq, b_eq)
    np.testing.assert_allclose(res.x, x_ref, atol=1e-9, rtol=1e-9)
    np.testing.assert_allclose(res.eq_multipliers, y_ref, atol=1e-9, rtol=1e-9)


def test_small_problems_match_active_set_enumeration():
    rng = np.random.default_rng(20240601)
    n_active = []
    for _ in range(200):
        n = int(rng.integers(1, 5))
        m = int(rng.integers(1, 7))
        p = int(rng.choice([0, 0, 1, 2])) if n > 1 else 0
        p = min(p, n - 1)
        problem = feasible_problem(rng, n, m, p)
        x_ref, lam_ref, y_ref, active_sets = enumerate_active_sets(*problem)
        res = oracles.solve_dense_qp(*problem)
        np.testing.assert_allclose(res.x, x_ref, atol=1e-8, rtol=1e-8)
        np.testing.assert_allclose(res.ineq_multipliers, lam_ref, atol=1e-8, rtol=1e-8)
        np.testing.assert_allclose(res.eq_multipliers, y_ref, atol=1e-8, rtol=1e-8)
        n_active.append(min(len(s) for s in active_sets))
    n_active = np.array(n_active)
    # The comparison must exercise active constraints, not just interior optima.
    assert np.mean(n_active >= 1) >= 0.5
    assert np.sum(n_active >= 2) >= 30


def test_box_constraints_closed_form():
    rng = np.random.default_rng(30)
    n = 50
    h = rng.uniform(0.5, 4.0, n)
    gradient = 3.0 * rng.standard_normal(n)
    lo, hi = -rng.uniform(0.2, 1.0, n), rng.uniform(0.2, 1.0, n)
    a_ineq = np.vstack([np.eye(n), -np.eye(n)])
    b_ineq = np.concatenate([hi, -lo])
    res = oracles.solve_dense_qp(np.diag(h), gradient, a_ineq, b_ineq)
    x_ref = np.clip(-gradient / h, lo, hi)
    assert np.sum(x_ref == hi) >= 5 and np.sum(x_ref == lo) >= 5
    assert np.sum((x_ref > lo) & (x_ref < hi)) >= 5
    np.testing.assert_allclose(res.x, x_ref, atol=1e-9, rtol=0)
    # Multipliers: upper bound λ = −(h·hi + g) ≥ 0, lower bound λ = h·lo + g ≥ 0.
    lam_hi = np.where(x_ref == hi, -(h * hi + gradient), 0.0)
    lam_lo = np.where(x_ref == lo, h * lo + gradient, 0.0)
    np.testing.assert_allclose(res.ineq_multipliers, np.concatenate([lam_hi, lam_lo]),
                               atol=1e-9, rtol=0)


def test_scale_invariance():
    """Scaling the objective by 1e6 and the constraint rows by 1e-3 leaves x unchanged."""
    rng = np.random.default_rng(40)
    hessian, gradient, a_ineq, b_ineq, a_eq, b_eq = feasible_problem(rng, 6, 12, 2)
    base = oracles.solve_dense_qp(hessian, gradient, a_ineq, b_ineq, a_eq, b_eq)
    scaled = oracles.solve_dense_qp(1e6 * hessian, 1e6 * gradient, 1e-3 * a_ineq,
                                    1e-3 * b_ineq, a_eq, b_eq)
    np.testing.assert_allclose(scaled.x, base.x, atol=1e-8, rtol=1e-8)
    np.testing.assert_allclose(scaled.ineq_multipliers, 1e9 * base.ineq_multipliers,
                               atol=1e-8 * 1e9, rtol=1e-7)


def _good_args():
    rng = np.random.default_rng(50)
    return dict(hessian=random_spd(rng, 3), gradient=rng.standard_normal(3),
                a_ineq=rng.standard_normal((4, 3)), b_ineq=np.ones(4),
                a_eq=rng.standard_normal((1, 3)), b_eq=np.zeros(1))


def _with(name, value):
    args = _good_args()
    args[name] = value(args[name]) if callable(value) else value
    return args


def _nan_at_0(a):
    a = a.copy()
    a.flat[0] = np.nan
    return a


@pytest.mark.parametrize("name,args", [
    ("hessian", _with("hessian", lambda h: h[:, :2])),
    ("hessian", _with("hessian", lambda h: h[0])),
    ("hessian", _with("hessian", _nan_at_0)),
    ("hessian", _with("hessian", lambda h: h + np.triu(np.ones((3, 3)), 1))),  # asymmetric
    ("hessian", _with("hessian", lambda h: -h)),  # not positive definite
    ("gradient", _with("gradient", lambda g: g[:2])),
    ("gradient", _with("gradient", lambda g: np.array([np.inf, 0.0, 0.0]))),
    ("a_ineq", _with("a_ineq", lambda a: a[:, :2])),
    ("a_ineq", _with("a_ineq", _nan_at_0)),
    ("b_ineq", _with("b_ineq", lambda b: b[:3])),
    ("b_ineq", _with("b_ineq", None)),
    ("a_eq", _with("a_eq", lambda a: a[:, :2])),
    ("b_eq", _with("b_eq", lambda b: np.array([np.nan]))),
    ("b_eq", _with("b_eq", lambda b: np.zeros(2))),
    ("a_eq", {**_good_args(), "a_eq": np.ones((2, 3)), "b_eq": np.ones(2)}),  # rank 1
    ("tol", {**_good_args(), "tol": 0.0}),
])
def test_bad_input_raises_value_error_naming_argument(name, args):
    oracles.solve_dense_qp(**_good_args())  # the unmodified arguments are valid
    with pytest.raises(ValueError, match=rf"\b{name}\b"):
        oracles.solve_dense_qp(**args)


def test_infeasible_or_iteration_limit_raises_runtime_error():
    rng = np.random.default_rng(60)
    hessian, gradient = random_spd(rng, 2), rng.standard_normal(2)
    # x0 ≤ -1 and x0 ≥ 1: infeasible.
    a_ineq, b_ineq = np.array([[1.0, 0.0], [-1.0, 0.0]]), np.array([-1.0, -1.0])
    with pytest.raises(RuntimeError, match="did not converge"):
        oracles.solve_dense_qp(hessian, gradient, a_ineq, b_ineq, max_iter=100)
    problem = feasible_problem(rng, 5, 10, 1)
    with pytest.raises(RuntimeError, match="did not converge"):
        oracles.solve_dense_qp(*problem, max_iter=2)


def test_result_is_frozen():
    res = oracles.solve_dense_qp(np.eye(2), np.ones(2))
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.x = np.zeros(2)


def test_mehrotra_cycling_regression():
    """Interior optimum of a 1-variable problem on which plain Mehrotra (no neighbourhood
    safeguard) cycles forever with complementarity stuck near 1e-2."""
    a_ineq = np.array([[-0.404], [0.117], [0.296], [-0.102], [-1.477], [-0.731]])
    b_ineq = np.array([0.915, 0.885, 0.013, 0.984, 0.416, 0.459])
    res = oracles.solve_dense_qp(np.array([[0.565]]), np.array([0.077]), a_ineq, b_ineq)
    np.testing.assert_allclose(res.x, [-0.077 / 0.565], atol=1e-10, rtol=0)
    np.testing.assert_allclose(res.ineq_multipliers, 0.0, atol=1e-10, rtol=0)


def test_large_problem_satisfies_kkt():
    """Many active rows: solving the plain normal equations H + AᵀWA stalls at a dual
    residual ~1e-6 on this seed (W spans ~1e25); the oracle must still reach tol."""
    rng = np.random.default_rng(1)
    problem = feasible_problem(rng, 400, 1200, 5, spread=5.0)
    res = oracles.solve_dense_qp(*problem)
    assert res.converged
    assert max(res.primal_residual, res.dual_residual, res.complementarity) <= 1e-11
    hessian, gradient, a_ineq, b_ineq, a_eq, b_eq = problem
    assert np.sum(b_ineq - a_ineq @ res.x < 1e-8) >= 50  # many rows active
    assert_kkt(res, *problem, atol=1e-7)
