"""Hard-limited online mode: commands whose finite differences never exceed the limits.

Issue 6 part 1; the online counterpart of the trajectory constraint of SPEC §2.6. At every
4 Hz tick k the ground station has the fixed-lag estimate r_k (the BMFLS / Online-CKS output,
SPEC §3) and must choose the command p_k it sends, with the commands already sent held fixed.
The finite differences of the *sent* sequence (history p_{−1} = p_{−2} = p_{−3} = q_start, the
robot at rest, SPEC §2.6)

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
time-optimal stop within the limits) and the tick is reported with a RuntimeWarning and in
``last_held``.
"""

from __future__ import annotations

import functools
import math
import warnings
from dataclasses import dataclass

import numpy as np

from telesmooth.smoothing.validation import (
    _joint_label,
    as_per_joint,
    check_positive_scalar,
    check_trajectory,
)

RULES = ("braking", "greedy")
DEFAULT_MARGIN = 1e-9
HISTORY_LENGTH = 3
_GRID_POINTS = 65
_GRID = np.linspace(0.0, 1.0, _GRID_POINTS)
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


def _clip_halfplane(poly: np.ndarray, normal, offset: float) -> np.ndarray:
    """Convex polygon ∩ {x : normal · x ≤ offset} (Sutherland–Hodgman); the result is convex
    and in order but may repeat points (the caller re-hulls)."""
    values = poly @ np.asarray(normal) - offset
    out = []
    n = len(poly)
    for i in range(n):
        p, q = poly[i], poly[(i + 1) % n]
        vp, vq = values[i], values[(i + 1) % n]
        if vp <= 0.0:
            out.append(p)
        if (vp < 0.0 < vq) or (vq < 0.0 < vp):
            out.append(p + (q - p) * (vp / (vp - vq)))
    return np.array(out) if out else np.zeros((0, 2))


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
    milliseconds at 4 Hz with realistic limits, ~2 s at 100 Hz (v_max = 0.3, a_max = 0.05,
    j_max = 0.1) and up to ~10 s for extreme ratios at 100 Hz, where the vertex count grows
    with a_max/(j_max Δt) (a known limit: no vertex pruning yet).
    OnlineHardLimiter caches the polygons by limits.
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
    for steps in range(1, max_steps + 1):
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


