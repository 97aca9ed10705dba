"""Hard-limited online mode: Online-CKS estimates through the hard limiter, as a stream.

The limiter itself (the stoppable set, the feasibility proof, the braking rule, the floating
point argument) is the pure core :mod:`telesmooth.safety.limiter`:
``limiter_step(params, state, target) -> (state, command)``. This module keeps two
conveniences for scripts and the smoothing methods: :class:`OnlineHardLimiter`, a small
stateful wrapper that holds one :class:`~telesmooth.safety.limiter.LimiterState`, and
:func:`online_hard_run`, which streams a whole estimate sequence through the limiter.
Drake systems do not use the wrapper: they keep the state in their Context.
"""

from __future__ import annotations

import warnings

import numpy as np

from telesmooth.arms.joint_vectors import _joint_label, check_finite_per_joint, check_trajectory
from telesmooth.safety.limiter import (
    DEFAULT_MARGIN,
    HISTORY_LENGTH,
    RULES,
    LimiterOutcome,
    StoppablePolygon,
    admissible_jerk,
    limiter_params,
    limiter_rest_state,
    limiter_step,
    stop_position,
    stoppable_polygon,
)
from telesmooth.safety.state_codec import VectorCodec

__all__ = [
    "DEFAULT_MARGIN",
    "HISTORY_LENGTH",
    "RULES",
    "OnlineHardLimiter",
    "StoppablePolygon",
    "online_hard_run",
    "stop_position",
    "stoppable_polygon",
]


