"""The hard limiter: commands whose finite differences never exceed the limits (pure core).

The online counterpart of the trajectory constraint of docs/method.md §2.6. At every
4 Hz tick k the ground station has the fixed-lag estimate r_k (the BMFLS / Online-CKS output,
docs/method.md §3) and must choose the command p_k it sends, with the commands already sent held
fixed. The finite differences of the *sent* sequence (history p_{−1} = p_{−2} = p_{−3} = q_start,
the robot at rest, docs/method.md §2.6)

    v_k = (p_k − p_{k−1}) / Δt
    a_k = (p_k − 2 p_{k−1} + p_{k−2}) / Δt²                          = (v_k − v_{k−1}) / Δt
    u_k = (p_k − 3 p_{k−1} + 3 p_{k−2} − p_{k−3}) / Δt³              = (a_k − a_{k−1}) / Δt

must satisfy |v_k| ≤ v_max (optional, may be inf), |a_k| ≤ a_max and |u_k| ≤ j_max for every
k, per joint. Choosing p_k is choosing the jerk u_k of the discrete triple integrator

    a_k = a_{k−1} + u_k Δt,   v_k = v_{k−1} + a_k Δt,   p_k = p_{k−1} + v_k Δt,        (1)

i.e. x_k = M x_{k−1} + b u_k for the FD state x = (v, a), M = [[1, Δt], [0, 1]],
b = (Δt², Δt).

Feasibility (the safety part)
-----------------------------
A one-step choice can corner itself: at v = v_max with a > j_max Δt, (1) gives
v_{k+1} = v_max + (a_k + u Δt) Δt > v_max for every admissible u. So the state is kept inside
the *stoppable set* S: the (v, a) from which a jerk sequence within all limits reaches rest
(v = a = 0, after which u = 0 holds it). With finite v_max, S is computed by the backward
recursion

    S_0 = {0},    S_{n+1} = Pre(S_n) ∩ B,    Pre(C) = {x : ∃ |u| ≤ j_max, M x + b u ∈ C}
                                                    = M⁻¹ (C ⊕ [−j_max, j_max] b),

with B = {|v| ≤ v_max, |a| ≤ a_max}; S_n is the set of states that can stop within n ticks.
All S_n are convex polygons (Minkowski sum with a segment, an invertible linear map and a box
clip preserve convex polygons), so the recursion is a few lines of 2-D geometry, once per joint
(``stoppable_polygon``). It stops at the first N with S_{N+1} = S_N (up to 1e-12 in the
normalised coordinates v/v_max, a/a_max), typically after v_max/(a_max Δt) + a_max/(j_max Δt)
+ a few iterations.

**Claim.** For every N, S_N is controlled invariant: for every x ∈ S_N there is a u with
|u| ≤ j_max and M x + b u ∈ S_N ⊆ B. **Proof.** 0 ∈ S_1 (u = 0 keeps rest), and the sets are
nested, S_{n−1} ⊆ S_n: by induction, S_{n−1} ⊆ S_n implies
Pre(S_{n−1}) ∩ B ⊆ Pre(S_n) ∩ B. Hence S_N = Pre(S_{N−1}) ∩ B ⊆ Pre(S_N). ∎
So convergence is not needed for safety, only for not being needlessly conservative. The
computed polygon is also *certified* numerically: for each of its vertices the admissible jerk
interval below is checked to be non-empty; since {(x, u) : M x + b u ∈ S, |u| ≤ j_max} is convex,
its projection Pre(S) is convex, and containing the vertices of S it contains S.

**The tick.** With S = {x : g_i · x ≤ 1, i = 1 … m} (0 is interior), the next state is affine
in u, so each facet gives one bound on u:

    (g_i · b) u ≤ 1 − g_i · M x_{k−1},        together with |u| ≤ j_max,              (2)

an interval [u_lo, u_hi] that is non-empty for every x_{k−1} ∈ S (Claim). Every u in it keeps
x_k ∈ S ⊆ B, i.e. |v_k| ≤ v_max, |a_k| ≤ a_max and |u_k| ≤ j_max, and x_{−1} = (0, 0) ∈ S.
By induction **every tick is feasible for every input stream**, whatever the estimates are.
The tracking rule (below) only picks the point of [u_lo, u_hi]; it cannot break a limit.
Cost: O(m) per joint, vectorised over joints (m ≈ 10–40 facets for realistic limits).

With v_max = inf the velocity is unconstrained and S = {|a| ≤ a_max} (a strip): from
|a_{k−1}| ≤ a_max the interval [max(−j_max, (−a_max − a_{k−1})/Δt),
min(j_max, (a_max − a_{k−1})/Δt)] contains the u that moves a toward 0 by min(|a|, j_max Δt),
so it is non-empty; it is the same formula (2) with the two rows ±a/a_max ≤ 1.

Floating point
--------------
1. The limits are shrunk internally by a relative ``margin`` (default 1e-9): S is computed for
   (1 − margin)·(v_max, a_max, j_max).
2. The limiter keeps a *nominal* state (p̂, v̂, â) updated by (1) and sends p_k = p̂_k. The FD
   values a user recomputes from the sent floats differ from (v̂_k, â_k, u_k) only by the
   rounding of the last few updates (p̂_k − p̂_{k−1} = v̂_k Δt + ρ_k with |ρ_k| ≤ ulp(p̂_k)/2,
   similarly for v̂ and â; Δt = 0.25 is a power of two, so the products by Δt are exact). The
   errors are fresh each tick and do not accumulate: |Δ³p/Δt³ − u_k| ≲ 4 ulp(|p|)/Δt³ +
   2 ulp(v_max)/Δt² + ulp(a_max)/Δt, about 1e-13 rad/s³ for |p| ≤ 10 rad at 4 Hz, which is far
   inside the margin (1e-10 rad/s³ for j_max = 0.1).
3. Rounding can leave the nominal (v̂, â) a few ulps outside S. Before each tick it is scaled
   back into S (x̂ ← x̂ / max_i g_i · x̂ when that gauge exceeds 1; a fresh jump of a few ulps,
   not an accumulating drift), and if the computed interval is empty by rounding, its midpoint
   is used. Hence the sent FD values stay within (1 − margin + O(ulp)) of the limits for any
   stream length; the tests recompute them from the positions and check ≤ limit·(1 + 1e-9).

Tracking (the quality part)
---------------------------
``u_hit`` is the jerk that sends exactly the estimate, p_k = r_k (3p_{k−1} − 3p_{k−2} + p_{k−3}
+ u Δt³ = r_k). Rules:

``"greedy"``
    u = clip(u_hit, u_lo, u_hi). Safe (thanks to S) but it overshoots: it accelerates until S
    forces braking, which happens at the velocity limit, not at the target.
``"braking"`` (default)
    Braking-aware: with F(p, v, a) the position where the time-optimal jerk/acceleration-
    limited stop from (p, v, a) ends (continuous-time closed form, ``stop_position``), the
    next state must satisfy  W⁻ ≤ F(p_k, v_k, a_k) ≤ W⁺, with W⁺ = max(r_k, F(target)),
    W⁻ = min(r_k, F(target)) and F(target) the stop point of the estimate's own FD state
    (from r_k, r_{k−1}, r_{k−2}). F is increasing in u, so the band is an interval of u
    (found by a 65-point grid and a secant step, vectorised); u = clip(u_hit, band ∩
    [u_lo, u_hi]) (the nearer end of [u_lo, u_hi] if they do not meet). Approaching a target
    it never plans to stop beyond where the target itself could stop, so it brakes in time;
    a stream that is itself within the limits is reproduced exactly, because then our state
    equals the estimate's state and u_hit lies in the band. With a ``lookahead`` (the fixed-
    lag smoother's estimates of the next L samples), the band is widened to the range of the
    look-ahead positions and the stop point of its last state.

A non-finite estimate never reaches the plant: that joint brakes (target = its own stop point,
time-optimal stop within the limits); the tick's outcome is ``LimiterOutcome.BRAKING`` and
``state.held`` names the joints.

Pure form
---------
The limiter is a pure function over immutable values, in Ruckig's vocabulary: the limits are
:class:`LimiterParams` (``max_velocity``, ``max_acceleration``, ``max_jerk`` and everything
derived from them once: the stoppable sets and their facet rows), the state after tick k is a
:class:`LimiterState` (``position``, ``velocity``, ``acceleration`` = the nominal p̂_k, v̂_k,
â_k, the sent history and the two previous targets), and

    limiter_step(params, state, target) -> (new state, command)

returns the next state and the command p_{k+1} without touching its arguments. Its outcome
(:class:`LimiterOutcome`: ``EXACT`` when the command is the target bit for bit, ``LIMITED``,
``BRAKING``) travels in the new state, like Ruckig's result enum. :func:`limiter_rest_state`
starts at rest, :func:`limiter_moving_state` just after three sent commands.

A tick runs compiled (:mod:`~telesmooth.safety.limiter_kernel`, numba, the same floats bit for
bit as the array form ``_step_arrays``, which stays the reference and takes the ticks with a
non-finite target or state); the kernel is compiled, or loaded from numba's cache, when the
parameters are built.
:class:`~telesmooth.smoothing.online_hard.OnlineHardLimiter` is a small stateful convenience
wrapper for scripts; Drake systems keep the state in their Context.
"""