class OnlineHardLimiter:
    """Chooses each tick's command so that the sent sequence obeys hard FD limits.

    See the module docstring for the algorithm and the feasibility proof. Vectorised over
    joints; O(facets) per joint and tick. Mutable: it keeps the committed history.

    Args:
        dt_s: Δt, the command period [s] (0.25 s at 4 Hz).
        max_acceleration: a_max [rad/s²] (scalar, sequence or {joint: value}); finite, > 0.
        max_jerk: j_max [rad/s³]; finite, > 0.
        max_velocity: v_max [rad/s]; None or inf entries = no velocity limit.
        q_start: the rest pose before the first tick (num_joints,) [rad];
            p_{−1} = p_{−2} = p_{−3} = q_start.
        joint_names: labels for errors, warnings and per-name limits.
        rule: "braking" (default) or "greedy", see the module docstring.
        margin: relative shrink of the limits used internally (default 1e-9).

    Raises:
        ValueError: non-positive/NaN/inf limits (naming field, value and joint), a bad q_start,
            dt_s, rule or margin.
    """

    def __init__(
        self,
        *,
        dt_s: float,
        max_acceleration,
        max_jerk,
        q_start,
        max_velocity=None,
        joint_names=None,
        rule: str = "braking",
        margin: float = DEFAULT_MARGIN,
    ):
        if rule not in RULES:
            raise ValueError(f"rule = {rule!r} must be one of {RULES}")
        self.rule = rule
        self.dt_s = check_positive_scalar("dt_s", dt_s)
        margin = check_positive_scalar("margin", margin)
        if margin >= 1e-3:
            raise ValueError(f"margin = {margin!r} must be below 1e-3")
        start = np.asarray(q_start, dtype=float)
        if start.ndim != 1 or start.size == 0:
            raise ValueError(f"q_start = {q_start!r} must be a 1-D sequence of joint positions")
        n = start.size
        self._num_joints = n
        self.joint_names = None if joint_names is None else tuple(joint_names)
        if self.joint_names is not None and len(self.joint_names) != n:
            raise ValueError(
                f"joint_names has {len(self.joint_names)} name(s) but q_start has {n} joints")
        self._check_finite("q_start", start)
        self.max_acceleration = as_per_joint("max_acceleration_rad_per_s2", max_acceleration, n,
                                             self.joint_names)
        self.max_jerk = as_per_joint("max_jerk_rad_per_s3", max_jerk, n, self.joint_names)
        self.max_velocity = (np.full(n, np.inf) if max_velocity is None else as_per_joint(
            "max_velocity_rad_per_s", max_velocity, n, self.joint_names, allow_inf=True))
        shrink = 1.0 - margin
        # Internal (shrunk) limits; the guarantee is stated for the user's limits.
        self._v = self.max_velocity * shrink
        self._a = self.max_acceleration * shrink
        self._j = self.max_jerk * shrink
        self.stoppable_sets = tuple(
            _cached_polygon(float(self._v[i]), float(self._a[i]), float(self._j[i]), self.dt_s)
            for i in range(n))
        rows = max(len(s.facets) for s in self.stoppable_sets)
        facets = np.zeros((n, rows, 2))  # padding rows 0·x ≤ 1 never bind
        for i, s in enumerate(self.stoppable_sets):
            facets[i, : len(s.facets)] = s.facets
        dt = self.dt_s
        self._gv, self._ga = facets[..., 0], facets[..., 1]
        # (2): g·b u ≤ 1 − g·M x, with g·M x = g_v (v + a Δt) + g_a a.
        nb = self._gv * dt**2 + self._ga * dt
        self._upper_rows = nb > 0.0
        self._lower_rows = nb < 0.0
        self._inv_nb = np.divide(1.0, nb, out=np.zeros_like(nb), where=nb != 0.0)
        self.reset(start)

    # -- state ---------------------------------------------------------------------------------

    @property
    def num_joints(self) -> int:
        return self._num_joints

    @property
    def current_position(self) -> np.ndarray:
        """The last sent command p_{k} [rad], (num_joints,)."""
        return self._p.copy()

    @property
    def current_velocity(self) -> np.ndarray:
        """v_k = (p_k − p_{k−1})/Δt of the sent sequence [rad/s] (nominal, = FD up to ulps)."""
        return self._vel.copy()

    @property
    def current_acceleration(self) -> np.ndarray:
        """a_k = (p_k − 2p_{k−1} + p_{k−2})/Δt² of the sent sequence [rad/s²] (nominal)."""
        return self._acc.copy()

    @property
    def sent_history(self) -> np.ndarray:
        """The last four sent commands p_{k−3} … p_k, oldest first, (4, num_joints) [rad]."""
        return np.array(self._sent)

    @property
    def last_held(self) -> np.ndarray:
        """Per joint: whether the last tick braked because its estimate was not finite."""
        return self._held.copy()

    @property
    def ticks(self) -> int:
        """Ticks since construction or the last reset."""
        return self._ticks

    def reset(self, q) -> None:
        """Rest at ``q`` (num_joints,) [rad]: history p_{−1} = p_{−2} = p_{−3} = q, v = a = 0."""
        q = np.asarray(q, dtype=float)
        if q.shape != (self._num_joints,):
            raise ValueError(f"q = {q!r} must have shape ({self.num_joints},)")
        self._check_finite("q", q)
        self._p = q.copy()
        self._vel = np.zeros_like(q)
        self._acc = np.zeros_like(q)
        self._sent = [q.copy() for _ in range(HISTORY_LENGTH + 1)]
        self._targets = [q.copy(), q.copy()]  # r_{k−2}, r_{k−1}
        self._held = np.zeros(q.shape, dtype=bool)
        self._ticks = 0

    @property
    def state_size(self) -> int:
        """Length of :meth:`get_state_vector` (10 values per joint + the tick count)."""
        return 10 * self._num_joints + 1

    def get_state_vector(self) -> np.ndarray:
        """Everything the next :meth:`step` depends on, as one vector (for a Drake Context):
        [p, v, a, p_{k−3} … p_k, r_{k−2}, r_{k−1}, held, ticks]."""
        return np.concatenate([self._p, self._vel, self._acc, *self._sent, *self._targets,
                               self._held.astype(float), [float(self._ticks)]])

    def set_state_vector(self, vector) -> None:
        """Restores a state from :meth:`get_state_vector` (the limits are not part of it)."""
        vector = np.asarray(vector, dtype=float)
        if vector.shape != (self.state_size,):
            raise ValueError(f"state vector has shape {vector.shape}; expected "
                             f"({self.state_size},)")
        parts = vector[:-1].reshape(10, self._num_joints)
        self._p, self._vel, self._acc = parts[0].copy(), parts[1].copy(), parts[2].copy()
        self._sent = [row.copy() for row in parts[3:7]]
        self._targets = [parts[7].copy(), parts[8].copy()]
        self._held = parts[9] > 0.5
        self._ticks = int(vector[-1])

    def _check_finite(self, field: str, values: np.ndarray) -> None:
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            i = int(bad[0])
            raise ValueError(f"{field}[{i}] = {float(values[i])!r} for "
                             f"{_joint_label(i, self.joint_names)} must be finite")

    # -- one tick ------------------------------------------------------------------------------

    def admissible_jerk(self) -> tuple[np.ndarray, np.ndarray]:
        """The interval [u_lo, u_hi] (2) of jerks [rad/s³] that keep the next state in S."""
        self._project_nominal()
        dt = self.dt_s
        rhs = 1.0 - (self._gv * (self._vel + self._acc * dt)[:, None]
                     + self._ga * self._acc[:, None])
        bound = rhs * self._inv_nb
        hi = np.minimum(np.where(self._upper_rows, bound, np.inf).min(axis=1), self._j)
        lo = np.maximum(np.where(self._lower_rows, bound, -np.inf).max(axis=1), -self._j)
        return lo, hi

    def _project_nominal(self) -> None:
        """Scales a nominal (v̂, â) that rounding left a few ulps outside S back onto S."""
        gauge = (self._gv * self._vel[:, None] + self._ga * self._acc[:, None]).max(axis=1)
        outside = gauge > 1.0
        if outside.any():
            scale = np.where(outside, 1.0 / np.where(outside, gauge, 1.0), 1.0)
            self._vel = self._vel * scale
            self._acc = self._acc * scale

    def _band(self, lo, hi, u_hit, wall_lo, wall_hi):
        """The jerks [u_lower, u_upper] ⊆ [lo, hi] whose next state has its stop point F in
        [wall_lo, wall_hi] (F increases with u; an end of [lo, hi] where the band misses it),
        and whether clip(u_hit, lo, hi) already lies in the band (per joint).

        Both walls of every joint are solved in one vectorised pass (row i is joint
        i mod num_joints): a 65-point grid over [lo, hi] (plus the u_hit column), then a
        secant step inside the bracketing cell."""
        n = self.num_joints
        wall = np.concatenate([wall_lo, wall_hi])
        joints = np.concatenate([np.arange(n), np.arange(n)])
        column = (self._p[joints, None], self._vel[joints, None], self._acc[joints, None],
                  self._a[joints, None], self._j[joints, None], self.dt_s)
        low, high = lo[joints], hi[joints]
        hit = np.clip(u_hit, lo, hi)[joints]
        rows = np.arange(2 * n)
        grid = np.concatenate([low[:, None] + (high - low)[:, None] * _GRID, hit[:, None]],
                              axis=1)
        values = _stop_after(grid, *column) - wall[:, None]
        tolerance = np.maximum(np.abs(wall), 1.0) * _BAND_TOLERANCE
        f_hit = values[:, -1]
        inside = (f_hit[:n] >= -tolerance[:n]) & (f_hit[n:] <= tolerance[n:])
        if inside.all():
            return lo, hi, inside
        values = values[:, :-1]
        all_below, none_below = values[:, -1] <= 0.0, values[:, 0] > 0.0
        left, right = low, high
        # Bracket the crossing in the grid, then one secant step inside the cell.
        index = np.clip((values <= 0.0).sum(axis=1) - 1, 0, _GRID_POINTS - 2)
        low, high = grid[rows, index], grid[rows, index + 1]
        f_low, f_high = values[rows, index], values[rows, index + 1]
        denom = f_high - f_low
        safe = np.where(denom > 0.0, denom, 1.0)
        root = np.clip(np.where(denom > 0.0, low - f_low * (high - low) / safe, low), low, high)
        crossing = np.where(all_below, right, np.where(none_below, left, root))
        lower = np.where(inside, lo, np.minimum(crossing[:n], crossing[n:]))
        upper = np.where(inside, hi, crossing[n:])
        return lower, upper, inside

    def step(self, estimate_now, lookahead=None) -> np.ndarray:
        """One tick: returns the command p_k (num_joints,) [rad] and commits it.

        Args:
            estimate_now: r_k, the fixed-lag estimate for this tick (num_joints,) [rad].
                Non-finite entries make that joint brake to rest (reported, never raised).
            lookahead: optional estimates of the next samples r_{k+1} … r_{k+L}, shape
                (L, num_joints) [rad], nearest first (the fixed-lag smoother's newer blocks).
                Used by the "braking" rule only; non-finite columns are ignored.

        Raises:
            ValueError: wrong shapes.
        """
        r = np.asarray(estimate_now, dtype=float)
        if r.shape != (self.num_joints,):
            raise ValueError(f"estimate_now has shape {r.shape}; expected ({self.num_joints},)")
        future = None
        if lookahead is not None:
            future = np.asarray(lookahead, dtype=float)
            if future.ndim != 2 or future.shape[1] != self.num_joints or future.shape[0] < 1:
                raise ValueError(f"lookahead has shape {future.shape}; expected "
                                 f"(L, {self.num_joints}) with L ≥ 1")
        lo, hi = self.admissible_jerk()
        dt = self.dt_s
        held = ~np.isfinite(r)
        raw = r
        if held.any():
            own_stop = stop_position(self._p, self._vel, self._acc, self._a, self._j)
            r = np.where(held, own_stop, r)
            labels = ", ".join(f"{_joint_label(int(i), self.joint_names)} = {float(raw[i])!r}"
                               for i in np.flatnonzero(held))
            warnings.warn(f"online_hard: non-finite estimate at tick {self._ticks} "
                          f"({labels}); braking to rest", RuntimeWarning, stacklevel=2)
        # u_hit: p_k = p_{k−1} + (v + (a + u Δt) Δt) Δt = r_k.
        u_hit = ((r - self._p) / dt - self._vel - self._acc * dt) / dt**2
        if self.rule == "greedy":
            u = u_hit
            lower_band, upper_band = lo, hi
        else:
            r2, r1 = self._targets
            target_vel = (r - r1) / dt
            target_acc = (r - 2.0 * r1 + r2) / dt**2
            target_stop = stop_position(r, target_vel, target_acc, self._a, self._j)
            target_stop = np.where(held, r, target_stop)
            wall_hi = np.maximum(r, target_stop)
            wall_lo = np.minimum(r, target_stop)
            if future is not None:
                usable = np.all(np.isfinite(future), axis=0) & ~held
                seq = np.vstack([r2, r1, r, np.where(usable, future, r)])
                end_vel = (seq[-1] - seq[-2]) / dt
                end_acc = (seq[-1] - 2.0 * seq[-2] + seq[-3]) / dt**2
                end_stop = stop_position(seq[-1], end_vel, end_acc, self._a, self._j)
                wall_hi = np.where(usable, np.maximum(wall_hi, np.maximum(
                    seq[2:].max(axis=0), end_stop)), wall_hi)
                wall_lo = np.where(usable, np.minimum(wall_lo, np.minimum(
                    seq[2:].min(axis=0), end_stop)), wall_lo)
            # u_hit is kept when it already lies in the band (exact tracking).
            lower_band, upper_band, _ = self._band(lo, hi, u_hit, wall_lo, wall_hi)
            u = u_hit
        u = np.clip(u, lower_band, upper_band)
        u = np.clip(u, lo, hi)
        # Rounding can make [lo, hi] empty by a few ulps: take its midpoint (see docstring).
        u = np.where(lo > hi, 0.5 * (lo + hi), u)
        # (1) on the nominal state; the command is the nominal position.
        self._acc = self._acc + u * dt
        self._vel = self._vel + self._acc * dt
        exact = u == u_hit
        self._p = np.where(exact & ~held, r, self._p + self._vel * dt)
        self._sent = self._sent[1:] + [self._p.copy()]
        self._targets = [self._targets[1], r]
        self._held = held
        self._ticks += 1
        return self._p.copy()


