"""Independent dense reference QP solver, used by the test suite as an oracle.

Solves the convex quadratic programme

    minimise    ½ xᵀ H x + gᵀ x
    subject to  A x ≤ b      (m inequality rows)
                E x = d      (p equality rows)

with H symmetric positive definite, by a primal-dual interior-point method with
Mehrotra's predictor-corrector. Everything is dense numpy/scipy; nothing here
shares code with the package under test.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg


@dataclass(frozen=True)
class DenseQpResult:
    """Solution of a dense QP.

    Attributes:
        x: Primal solution, shape (n,).
        ineq_multipliers: λ ≥ 0 for A x ≤ b, shape (m,).
        eq_multipliers: y for E x = d, shape (p,). Sign convention: the Lagrangian is
            ½ xᵀHx + gᵀx + λᵀ(Ax − b) + yᵀ(Ex − d), so H x + g + Aᵀλ + Eᵀy = 0.
        iterations: Interior-point iterations taken.
        converged: Always True (non-convergence raises instead).
        primal_residual: max(‖Ax + s − b‖∞, ‖Ex − d‖∞) / (1 + max(‖b‖∞, ‖d‖∞, ‖Ax‖∞, ‖Ex‖∞)).
        dual_residual: ‖Hx + g + Aᵀλ + Eᵀy‖∞ / (1 + max(‖g‖∞, ‖Hx‖∞, ‖Aᵀλ‖∞, ‖Eᵀy‖∞)).
        complementarity: Duality gap sᵀλ / (1 + |½ xᵀHx + gᵀx|).
    """

    x: np.ndarray
    ineq_multipliers: np.ndarray
    eq_multipliers: np.ndarray
    iterations: int
    converged: bool
    primal_residual: float
    dual_residual: float
    complementarity: float


def _finite_array(name: str, value, ndim: int) -> np.ndarray:
    arr = np.array(value, dtype=float)
    if arr.ndim != ndim:
        raise ValueError(f"{name} must be {ndim}-dimensional, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must contain only finite values")
    return arr


def _constraint_pair(a_name, a, b_name, b, n):
    if (a is None) != (b is None):
        raise ValueError(f"{a_name} and {b_name} must be given together")
    if a is None:
        return np.zeros((0, n)), np.zeros(0)
    a_arr, b_arr = _finite_array(a_name, a, 2), _finite_array(b_name, b, 1)
    if a_arr.shape[1] != n:
        raise ValueError(f"{a_name} must have {n} columns, got shape {a_arr.shape}")
    if b_arr.shape != (a_arr.shape[0],):
        raise ValueError(f"{b_name} must have shape ({a_arr.shape[0]},), got {b_arr.shape}")
    return a_arr, b_arr


def _max_step(v: np.ndarray, dv: np.ndarray) -> float:
    """Largest α > 0 with v + α dv ≥ 0 for v > 0 (inf if dv ≥ 0)."""
    neg = dv < 0
    return float(np.min(-v[neg] / dv[neg])) if np.any(neg) else np.inf


def _inf_norm(v: np.ndarray) -> float:
    return float(np.max(np.abs(v))) if v.size else 0.0


def _newton_solver(H, A, E, s, lam):
    """Factorise the Newton system at (s, λ); return (r_d, r_p, r_e, r_c) -> (dx, dy, ds, dλ).

    Rows with w_i = λ_i/s_i ≤ 1 are condensed into H + A_IᵀW_I A_I; the others keep dλ_i as an
    unknown with the row A_i dx − (s_i/λ_i) dλ_i = −r_p,i + r_c,i/λ_i, so no huge w_i enters
    the matrix (the plain normal equations stall near 1e-9 once w spans ~1e20).
    """
    n, p = H.shape[0], E.shape[0]
    w = lam / s
    act = w > 1.0
    A_a, A_i, k = A[act], A[~act], int(act.sum())
    lu = scipy.linalg.lu_factor(np.block([
        [H + A_i.T @ (w[~act, None] * A_i), A_a.T, E.T],
        [A_a, -np.diag(s[act] / lam[act]), np.zeros((k, p))],
        [E, np.zeros((p, k)), np.zeros((p, p))]]))

    def solve(r_d, r_p, r_e, r_c):
        rhs = np.concatenate([-r_d + A_i.T @ (r_c / s - w * r_p)[~act],
                              (r_c / lam - r_p)[act], -r_e])
        sol = scipy.linalg.lu_solve(lu, rhs)
        ds = -r_p - A @ sol[:n]
        dl = (-r_c - lam * ds) / s
        dl[act] = sol[n:n + k]
        return sol[:n], sol[n + k:], ds, dl

    return solve


def solve_dense_qp(hessian, gradient, a_ineq=None, b_ineq=None, a_eq=None, b_eq=None, *,
                   tol: float = 1e-11, max_iter: int = 200) -> DenseQpResult:
    """Solve min ½ xᵀHx + gᵀx s.t. A x ≤ b, E x = d by Mehrotra predictor-corrector.

    With slacks s = b − Ax ≥ 0, multipliers λ ≥ 0 and y, the KKT conditions are

        r_d = Hx + g + Aᵀλ + Eᵀy = 0,   r_p = Ax + s − b = 0,   r_e = Ex − d = 0,
        s ∘ λ = 0,   s, λ ≥ 0.

    Each Newton step linearises these with s∘λ = σμ replaced by Λ ds + S dλ = −r_c
    (r_c = s∘λ + ds_aff∘dλ_aff − σμ), eliminates ds = −r_p − A dx and dλ = (−r_c − λ∘ds)/s,
    and solves, with W = diag(λ/s),

        [H + AᵀWA  Eᵀ] [dx]   [−r_d + Aᵀ(r_c/s − W r_p)]
        [E         0 ] [dy] = [−r_e                    ]

    (rows with λ_i/s_i > 1 are kept in augmented form instead, see _newton_solver) by one
    LU factorisation reused for the affine (predictor, r_c = s∘λ) and the corrector
    right-hand sides; σ = (μ_aff/μ)³ as in Mehrotra (1992). Steps use 0.995 of the
    distance to the boundary of s, λ ≥ 0, shortened if needed so that no s_i λ_i falls below
    γ·sᵀλ/m (γ = min(10⁻³, half the current ratio)); without this Mehrotra's heuristic
    occasionally cycles.

    Args:
        hessian: H, (n, n), symmetric positive definite.
        gradient: g, (n,).
        a_ineq: A, (m, n), or None. b_ineq: b, (m,), or None (given together with A).
        a_eq: E, (p, n) with full row rank, or None. b_eq: d, (p,), or None.
        tol: Bound on the relative primal/dual residuals and gap (see DenseQpResult).
        max_iter: Iteration limit.

    Returns:
        DenseQpResult with converged=True.

    Raises:
        ValueError: Inconsistent shapes, non-finite data, H not symmetric positive definite,
            or a_eq without full row rank.
        RuntimeError: Not converged within max_iter (e.g. infeasible problem).
    """
    H = _finite_array("hessian", hessian, 2)
    n = H.shape[0]
    if H.shape != (n, n):
        raise ValueError(f"hessian must be square, got shape {H.shape}")
    g = _finite_array("gradient", gradient, 1)
    if g.shape != (n,):
        raise ValueError(f"gradient must have shape ({n},), got {g.shape}")
    if _inf_norm(H - H.T) > 1e-10 * (1.0 + _inf_norm(H)):
        raise ValueError("hessian must be symmetric")
    try:
        np.linalg.cholesky(H)
    except np.linalg.LinAlgError:
        raise ValueError("hessian must be positive definite") from None
    A, b = _constraint_pair("a_ineq", a_ineq, "b_ineq", b_ineq, n)
    E, d = _constraint_pair("a_eq", a_eq, "b_eq", b_eq, n)
    m, p = A.shape[0], E.shape[0]
    if p and np.linalg.matrix_rank(E) < p:
        raise ValueError("a_eq must have full row rank")
    if not (tol > 0 and max_iter >= 0):
        raise ValueError(f"need tol > 0 and max_iter >= 0, got tol={tol}, max_iter={max_iter}")
    # Start: x minimises ½xᵀHx + gᵀx + ½‖Ax − b‖² on Ex = d (the Newton solver at s = λ = 1
    # with r_d = g, r_p = −b, r_e = −d, r_c = 0); slacks and multipliers pushed to ≥ 1.
    x, y, _, _ = _newton_solver(H, A, E, np.ones(m), np.ones(m))(g, -b, -d, np.zeros(m))
    s, lam = np.maximum(np.abs(b - A @ x), 1.0), np.ones(m)
    for it in range(max_iter + 1):
        Ax, Ex, Hx, Atl, Ety = A @ x, E @ x, H @ x, A.T @ lam, E.T @ y
        r_d, r_p, r_e = Hx + g + Atl + Ety, Ax + s - b, Ex - d
        primal = max(_inf_norm(r_p), _inf_norm(r_e)) / (
            1.0 + max(_inf_norm(b), _inf_norm(d), _inf_norm(Ax), _inf_norm(Ex)))
        dual = _inf_norm(r_d) / (
            1.0 + max(_inf_norm(g), _inf_norm(Hx), _inf_norm(Atl), _inf_norm(Ety)))
        comp = float(s @ lam) / (1.0 + abs(0.5 * x @ Hx + g @ x))
        finite = bool(np.all(np.isfinite(np.concatenate([x, s, lam, y]))))
        if finite and max(primal, dual, comp) <= tol:
            return DenseQpResult(x, lam, y, it, True, primal, dual, comp)
        if it == max_iter or not finite or (m and min(s.min(), lam.min()) <= 0.0):
            break
        try:
            direction = _newton_solver(H, A, E, s, lam)
        except (np.linalg.LinAlgError, ValueError):
            break
        if m:
            mu = float(s @ lam) / m
            _, _, ds_a, dl_a = direction(r_d, r_p, r_e, s * lam)
            a_aff = min(1.0, _max_step(s, ds_a), _max_step(lam, dl_a))
            sigma = (float((s + a_aff * ds_a) @ (lam + a_aff * dl_a)) / m / mu) ** 3
            dx, dy, ds, dl = direction(r_d, r_p, r_e, s * lam + ds_a * dl_a - sigma * mu)
            alpha = min(1.0, 0.995 * min(_max_step(s, ds), _max_step(lam, dl)))
            # Safeguard (plain Mehrotra can cycle): backtrack until min_i s_i λ_i ≥ γ sᵀλ/m.
            gamma = min(1e-3, 0.5 * float(np.min(s * lam)) / mu)
            while alpha > 1e-12:
                s_new, lam_new = s + alpha * ds, lam + alpha * dl
                if np.min(s_new * lam_new) >= gamma * float(s_new @ lam_new) / m:
                    break
                alpha *= 0.8
        else:
            dx, dy, ds, dl = direction(r_d, r_p, r_e, np.zeros(0))
            alpha = 1.0
        x, y, s, lam = x + alpha * dx, y + alpha * dy, s + alpha * ds, lam + alpha * dl
    raise RuntimeError(
        f"solve_dense_qp did not converge in {it} iterations (primal {primal:.2e}, "
        f"dual {dual:.2e}, complementarity {comp:.2e}, tol {tol:.1e}); infeasible?")