from __future__ import annotations

import enum
import functools
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from telesmooth.arms.joint_vectors import (
    as_per_joint,
    check_finite_per_joint,
    check_positive_scalar,
)
from telesmooth.compiled import readonly_copy
from telesmooth.safety.finite_differences import fd_acceleration, fd_state, fd_velocity

__all__ = [
    "DEFAULT_MARGIN",
    "HISTORY_LENGTH",
    "RULES",
    "LimiterOutcome",
    "LimiterParams",
    "LimiterState",
    "StoppablePolygon",
    "admissible_jerk",
    "limiter_moving_state",
    "limiter_params",
    "limiter_rest_state",
    "limiter_step",
    "stop_position",
    "stoppable_polygon",
]

RULES = ("braking", "greedy")
DEFAULT_MARGIN = 1e-9
HISTORY_LENGTH = 3
_GRID_POINTS = 65
_GRID = np.linspace(0.0, 1.0, _GRID_POINTS)
_GRID.flags.writeable = False
_HULL_TOLERANCE = 1e-13  # normalised coordinates are O(1)
_CONVERGENCE_TOLERANCE = 1e-12
_BAND_TOLERANCE = 1e-9  # relative slack when accepting u_hit inside the braking band


@dataclass(frozen=True, eq=False)
class StoppablePolygon:
    """The stoppable set S of one joint in the FD state plane (v, a), physical units.

    Attributes:
        facets: rows g_i, shape (m, 2), with S = {x = (v, a) : g_i · x ≤ 1}.
        vertices: counter-clockwise vertices (n, 2) [rad/s, rad/s²]; empty (0, 2) when
            v_max = inf (S is then the strip |a| ≤ a_max).
        steps: N, the recursion depth: every state of S stops within N ticks (0 for the strip).
        limits: the (v_max, a_max, j_max) S was computed for.
    """

    facets: np.ndarray
    vertices: np.ndarray
    steps: int
    limits: tuple[float, float, float]

    def contains(self, velocity, acceleration, *, tolerance: float = 0.0) -> np.ndarray:
        """Whether each (v, a) lies in S (gauge ≤ 1 + tolerance); broadcasts."""
        v = np.asarray(velocity, dtype=float)[..., None]
        a = np.asarray(acceleration, dtype=float)[..., None]
        return (self.facets[:, 0] * v + self.facets[:, 1] * a).max(axis=-1) <= 1.0 + tolerance