def online_hard_run(
    estimates,
    dt_s: float,
    *,
    max_acceleration,
    max_jerk,
    max_velocity=None,
    q_start=None,
    joint_names=None,
    lookahead=None,
    rule: str = "braking",
    margin: float = DEFAULT_MARGIN,
) -> np.ndarray:
    """Streams a whole estimate sequence through an OnlineHardLimiter.

    Args:
        estimates: r_k per tick, shape (N, num_joints) [rad]; non-finite entries brake.
        dt_s: Δt [s].
        max_acceleration, max_jerk, max_velocity: limits as for OnlineHardLimiter.
        q_start: rest pose before the first tick (num_joints,); default estimates[0].
        joint_names: labels.
        lookahead: optional (N, L, num_joints) estimates of the next L samples at each tick.
        rule: "braking" (default) or "greedy".
        margin: internal relative shrink of the limits.

    Returns:
        The sent commands p_k, shape (N, num_joints) [rad]; with the history
        [q_start] * 3 in front their FD values obey every limit.

    Raises:
        ValueError: bad shapes or limits (naming the field, value and joint).
    """
    array = np.asarray(estimates, dtype=float)
    if array.ndim != 2 or array.shape[0] < 1 or array.shape[1] < 1:
        raise ValueError(
            f"estimates must have shape (num_samples, num_joints); got shape {array.shape}")
    num_samples, num_joints = array.shape
    if q_start is None:
        check_trajectory("estimates[0:1]", array[:1], joint_names=joint_names)
        q_start = array[0]
    if lookahead is not None:
        lookahead = np.asarray(lookahead, dtype=float)
        if lookahead.ndim != 3 or lookahead.shape[0] != num_samples or (
                lookahead.shape[2] != num_joints):
            raise ValueError(f"lookahead has shape {lookahead.shape}; expected "
                             f"({num_samples}, L, {num_joints})")
    limiter = OnlineHardLimiter(dt_s=dt_s, max_acceleration=max_acceleration, max_jerk=max_jerk,
                                max_velocity=max_velocity, q_start=q_start,
                                joint_names=joint_names, rule=rule, margin=margin)
    if np.asarray(q_start).shape != (num_joints,):
        raise ValueError(f"q_start has shape {np.asarray(q_start).shape}; expected "
                         f"({num_joints},)")
    out = np.empty_like(array)
    for k in range(num_samples):
        out[k] = limiter.step(array[k], None if lookahead is None else lookahead[k])
    return out