class OnlineHardLimiter:
    """A limiter that keeps its own state: :func:`~telesmooth.safety.limiter.limiter_step`
    with the state held between calls (for scripts; see the module docstring).

    Args:
        dt_s: Δt, the command period [s] (0.25 s at 4 Hz).
        max_acceleration: a_max [rad/s²] (scalar, sequence or {joint: value}); finite, > 0.
        max_jerk: j_max [rad/s³]; finite, > 0.
        max_velocity: v_max [rad/s]; None or inf entries = no velocity limit.
        q_start: the rest pose before the first tick (num_joints,) [rad];
            p_{−1} = p_{−2} = p_{−3} = q_start.
        joint_names: labels for errors, warnings and per-name limits.
        rule: "braking" (default) or "greedy".
        margin: relative shrink of the limits used internally (default 1e-9).

    Raises:
        ValueError: non-positive/NaN/inf limits (naming field, value and joint), a bad q_start,
            dt_s, rule or margin.
    """

    def __init__(self, *, dt_s: float, max_acceleration, max_jerk, q_start, max_velocity=None,
                 joint_names=None, rule: str = "braking", margin: float = DEFAULT_MARGIN):
        start = np.asarray(q_start, dtype=float)
        if start.ndim != 1 or start.size == 0:
            raise ValueError(f"q_start = {q_start!r} must be a 1-D sequence of joint positions")
        if joint_names is not None and len(tuple(joint_names)) != start.size:
            raise ValueError(f"joint_names has {len(tuple(joint_names))} name(s) but q_start "
                             f"has {start.size} joints")
        self.params = limiter_params(
            dt_s=dt_s, max_acceleration=max_acceleration, max_jerk=max_jerk,
            max_velocity=max_velocity, num_joints=start.size, joint_names=joint_names,
            rule=rule, margin=margin)
        self.state = limiter_rest_state(self.params, start, field="q_start")
        self._codec = VectorCodec(self.state)

    # -- the limits and the state --------------------------------------------------------------

    @property
    def dt_s(self) -> float:
        return self.params.dt_s

    @property
    def rule(self) -> str:
        return self.params.rule

    @property
    def joint_names(self):
        return self.params.joint_names

    @property
    def num_joints(self) -> int:
        return self.params.num_joints

    @property
    def max_acceleration(self) -> np.ndarray:
        return self.params.max_acceleration.copy()

    @property
    def max_jerk(self) -> np.ndarray:
        return self.params.max_jerk.copy()

    @property
    def max_velocity(self) -> np.ndarray:
        return self.params.max_velocity.copy()

    @property
    def stoppable_sets(self) -> tuple[StoppablePolygon, ...]:
        return self.params.stoppable_sets

    @property
    def current_position(self) -> np.ndarray:
        """The last sent command p_k [rad], (num_joints,)."""
        return self.state.position.copy()

    @property
    def current_velocity(self) -> np.ndarray:
        """v_k = (p_k − p_{k−1})/Δt of the sent sequence [rad/s] (nominal, = FD up to ulps)."""
        return self.state.velocity.copy()

    @property
    def current_acceleration(self) -> np.ndarray:
        """a_k = (p_k − 2p_{k−1} + p_{k−2})/Δt² of the sent sequence [rad/s²] (nominal)."""
        return self.state.acceleration.copy()

    @property
    def sent_history(self) -> np.ndarray:
        """The last four sent commands p_{k−3} … p_k, oldest first, (4, num_joints) [rad]."""
        return self.state.sent.copy()

    @property
    def last_held(self) -> np.ndarray:
        """Per joint: whether the last tick braked because its estimate was not finite."""
        return self.state.held.copy()

    @property
    def last_outcome(self) -> LimiterOutcome:
        return self.state.outcome

    @property
    def ticks(self) -> int:
        """Ticks since construction or the last reset."""
        return self.state.ticks

    def reset(self, q) -> None:
        """Rest at ``q`` (num_joints,) [rad]: history p_{−1} = p_{−2} = p_{−3} = q, v = a = 0.

        Raises:
            ValueError: a wrong count or a non-finite entry (field ``q``, the joint, the value).
        """
        self.state = limiter_rest_state(self.params, q, field="q")

    @property
    def state_size(self) -> int:
        """Length of :meth:`get_state_vector`."""
        return self._codec.size

    def get_state_vector(self) -> np.ndarray:
        """Everything the next :meth:`step` depends on, as one vector."""
        return self._codec.pack(self.state)

    def set_state_vector(self, vector) -> None:
        """Restores a state from :meth:`get_state_vector` (the limits are not part of it)."""
        self.state = self._codec.unpack(vector)

    def admissible_jerk(self) -> tuple[np.ndarray, np.ndarray]:
        """The interval [u_lo, u_hi] of jerks [rad/s³] that keep the next state in S."""
        return admissible_jerk(self.params, self.state)

    def step(self, estimate_now, lookahead=None) -> np.ndarray:
        """One tick: returns the command p_k (num_joints,) [rad] and commits it.

        Args:
            estimate_now: r_k, the fixed-lag estimate for this tick (num_joints,) [rad].
                Non-finite entries make that joint brake to rest (a RuntimeWarning names
                them; never raised).
            lookahead: optional estimates of the next samples, (L, num_joints) [rad].

        Raises:
            ValueError: wrong shapes.
        """
        r = np.asarray(estimate_now, dtype=float)
        if r.shape != (self.num_joints,):
            raise ValueError(f"estimate_now has shape {r.shape}; expected ({self.num_joints},)")
        ticks = self.state.ticks
        self.state, command = limiter_step(self.params, self.state, r, lookahead)
        if self.state.outcome == LimiterOutcome.BRAKING:
            labels = ", ".join(f"{_joint_label(int(i), self.joint_names)} = {float(r[i])!r}"
                               for i in np.flatnonzero(self.state.held))
            warnings.warn(f"online_hard: non-finite estimate at tick {ticks} ({labels}); "
                          "braking to rest", RuntimeWarning, stacklevel=2)
        return command


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
    """Streams a whole estimate sequence through the limiter.

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
    q_start = check_finite_per_joint("q_start", q_start, num_joints, joint_names)
    limiter = OnlineHardLimiter(dt_s=dt_s, max_acceleration=max_acceleration, max_jerk=max_jerk,
                                max_velocity=max_velocity, q_start=q_start,
                                joint_names=joint_names, rule=rule, margin=margin)
    out = np.empty_like(array)
    for k in range(num_samples):
        out[k] = limiter.step(array[k], None if lookahead is None else lookahead[k])
    return out