# -- 2-D polygon geometry (normalised coordinates) --------------------------------------------

def _convex_hull(points: np.ndarray) -> np.ndarray:
    """Counter-clockwise hull of (n, 2) points without collinear vertices (monotone chain).
    Degenerate inputs give 1 or 2 points."""
    if len(points) > _LARGE_HULL:
        hull = _qhull(np.round(points, 15))
        if hull is not None:
            return hull
    pts = np.unique(np.round(points, 15), axis=0)
    if len(pts) <= 2:
        return pts

    def half(sequence):
        chain = []
        for p in sequence:
            while len(chain) >= 2:
                o, a = chain[-2], chain[-1]
                cross = (a[0] - o[0]) * (p[1] - o[1]) - (a[1] - o[1]) * (p[0] - o[0])
                if cross > _HULL_TOLERANCE:
                    break
                chain.pop()
            chain.append(p)
        return chain

    lower = half(pts)
    upper = half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


_LARGE_HULL = 256
"""Above this many points the hull is Qhull's (scipy, in C) instead of the monotone chain in
Python: the extreme limit ratios (a_max/(j_max Δt) in the hundreds) give polygons of
thousands of vertices, where the Python loop took minutes."""


def _qhull(pts: np.ndarray) -> np.ndarray | None:
    """Counter-clockwise hull of points by Qhull, without the vertices where the boundary
    turns by no more than the monotone chain's tolerance; None if Qhull refuses (degenerate
    input: the caller falls back to the monotone chain)."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = pts[ConvexHull(pts).vertices]      # counter-clockwise in 2-D
    except (QhullError, ValueError):
        return None
    while len(hull) > 3:
        o, a, p = np.roll(hull, 1, axis=0), hull, np.roll(hull, -1, axis=0)
        cross = (a[:, 0] - o[:, 0]) * (p[:, 1] - o[:, 1]) \
            - (a[:, 1] - o[:, 1]) * (p[:, 0] - o[:, 0])
        flat = cross <= _HULL_TOLERANCE
        if not flat.any():
            break
        # Drop flat vertices whose predecessor stays (never two neighbours in one pass: the
        # turn at a vertex is judged against neighbours that are kept).
        index = np.arange(len(hull))
        drop = flat & (index % 2 == 0)
        if len(hull) % 2 == 1:
            drop[-1] = False      # the last and the first (both even) are neighbours
        if not drop.any():
            drop = flat & (index % 2 == 1)
        hull = hull[~drop]
    return hull


def _clip_halfplane(poly: np.ndarray, normal, offset: float) -> np.ndarray:
    """Convex polygon ∩ {x : normal · x ≤ offset} (Sutherland–Hodgman); the result is convex
    and in order but may repeat points (the caller re-hulls)."""
    if len(poly) == 0:
        return np.zeros((0, 2))
    values = poly @ np.asarray(normal) - offset
    following = np.roll(poly, -1, axis=0)
    next_values = np.roll(values, -1)
    keep = values <= 0.0
    crosses = ((values < 0.0) & (next_values > 0.0)) | ((next_values < 0.0) & (values > 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(crosses, values / (values - next_values), 0.0)
    crossing = poly + (following - poly) * ratio[:, None]
    # Edge by edge, in order: the start point if kept, then the crossing if any.
    stacked = np.stack([poly, crossing], axis=1)           # (n, 2 points, 2)
    return stacked[np.stack([keep, crosses], axis=1)]


def _facets(vertices: np.ndarray) -> np.ndarray:
    """Rows g with {x : g · x ≤ 1} for a CCW polygon with 0 in its interior."""
    nxt = np.roll(vertices, -1, axis=0)
    edge = nxt - vertices
    normal = np.stack([edge[:, 1], -edge[:, 0]], axis=1)  # outward for CCW
    offset = np.einsum("ij,ij->i", normal, vertices)
    if np.any(offset <= 0.0):
        raise RuntimeError("stoppable polygon does not contain rest in its interior")
    return normal / offset[:, None]


@functools.lru_cache(maxsize=256)
def _cached_polygon(v_max: float, a_max: float, j_max: float, dt: float) -> StoppablePolygon:
    return stoppable_polygon(v_max, a_max, j_max, dt)


def stoppable_polygon(
    max_velocity: float,
    max_acceleration: float,
    max_jerk: float,
    dt_s: float,
    *,
    max_steps: int = 2_000,
) -> StoppablePolygon:
    """Computes the stoppable set S of the FD triple integrator (1) for one joint.

    Args:
        max_velocity: v_max [rad/s], > 0, may be inf.
        max_acceleration: a_max [rad/s²], finite and > 0.
        max_jerk: j_max [rad/s³], finite and > 0.
        dt_s: Δt [s].
        max_steps: cap on the recursion depth N (S_N, the states that can stop within N
            steps, is invariant for every N, so a cap only makes the set conservative: at 4 Hz
            2000 steps are 500 s of braking; at 100 Hz, 20 s).

    Returns:
        The polygon (see StoppablePolygon), certified controlled invariant.

    Raises:
        RuntimeError: the certification failed (a bug, not an input error).

    Cost: O(N · vertices) with N ≈ v_max/(a_max Δt) + a_max/(j_max Δt) (at most max_steps);
    milliseconds at 4 Hz with realistic limits, ~1.5 s at 100 Hz (v_max = 0.3, a_max = 0.05,
    j_max = 0.1); the vertex count grows with a_max/(j_max Δt), and with ratios in the hundreds
    (880 vertices at a_max/(j_max Δt) ≈ 440) it takes ~15 s (hulls above :data:`_LARGE_HULL`
    points by Qhull; was minutes with the monotone chain alone; a known limit).
    :func:`limiter_params` caches the polygons by limits.
    """
    v_max, a_max, j_max, dt = (float(max_velocity), float(max_acceleration), float(max_jerk),
                               float(dt_s))
    if math.isinf(v_max):
        facets = np.array([[0.0, 1.0 / a_max], [0.0, -1.0 / a_max]])
        facets.flags.writeable = False
        return StoppablePolygon(facets, np.zeros((0, 2)), 0, (v_max, a_max, j_max))
    # Normalised coordinates x̃ = (v/v_max, a/a_max), ũ = u/j_max ∈ [−1, 1]:
    # ṽ' = ṽ + α ã + β ũ,  ã' = ã + γ ũ.
    alpha = a_max * dt / v_max
    beta = j_max * dt**2 / v_max
    gamma = j_max * dt / a_max
    segment = np.array([beta, gamma])
    m_inv = np.array([[1.0, -alpha], [0.0, 1.0]])
    box = [((1.0, 0.0), 1.0), ((-1.0, 0.0), 1.0), ((0.0, 1.0), 1.0), ((0.0, -1.0), 1.0)]
    poly = np.zeros((1, 2))  # S_0 = {rest}
    steps = 0
    for steps in range(1, max_steps + 1):  # noqa: B007 (read after the loop: the count)
        summed = _convex_hull(np.vstack([poly + segment, poly - segment]))  # S ⊕ [−1, 1] b̃
        new = summed @ m_inv.T  # M̃⁻¹ (…): linear, det 1, keeps order and convexity
        for normal, offset in box:
            new = _clip_halfplane(new, normal, offset)
        new = _convex_hull(new)
        if len(poly) >= 3 and len(new) >= 3:
            old_facets = _facets(poly)
            if (new @ old_facets.T).max() <= 1.0 + _CONVERGENCE_TOLERANCE:
                poly = new
                break
        poly = new
    facets_n = _facets(poly)
    # Certification: every vertex admits a jerk in [−1, 1] that stays in S (convexity ⇒ all of S).
    nb = facets_n @ segment
    moved = poly @ np.array([[1.0, alpha], [0.0, 1.0]]).T
    rhs = 1.0 - moved @ facets_n.T  # (n_vertices, m)
    with np.errstate(divide="ignore", invalid="ignore"):
        bound = rhs / nb
    lo = np.where(nb < 0, bound, -np.inf).max(axis=1).clip(min=-1.0)
    hi = np.where(nb > 0, bound, np.inf).min(axis=1).clip(max=1.0)
    flat = np.where(nb == 0, rhs, 0.0).min(axis=1)
    if np.any(lo > hi + 1e-9) or np.any(flat < -1e-9):
        raise RuntimeError("stoppable polygon failed its invariance certification")
    scale = np.array([v_max, a_max])
    facets, vertices = facets_n / scale, poly * scale
    facets.flags.writeable = vertices.flags.writeable = False  # shared through the cache
    return StoppablePolygon(facets, vertices, steps, (v_max, a_max, j_max))


def stop_position(position, velocity, acceleration, max_acceleration, max_jerk):
    """F(p, v, a): where the time-optimal stop (v = a = 0) with |a| ≤ a_max, |jerk| ≤ j_max of
    the continuous triple integrator ends. Broadcasts; used only as a tracking heuristic.

    Profile (mirrored by s = sign(v + a|a|/(2 j_max)) so that it brakes downward): jerk
    −j_max for t1 until a = −a_p, hold −a_p for t2 (only if a_p = a_max), jerk +j_max for
    t3 = a_p/j_max until a = 0, where a_p = min(√(j_max v + a²/2), a_max) and
    t2 = (j_max v + a²/2 − a_p²)/(j_max a_max). Written with few array operations: it is
    evaluated on grids of candidate jerks every tick.
    """
    a_max, j_max = max_acceleration, max_jerk
    sign = np.where(velocity + acceleration * np.abs(acceleration) / (2.0 * j_max) >= 0.0,
                    1.0, -1.0)
    v = sign * velocity
    a = sign * acceleration
    peak_sq = np.maximum(j_max * v + 0.5 * a * a, 0.0)
    peak = np.minimum(np.sqrt(peak_sq), a_max)
    t1 = np.maximum((a + peak) / j_max, 0.0)
    t2 = np.maximum((peak_sq - peak * peak) / (j_max * a_max), 0.0)
    t3 = peak / j_max
    # Phase 1 (jerk −j_max): Δp = v t1 + a t1²/2 − j t1³/6, v1 = v + a t1 − j t1²/2.
    jt1 = j_max * t1
    d1 = t1 * (v + t1 * (0.5 * a - jt1 / 6.0))
    v1 = v + t1 * (a - 0.5 * jt1)
    # Phase 2 (a = −a_p) then 3 (jerk +j_max, j t3 = a_p), with v2 = v1 − a_p t2:
    # Δp = v1 t2 − a_p t2²/2 + v2 t3 − a_p t3²/2 + a_p t3²/6
    #    = v1 (t2 + t3) − a_p (t2²/2 + t2 t3 + t3²/3).
    d23 = v1 * (t2 + t3) - peak * (0.5 * t2 * t2 + t2 * t3 + t3 * t3 / 3.0)
    return position + sign * (d1 + d23)


def _stop_after(u, position, velocity, acceleration, max_acceleration, max_jerk, dt):
    """F of the state reached from (p, v, a) with jerk u by (1); broadcasts."""
    acc = acceleration + u * dt
    vel = velocity + acc * dt
    return stop_position(position + vel * dt, vel, acc, max_acceleration, max_jerk)




# -- the pure limiter ---------------------------------------------------------------------------

class LimiterOutcome(enum.IntEnum):
    """What one tick of :func:`limiter_step` did (the limiter's result enum)."""

    EXACT = 0
    """Every joint commanded its target, bit for bit."""
    LIMITED = 1
    """Some joint's command differs from its target: the limits (or the braking band) moved
    it. Safe: every limit still holds."""
    BRAKING = 2
    """Some joint's target was not finite: that joint brakes to rest (``state.held``)."""


@dataclass(frozen=True, eq=False)
class LimiterParams:
    """The limits of a limiter and everything derived from them once (immutable).

    Attributes:
        dt_s: Δt, the command period [s].
        max_velocity, max_acceleration, max_jerk: the user's limits v_max (inf = none),
            a_max, j_max per joint, (J,) [rad/s, rad/s², rad/s³]; the guarantee is stated
            for these.
        rule: ``"braking"`` or ``"greedy"`` (module docstring).
        margin: the relative shrink of the limits used internally.
        joint_names: labels, or None.
        stoppable_sets: per joint, the stoppable set S of the shrunk limits.
        velocity_internal, acceleration_internal, jerk_internal: (1 − margin)·limits, (J,).
        facet_velocity, facet_acceleration: the facet rows g of every S, padded to a common
            count m with rows 0·x ≤ 1 that never bind, (J, m).
        upper_rows, lower_rows: where g·b > 0 (an upper bound on u) and g·b < 0, (J, m).
        inverse_gb: 1/(g·b) (0 where g·b = 0), (J, m).
    """

    dt_s: float
    max_velocity: np.ndarray
    max_acceleration: np.ndarray
    max_jerk: np.ndarray
    rule: str
    margin: float
    joint_names: tuple[str, ...] | None
    stoppable_sets: tuple[StoppablePolygon, ...]
    velocity_internal: np.ndarray
    acceleration_internal: np.ndarray
    jerk_internal: np.ndarray
    facet_velocity: np.ndarray
    facet_acceleration: np.ndarray
    upper_rows: np.ndarray
    lower_rows: np.ndarray
    inverse_gb: np.ndarray

    def __post_init__(self):
        # Derived once for the compiled tick (limiter_step, safety/limiter_kernel.py): per
        # joint, the facet rows (g_v, g_a, 1/(g·b)) of S in three groups, the rows of S without
        # the padding rows (for the gauge), the rows bounding u from above (g·b > 0) and from
        # below (g·b < 0), padded to a common count, with the counts and the internal
        # (a_max, j_max). Not dataclass fields: the constructor is unchanged. The kernel is
        # compiled (or loaded from numba's cache) here, once per process, not in a tick.
        gv, ga, inverse = self.facet_velocity, self.facet_acceleration, self.inverse_gb
        groups = ((gv != 0.0) | (ga != 0.0), self.upper_rows, self.lower_rows)
        num_joints, num_rows = gv.shape
        rows = np.zeros((num_joints, len(groups), num_rows, 3))
        counts = np.zeros((num_joints, len(groups)), dtype=np.int64)
        for j in range(num_joints):
            for g, selected in enumerate(groups):
                chosen = np.flatnonzero(selected[j])
                counts[j, g] = len(chosen)
                rows[j, g, : len(chosen)] = np.stack(
                    [gv[j, chosen], ga[j, chosen], inverse[j, chosen]], axis=1)
        limits = np.stack([self.acceleration_internal, self.jerk_internal], axis=1)
        none_held = np.zeros(num_joints, dtype=bool)
        for array in (rows, counts, limits, none_held):
            array.flags.writeable = False
        # The kernel's leading arguments, and the `held` of every tick it does (no joint).
        object.__setattr__(self, "_kernel_arguments", (
            self.dt_s, self.dt_s**2, self.rule != "greedy", _GRID, rows, counts, limits))
        object.__setattr__(self, "_none_held", none_held)
        _kernel()

    @property
    def num_joints(self) -> int:
        return int(self.max_acceleration.shape[0])


class LimiterState(NamedTuple):
    """The limiter after tick k (immutable: no function changes one).

    Attributes:
        position: p̂_k, the last command [rad], (J,).
        velocity: v̂_k, the nominal FD velocity of the sent sequence [rad/s], (J,).
        acceleration: â_k, the nominal FD acceleration [rad/s²], (J,).
        sent: p_{k−3} … p_k, oldest first [rad], (4, J).
        targets: r_{k−1}, r_k, the two previous targets [rad], (2, J).
        held: per joint, whether tick k braked because its target was not finite, (J,).
        ticks: k + 1, the ticks since the start.
        outcome: what tick k did.
    """

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    sent: np.ndarray
    targets: np.ndarray
    held: np.ndarray
    ticks: int
    outcome: LimiterOutcome


def limiter_params(
    *,
    dt_s: float,
    max_acceleration,
    max_jerk,
    max_velocity=None,
    num_joints: int | None = None,
    joint_names=None,
    rule: str = "braking",
    margin: float = DEFAULT_MARGIN,
) -> LimiterParams:
    """Validates the limits and derives the stoppable sets (cached by limits).

    Args:
        dt_s: Δt [s].
        max_acceleration: a_max [rad/s²] (scalar, per joint or {joint: value}); finite > 0.
        max_jerk: j_max [rad/s³]; finite > 0.
        max_velocity: v_max [rad/s]; None or inf entries = no velocity limit.
        num_joints: J; may be left out when ``joint_names`` gives it.
        joint_names: labels for errors and per-name limits.
        rule: ``"braking"`` (default) or ``"greedy"``.
        margin: relative internal shrink of the limits, in (0, 1e-3).

    Raises:
        ValueError: naming the field, the value and (where relevant) the joint.
    """
    if rule not in RULES:
        raise ValueError(f"rule = {rule!r} must be one of {RULES}")
    dt = check_positive_scalar("dt_s", dt_s)
    margin = check_positive_scalar("margin", margin)
    if margin >= 1e-3:
        raise ValueError(f"margin = {margin!r} must be below 1e-3")
    names = None if joint_names is None else tuple(str(name) for name in joint_names)
    if num_joints is None:
        if names is None:
            raise ValueError("num_joints = None: give num_joints or joint_names")
        num_joints = len(names)
    if isinstance(num_joints, bool) or not isinstance(num_joints, (int, np.integer)) or (
            num_joints < 1):
        raise ValueError(f"num_joints = {num_joints!r} must be a positive integer")
    n = int(num_joints)
    if names is not None and len(names) != n:
        raise ValueError(f"joint_names has {len(names)} name(s) but num_joints = {n}")
    a_max = as_per_joint("max_acceleration_rad_per_s2", max_acceleration, n, names)
    j_max = as_per_joint("max_jerk_rad_per_s3", max_jerk, n, names)
    v_max = (np.full(n, np.inf) if max_velocity is None else as_per_joint(
        "max_velocity_rad_per_s", max_velocity, n, names, allow_inf=True))
    shrink = 1.0 - margin
    v_in, a_in, j_in = v_max * shrink, a_max * shrink, j_max * shrink
    sets = tuple(_cached_polygon(float(v_in[i]), float(a_in[i]), float(j_in[i]), dt)
                 for i in range(n))
    rows = max(len(s.facets) for s in sets)
    facets = np.zeros((n, rows, 2))  # padding rows 0·x ≤ 1 never bind
    for i, s in enumerate(sets):
        facets[i, : len(s.facets)] = s.facets
    gv, ga = facets[..., 0], facets[..., 1]
    # (2): g·b u ≤ 1 − g·M x, with g·M x = g_v (v + a Δt) + g_a a and b = (Δt², Δt).
    gb = gv * dt**2 + ga * dt
    inverse = np.divide(1.0, gb, out=np.zeros_like(gb), where=gb != 0.0)
    upper, lower = gb > 0.0, gb < 0.0
    for array in (upper, lower):
        array.flags.writeable = False
    return LimiterParams(
        dt_s=dt, max_velocity=readonly_copy(v_max), max_acceleration=readonly_copy(a_max),
        max_jerk=readonly_copy(j_max), rule=rule, margin=margin, joint_names=names,
        stoppable_sets=sets, velocity_internal=readonly_copy(v_in),
        acceleration_internal=readonly_copy(a_in), jerk_internal=readonly_copy(j_in),
        facet_velocity=readonly_copy(gv), facet_acceleration=readonly_copy(ga), upper_rows=upper,
        lower_rows=lower, inverse_gb=readonly_copy(inverse))


def limiter_rest_state(params: LimiterParams, q, *, field: str = "q") -> LimiterState:
    """At rest at ``q`` (J,) [rad]: history p_{−1} = p_{−2} = p_{−3} = q, v = a = 0.

    Raises:
        ValueError: a wrong shape or a non-finite entry (naming ``field``, the joint and the
            value).
    """
    q = check_finite_per_joint(field, q, params.num_joints, params.joint_names)
    zeros = np.zeros_like(q)
    return LimiterState(position=q, velocity=zeros, acceleration=zeros.copy(),
                        sent=np.tile(q, (HISTORY_LENGTH + 1, 1)), targets=np.tile(q, (2, 1)),
                        held=np.zeros(q.shape, dtype=bool), ticks=0,
                        outcome=LimiterOutcome.EXACT)


def limiter_moving_state(params: LimiterParams, history, target) -> LimiterState:
    """Just after the sent commands ``history`` = [p_{k−3}, p_{k−2}, p_{k−1}] (3, J), oldest
    first: nominal (p, v, a) = their FD values, target history (r_{k−2}, r_{k−1}) =
    ``target`` (2, J), or a single target (J,) twice (a target at rest there). p_{k−4} (one before
    the oldest) is taken equal to p_{k−3}; it only enters the jerk of the tick already sent.

    The FD state is taken as it is; the next :func:`limiter_step` scales a state that lies a
    few ulps outside S back onto it (module docstring, Floating point 3), so a history whose
    FD state is really outside S must not be given (check it against
    ``params.stoppable_sets`` first).
    """
    dt = params.dt_s
    h = np.array(history, dtype=float)
    if h.shape != (HISTORY_LENGTH, params.num_joints):
        raise ValueError(f"history has shape {h.shape}; expected "
                         f"({HISTORY_LENGTH}, {params.num_joints}) (p_(k-3), p_(k-2), p_(k-1))")
    r = np.array(target, dtype=float)
    n = params.num_joints
    if r.shape == (n,):
        r = np.vstack([r, r])
    if r.shape != (2, n):
        raise ValueError(f"target has shape {r.shape}; expected ({n},) or (2, {n})")
    velocity, acceleration = fd_state(h, dt)
    return LimiterState(position=h[2].copy(), velocity=velocity, acceleration=acceleration,
                        sent=np.vstack([h[0], h[0], h[1], h[2]]), targets=r,
                        held=np.zeros(n, dtype=bool), ticks=0, outcome=LimiterOutcome.EXACT)


def _projected(params: LimiterParams, velocity, acceleration):
    """(v̂, â) scaled back onto S where rounding left them a few ulps outside (Floating point
    3); unchanged (the same arrays) otherwise."""
    gauge = (params.facet_velocity * velocity[:, None]
             + params.facet_acceleration * acceleration[:, None]).max(axis=1)
    outside = gauge > 1.0
    if outside.any():
        scale = np.where(outside, 1.0 / np.where(outside, gauge, 1.0), 1.0)
        return velocity * scale, acceleration * scale
    return velocity, acceleration


def _interval(params: LimiterParams, velocity, acceleration):
    """[u_lo, u_hi] of (2) for a (projected) FD state."""
    dt = params.dt_s
    rhs = 1.0 - (params.facet_velocity * (velocity + acceleration * dt)[:, None]
                 + params.facet_acceleration * acceleration[:, None])
    bound = rhs * params.inverse_gb
    hi = np.minimum(np.where(params.upper_rows, bound, np.inf).min(axis=1),
                    params.jerk_internal)
    lo = np.maximum(np.where(params.lower_rows, bound, -np.inf).max(axis=1),
                    -params.jerk_internal)
    return lo, hi


def admissible_jerk(params: LimiterParams, state: LimiterState) -> tuple[np.ndarray, np.ndarray]:
    """The interval [u_lo, u_hi] (2) of jerks [rad/s³] that keep the next state in S."""
    return _interval(params, *_projected(params, state.velocity, state.acceleration))


def _band(params, position, velocity, acceleration, lo, hi, u_hit, wall_lo, wall_hi):
    """The jerks [u_lower, u_upper] ⊆ [lo, hi] whose next state has its stop point F in
    [wall_lo, wall_hi] (F increases with u; an end of [lo, hi] where the band misses it).

    First F at clip(u_hit, lo, hi) alone: when it lies between the walls (most ticks: the
    command follows the target), the band is not needed and [lo, hi] is returned. Otherwise
    both walls of every joint are solved in one vectorised pass (row i is joint
    i mod num_joints): a 65-point grid over [lo, hi], then a secant step inside the
    bracketing cell."""
    n, dt = params.num_joints, params.dt_s
    a_lim, j_lim = params.acceleration_internal, params.jerk_internal
    hit = np.minimum(np.maximum(u_hit, lo), hi)
    f_hit = _stop_after(hit, position, velocity, acceleration, a_lim, j_lim, dt)
    tolerance_lo = np.maximum(np.abs(wall_lo), 1.0) * _BAND_TOLERANCE
    tolerance_hi = np.maximum(np.abs(wall_hi), 1.0) * _BAND_TOLERANCE
    inside = (f_hit - wall_lo >= -tolerance_lo) & (f_hit - wall_hi <= tolerance_hi)
    if inside.all():
        return lo, hi
    joints = np.concatenate([np.arange(n), np.arange(n)])
    wall = np.concatenate([wall_lo, wall_hi])
    column = (position[joints, None], velocity[joints, None], acceleration[joints, None],
              a_lim[joints, None], j_lim[joints, None], dt)
    low, high = lo[joints], hi[joints]
    rows = np.arange(2 * n)
    grid = low[:, None] + (high - low)[:, None] * _GRID
    values = _stop_after(grid, *column) - wall[:, None]
    all_below, none_below = values[:, -1] <= 0.0, values[:, 0] > 0.0
    left, right = low, high
    # Bracket the crossing in the grid, then one secant step inside the cell.
    index = np.clip((values <= 0.0).sum(axis=1) - 1, 0, _GRID_POINTS - 2)
    low, high = grid[rows, index], grid[rows, index + 1]
    f_low, f_high = values[rows, index], values[rows, index + 1]
    denom = f_high - f_low
    safe = np.where(denom > 0.0, denom, 1.0)
    root = np.minimum(np.maximum(np.where(denom > 0.0, low - f_low * (high - low) / safe, low),
                                 low), high)
    crossing = np.where(all_below, right, np.where(none_below, left, root))
    lower = np.where(inside, lo, np.minimum(crossing[:n], crossing[n:]))
    upper = np.where(inside, hi, crossing[n:])
    return lower, upper


def limiter_step(params: LimiterParams, state: LimiterState, target,
                 lookahead=None) -> tuple[LimiterState, np.ndarray]:
    """One tick: the command p_{k+1} for the target r (the estimate for this tick).

    Args:
        params: the limits (:func:`limiter_params`).
        state: the limiter after the previous tick.
        target: r, (J,) [rad]. Non-finite entries make that joint brake to rest
            (``LimiterOutcome.BRAKING``; never raised).
        lookahead: optional estimates of the next samples r_{k+1} … r_{k+L}, (L, J) [rad],
            nearest first (the fixed-lag smoother's newer blocks); used by the "braking" rule
            only; non-finite columns are ignored.

    Returns:
        (the new state, the command (J,) [rad]); the arguments are not changed.

    Raises:
        ValueError: wrong shapes.
    """
    n = params.num_joints
    r = np.asarray(target, dtype=float)
    if r.shape != (n,):
        raise ValueError(f"target has shape {r.shape}; expected ({n},)")
    future = None
    if lookahead is not None:
        future = np.asarray(lookahead, dtype=float)
        if future.ndim != 2 or future.shape[1] != n or future.shape[0] < 1:
            raise ValueError(f"lookahead has shape {future.shape}; expected (L, {n}) with "
                             "L ≥ 1")
    fast = _step_compiled(params, state, r, future)
    if fast is not None:
        return fast
    return _step_arrays(params, state, r, future)


def _step_arrays(params: LimiterParams, state: LimiterState, r: np.ndarray,
                 future) -> tuple[LimiterState, np.ndarray]:
    """:func:`limiter_step` on arrays (the reference form; used for the ticks the compiled
    path leaves to it: non-finite targets, states or results)."""
    dt = params.dt_s
    a_lim, j_lim = params.acceleration_internal, params.jerk_internal
    p = state.position
    vel, acc = _projected(params, state.velocity, state.acceleration)
    lo, hi = _interval(params, vel, acc)
    held = ~np.isfinite(r)
    if held.any():
        own_stop = stop_position(p, vel, acc, a_lim, j_lim)
        r = np.where(held, own_stop, r)
    # u_hit: p_k = p_{k−1} + (v + (a + u Δt) Δt) Δt = r_k.
    u_hit = ((r - p) / dt - vel - acc * dt) / dt**2
    if params.rule == "greedy":
        lower_band, upper_band = lo, hi
    else:
        r2, r1 = state.targets
        target_vel = fd_velocity(r1, r, dt)
        target_acc = fd_acceleration(r2, r1, r, dt)
        target_stop = stop_position(r, target_vel, target_acc, a_lim, j_lim)
        if held.any():
            target_stop = np.where(held, r, target_stop)
        wall_hi = np.maximum(r, target_stop)
        wall_lo = np.minimum(r, target_stop)
        if future is not None:
            usable = np.all(np.isfinite(future), axis=0) & ~held
            seq = np.vstack([r2, r1, r, np.where(usable, future, r)])
            end_vel = fd_velocity(seq[-2], seq[-1], dt)
            end_acc = fd_acceleration(seq[-3], seq[-2], seq[-1], dt)
            end_stop = stop_position(seq[-1], end_vel, end_acc, a_lim, j_lim)
            wall_hi = np.where(usable, np.maximum(wall_hi, np.maximum(
                seq[2:].max(axis=0), end_stop)), wall_hi)
            wall_lo = np.where(usable, np.minimum(wall_lo, np.minimum(
                seq[2:].min(axis=0), end_stop)), wall_lo)
        # u_hit is kept when it already lies in the band (exact tracking).
        lower_band, upper_band = _band(params, p, vel, acc, lo, hi, u_hit, wall_lo, wall_hi)
    u = np.minimum(np.maximum(u_hit, lower_band), upper_band)
    u = np.minimum(np.maximum(u, lo), hi)
    # Rounding can make [lo, hi] empty by a few ulps: take its midpoint (module docstring).
    u = np.where(lo > hi, 0.5 * (lo + hi), u)
    # (1) on the nominal state; the command is the nominal position.
    acc = acc + u * dt
    vel = vel + acc * dt
    exact = (u == u_hit) & ~held
    command = np.where(exact, r, p + vel * dt)
    if held.any():
        outcome = LimiterOutcome.BRAKING
    elif exact.all():
        outcome = LimiterOutcome.EXACT
    else:
        outcome = LimiterOutcome.LIMITED
    new_state = LimiterState(
        position=command, velocity=vel, acceleration=acc,
        sent=np.vstack([state.sent[1:], command[None, :]]),
        targets=np.vstack([state.targets[1:], r[None, :]]), held=held,
        ticks=state.ticks + 1, outcome=outcome)
    return new_state, command.copy()


# -- the compiled tick ------------------------------------------------------------------------

@functools.cache
def _kernel():
    """The compiled tick (safety/limiter_kernel.py), imported (and so compiled or loaded from
    numba's cache) on first use: a process that never builds limiter parameters does not
    import numba."""
    from telesmooth.safety import limiter_kernel

    return limiter_kernel


_NO_LOOKAHEAD = np.zeros((0, 0))
_NO_LOOKAHEAD.flags.writeable = False


def _step_compiled(params: LimiterParams, state: LimiterState, r: np.ndarray, future):
    """:func:`limiter_step` by the compiled kernel, or None for a tick left to the array
    form (non-finite targets, states or results)."""
    kernel = _kernel()
    history = state.sent.shape[0]
    out = np.empty((history + 5, r.shape[0]))
    try:
        done = kernel.limiter_tick(
            *params._kernel_arguments, state.position, state.velocity, state.acceleration,
            state.targets, state.sent, r, _NO_LOOKAHEAD if future is None else future, out)
    except TypeError:           # state arrays of other dimensions or types than the kernel's
        return None
    if done == kernel.LEFT_TO_ARRAYS:
        return None
    # The new state's arrays are rows of ``out`` (kernel.ROW_…), never written again.
    # Positional fields: position, velocity, acceleration, sent, targets, held, ticks, outcome.
    sent = kernel.ROW_SENT
    command = out[kernel.ROW_COMMAND]
    new_state = LimiterState(
        command, out[kernel.ROW_VELOCITY], out[kernel.ROW_ACCELERATION],
        out[sent:sent + history], out[sent + history:], params._none_held,
        state.ticks + 1,
        LimiterOutcome.EXACT if done == kernel.EXACT else LimiterOutcome.LIMITED)
    return new_state, command.copy()
