"""The 0.75 s safety delay: a FIFO of 4 Hz joint-target samples with collision hold.

The ground station samples the 100 Hz inverse-kinematics stream once per uplink period and
queues the samples for ``delay_s`` (L = delay_s / period_s samples, 3 by default) before they
are sent, so that the pre-simulator, which shows the newest command, runs 0.75 s ahead of the
robot. When the pre-simulator reports a collision the queue is refilled with the command
already sent (docs/method.md §5.2, policy "hold"): everything queued that leads into the collision
is discarded and the robot holds. The optional policy "stop" instead plays out a
jerk-limited stop planned from the sent motion (:mod:`telesmooth.systems.collision_stop`) and
then holds at its rest pose. The FIFO is also the fixed-lag smoother's window
(docs/method.md §5.1): the smoother consumes the same samples at the same ticks, so smoothing
adds no delay.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import NamedTuple

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem, ValueProducer

from telesmooth.arms.joint_vectors import check_finite_per_joint
from telesmooth.safety.limiter import HISTORY_LENGTH
from telesmooth.safety.state_codec import VectorCodec
from telesmooth.safety.stop import StopOutcome, StopParams, plan_stop
from telesmooth.systems.timing import check_period, delay_in_samples

_logger = logging.getLogger(__name__)

__all__ = ["DelayFifo", "DelayFifoConfig", "FIFO_COLLISION_POLICIES", "FIFO_RELEASE_POLICIES"]

FIFO_RELEASE_POLICIES = ("collision-clear", "clutch")
FIFO_COLLISION_POLICIES = ("hold", "stop")


@dataclasses.dataclass(frozen=True)
class DelayFifoConfig:
    """Settings of the delay FIFO.

    Attributes:
        period_s: Uplink (sampling) period, s; 0.25 s for the 4 Hz link.
        delay_s: Safety delay, s; must be a whole number L >= 0 of periods (0.75 s → L = 3).
        release: When a collision hold ends. ``"collision-clear"`` (default): at the first
            tick whose ``collision_detected`` input is false. ``"clutch"``: additionally the
            operator must have released the clutch (``enable`` = 0 at some tick during the
            hold) and re-engaged it (haptic re-indexing, docs/method.md §5.2 follow-up); requires
            the ``enable`` input.
        on_collision: What a collision does. ``"hold"`` (default, docs/method.md §5.2): re-send the
            last sent command at once (a velocity step). ``"stop"``: a jerk-limited stop from the
            sent motion to rest within the smoother's acceleration/jerk limits, checked pose
            by pose with the pre-simulator, then hold at the rest pose; where no such stop
            exists it falls back to the hold (see :mod:`telesmooth.systems.collision_stop`).
            Needs the ``collision_stop`` planner (AddGroundStation passes it).
        max_stop_duration_s: Longest stop, s (a whole number of periods); a stop that needs
            longer falls back to the hold. Sizes the state that stores the planned stop.
    """

    period_s: float = 0.25
    delay_s: float = 0.75
    release: str = "collision-clear"
    on_collision: str = "hold"
    max_stop_duration_s: float = 30.0

    def __post_init__(self) -> None:
        check_period("DelayFifoConfig.period_s", self.period_s)
        delay_in_samples(
            self.delay_s, self.period_s,
            delay_field="DelayFifoConfig.delay_s", period_field="DelayFifoConfig.period_s",
        )
        if self.release not in FIFO_RELEASE_POLICIES:
            raise ValueError(
                f"DelayFifoConfig.release = {self.release!r} must be one of "
                f"{FIFO_RELEASE_POLICIES}"
            )
        if self.on_collision not in FIFO_COLLISION_POLICIES:
            raise ValueError(
                f"DelayFifoConfig.on_collision = {self.on_collision!r} must be one of "
                f"{FIFO_COLLISION_POLICIES}"
            )
        if delay_in_samples(
                self.max_stop_duration_s, self.period_s,
                delay_field="DelayFifoConfig.max_stop_duration_s",
                period_field="DelayFifoConfig.period_s") < 1:
            raise ValueError(
                f"DelayFifoConfig.max_stop_duration_s = {self.max_stop_duration_s!r} must be "
                f"at least one period_s = {self.period_s!r}"
            )

    @property
    def lag(self) -> int:
        """L, the delay in samples."""
        return delay_in_samples(self.delay_s, self.period_s)

    @property
    def max_stop_ticks(self) -> int:
        """The most commands a collision stop may take."""
        return delay_in_samples(self.max_stop_duration_s, self.period_s)


class _Contingency(NamedTuple):
    """The stop the FIFO would play if a collision came at the next tick, planned between
    ticks from the sent history it will have then."""

    history: np.ndarray           # (3, J) [p_{k−3}, p_{k−2}, p_{k−1}] it was planned from
    outcome: StopOutcome
    length: int                   # N, the planned commands (1 for a hold fallback)
    commands: np.ndarray          # (max_stop_ticks, J), the first N rows used
    braking_distance: np.ndarray  # (J,)


class _Tick(NamedTuple):
    """One tick of the FIFO, as computed from the state and the current inputs."""

    window: np.ndarray            # (L+1, J), oldest first
    hold: bool                    # a collision hold (or stop) is in force at this tick
    clutch_released: bool         # the clutch was seen released during the hold
    sent_history: np.ndarray | None = None   # stop only: [p_{k−2}, p_{k−1}] to remember
    stop_plan: np.ndarray | None = None      # stop only: (max_ticks, J) planned commands
    stop_info: np.ndarray | None = None      # stop only: [outcome, length, next index]
    braking_distance: np.ndarray | None = None  # stop only: (J,)


class DelayFifo(LeafSystem):
    r"""FIFO of L = delay_s/period_s joint-target samples, refilled with the sent command on
    collision (or, with ``on_collision = "stop"``, with a jerk-limited stop and then the sent
    command).

    .. pydrake_system::

        name: DelayFifo
        input_ports:
        - q_target
        - collision_detected (optional)
        - q_sent (optional)
        - enable (optional)
        - stop_requested (optional)
        output_ports:
        - q_newest
        - q_delayed
        - window
        - reset
        - holding
        - braking_distance (on_collision = "stop" only)
        - stop_status (on_collision = "stop" only)

    Ports (J = num_joints, L = lag):

    - ``q_target``: newest joint targets from the inverse kinematics, rad, (J,); sampled
      (latest value) at each tick. For the period-mean option feed it from a
      :class:`~telesmooth.systems.period_mean.PeriodMean` block.
    - ``collision_detected``: 1 if the pre-simulator saw a collision since the last tick
      (the collision checker's latched flag), (1,); unconnected = never.
    - ``q_sent``: the command most recently sent to the robot (the uplink output), rad, (J,);
      unconnected = this FIFO's own last ``q_delayed``.
    - ``enable``: the operator's clutch, (1,); used by ``release="clutch"`` only.
    - ``stop_requested``: the operator's stop button, (1,): while > 0.5 it acts as a
      collision (the hold, or with ``on_collision = "stop"`` the jerk-limited stop, then the
      hold); unconnected = never.
    - ``q_newest``: z_k, the sample entering the queue at this tick, rad, (J,).
    - ``q_delayed``: z_{k−L}, the sample leaving the queue (the raw delayed command), rad, (J,).
    - ``window``: [z_{k−L}, …, z_k], oldest first, rad, ((L+1)·J,): the smoother's window.
    - ``reset``: 1 when the queue is refilled at this tick (the smoother restarts), (1,).
    - ``holding``: 1 while a collision hold (including a collision stop) is in force, (1,).
    - ``braking_distance``: per joint, the signed excursion from q_hold (the command the
      hold would have kept) of largest magnitude over the last collision stop, rad, (J,);
      every stop command lies between q_hold and q_hold + braking_distance. Zeros before
      the first collision and when the last collision fell back to the hold.
    - ``stop_status``: index in :data:`~telesmooth.systems.collision_stop.STOP_OUTCOMES` of
      the last collision's outcome (0 ``"none"`` before the first, 1 ``"stop"``, 3…6 the
      hold fallbacks: not stoppable, pose rejected, reverses, too long), (1,).

    State (discrete, updated at t_k = k·period_s, offset 0): the L queued samples
    b = [z_{k−L}, …, z_{k−1}] (oldest first), the hold flag h, whether the clutch was seen
    released during the hold, and the last ``q_delayed`` (the fallback for ``q_sent``).
    With ``on_collision = "stop"`` also: the two sent commands before the last
    [p_{k−3}, p_{k−2}] (p_{k−1} is the ``q_sent`` input at tick k), the planned stop
    (max_stop_ticks × J), [outcome, plan length N, next plan index i] and the braking
    distance.

    Outputs are the values *of a tick taken at the current time*: they are computed from the
    state (which holds the queue up to the previous tick) and the current inputs, like Drake's
    ``DiscreteDerivative``. A consumer that samples them at t_k (the smoother, the uplink's
    zero-order hold) therefore gets the tick-k values with no extra period of delay; between
    ticks they preview the next tick. With s = q_target(t_k) and q_s the sent command:

        h_k = collision_k  or  (h_{k−1} and not released_k)
        window_k = [b, s]            if not h_k
                 = [q_s, …, q_s]     if h_k   (docs/method.md §5.2 hold: queue and newest
                                                discarded)
        q_newest = window_k[L];  q_delayed = window_k[0];  b ← window_k[1:]

    With ``on_collision = "stop"``, at a collision tick that starts a hold (h_{k−1} = 0) the
    plan P = [P_0 … P_{N−1}] from [p_{k−3}, p_{k−2}, p_{k−1}] (planned before the tick, see
    below; a hold fallback is N = 1, P_0 = q_s) is taken and i ← 0; then

        h_k = collision_k  or  (h_{k−1} and (not released_k or i < N))
        window_k = [P_i, …, P_i], i ← i + 1   if h_k and i < N   (the stop: the smoother
                                                                  restarts at P_i and emits it)
                 = [q_s, …, q_s]               if h_k and i = N   (hold at the rest pose)

    so the hold is never released before the stop is at rest, the queue and the smoother
    continue from the rest pose, and ``holding`` (hence the uplink's MODE_HOLD) is 1 during
    the stop as during the hold.

    **The plan is made between ticks, never in an output calculation.** At the middle of
    every period (t_k + period_s/2, a second periodic update) the FIFO plans the stop
    P = :func:`~telesmooth.safety.stop.plan_stop` from the history [p_{k−2}, p_{k−1}, p_k]
    it will have at the next tick (p_k = ``q_sent``, which the uplink set at t_k and holds
    until t_{k+1}), and keeps it in its state as the *contingency*: what a collision at
    t_{k+1} will play (planned only when that history changed, and not during a hold). At the
    tick the outputs only read it. A collision tick whose history is not the contingency's
    (a tick forced without the mid-period update) falls back to the hold (outcome
    ``"hold"``, logged): nothing unplanned is sent. At t = 0 the contingency is the stop
    from rest at ``initial_position_rad``.

    A non-finite ``q_target`` is never queued: it is treated like a collision (hold).
    At t = 0 the queue holds ``initial_position_rad`` (the robot's pose), so the first L
    ticks send that pose: the robot starts at rest.
    """

    def __init__(self, config: DelayFifoConfig = DelayFifoConfig(), *, num_joints: int,
                 initial_position_rad=None, collision_stop: StopParams | None = None):
        """Declares ports, state and the tick.

        Args:
            config: Period, delay, release and collision policies.
            num_joints: J.
            initial_position_rad: The robot's start pose (J,), rad; default zeros.
            collision_stop: The stop parameters (limits and the pre-simulator's pose check,
                :func:`~telesmooth.systems.collision_stop.MakeCollisionStopPlanner`);
                required with ``on_collision = "stop"``, ignored with ``"hold"``.

        Raises:
            ValueError: A bad size or pose, a missing planner for ``"stop"``, or a planner
                whose period or joint count differs from this FIFO's.
        """
        super().__init__()
        if not isinstance(num_joints, (int, np.integer)) or num_joints < 1:
            raise ValueError(f"num_joints = {num_joints!r} must be a positive integer")
        self._config = config
        self._num_joints = int(num_joints)
        self._lag = config.lag
        q0 = np.zeros(num_joints) if initial_position_rad is None else check_finite_per_joint(
            "initial_position_rad", initial_position_rad, self._num_joints)
        n, lag = self._num_joints, self._lag
        self._planner = None
        if config.on_collision == "stop":
            if collision_stop is None:
                raise ValueError(
                    "DelayFifoConfig.on_collision = 'stop' needs the collision_stop planner "
                    "(the smoother's limits and the pre-simulator's pose check; see "
                    "telesmooth.systems.collision_stop.MakeCollisionStopPlanner)"
                )
            if collision_stop.num_joints != n:
                raise ValueError(f"collision_stop has {collision_stop.num_joints} joints; the "
                                 f"FIFO has num_joints = {n}")
            if abs(collision_stop.dt_s - config.period_s) > 1e-12 * config.period_s:
                raise ValueError(f"collision_stop.dt_s = {collision_stop.dt_s!r} must equal "
                                 f"DelayFifoConfig.period_s = {config.period_s!r}")
            self._planner = collision_stop  # immutable parameters, no state

        self._q_target_input = self.DeclareVectorInputPort("q_target", n)
        self._collision_input = self.DeclareVectorInputPort("collision_detected", 1)
        self._q_sent_input = self.DeclareVectorInputPort("q_sent", n)
        self._enable_input = self.DeclareVectorInputPort("enable", 1)
        self._stop_input = self.DeclareVectorInputPort("stop_requested", 1)

        self._queue_state = self.DeclareDiscreteState(np.tile(q0, lag))
        # [holding, clutch seen released during the hold]
        self._hold_state = self.DeclareDiscreteState(np.zeros(2))
        self._last_delayed_state = self.DeclareDiscreteState(q0.copy())
        if self._planner is not None:
            self._max_stop_ticks = config.max_stop_ticks
            # [p_{k−3}, p_{k−2}] of the sent commands; the robot starts at rest at q0.
            self._sent_history_state = self.DeclareDiscreteState(
                np.tile(q0, HISTORY_LENGTH - 1))
            self._stop_plan_state = self.DeclareDiscreteState(
                np.zeros(self._max_stop_ticks * n))
            # [outcome index, plan length N, next plan index i]
            self._stop_info_state = self.DeclareDiscreteState(np.zeros(3))
            self._braking_distance_state = self.DeclareDiscreteState(np.zeros(n))
            initial = self._plan_contingency(np.tile(q0, (HISTORY_LENGTH, 1)))
            self._contingency_codec = VectorCodec(initial)
            self._contingency_state = self.DeclareDiscreteState(
                self._contingency_codec.pack(initial))
            self.DeclarePeriodicDiscreteUpdateEvent(config.period_s, 0.5 * config.period_s,
                                                    self._update_contingency)
        self._tick_cache = self.DeclareCacheEntry(
            "tick", ValueProducer(allocate=lambda: AbstractValue.Make(object()),
                                  calc=lambda c, value: value.set_value(self._compute_tick(c))))
        self.DeclarePeriodicDiscreteUpdateEvent(config.period_s, 0.0, self._update_queue)
        # A forced update runs the same tick on demand (CalcForcedDiscreteVariableUpdate).
        self.DeclareForcedDiscreteUpdateEvent(self._update_queue)

        self._q_newest_output = self.DeclareVectorOutputPort(
            "q_newest", n, lambda c, out: out.SetFromVector(self._tick(c).window[lag]))
        self._q_delayed_output = self.DeclareVectorOutputPort(
            "q_delayed", n, lambda c, out: out.SetFromVector(self._tick(c).window[0]))
        self._window_output = self.DeclareVectorOutputPort(
            "window", (lag + 1) * n,
            lambda c, out: out.SetFromVector(self._tick(c).window.ravel()))
        self._reset_output = self.DeclareVectorOutputPort(
            "reset", 1, lambda c, out: out.SetAtIndex(0, float(self._tick(c).hold)))
        self._holding_output = self.DeclareVectorOutputPort(
            "holding", 1, lambda c, out: out.SetAtIndex(0, float(self._tick(c).hold)))
        self._braking_distance_output = None
        self._stop_status_output = None
        if self._planner is not None:
            self._braking_distance_output = self.DeclareVectorOutputPort(
                "braking_distance", n,
                lambda c, out: out.SetFromVector(self._tick(c).braking_distance))
            self._stop_status_output = self.DeclareVectorOutputPort(
                "stop_status", 1, lambda c, out: out.SetAtIndex(0, self._tick(c).stop_info[0]))

    # -- accessors ------------------------------------------------------------------------

    @property
    def lag(self) -> int:
        """L, the delay in samples."""
        return self._lag

    @property
    def config(self) -> DelayFifoConfig:
        return self._config

    @property
    def collision_stop(self) -> StopParams | None:
        """The stop parameters (``on_collision = "stop"``), else None."""
        return self._planner

    def get_q_target_input_port(self):
        return self._q_target_input

    def get_collision_detected_input_port(self):
        return self._collision_input

    def get_q_sent_input_port(self):
        return self._q_sent_input

    def get_enable_input_port(self):
        return self._enable_input

    def get_stop_requested_input_port(self):
        return self._stop_input

    def get_q_newest_output_port(self):
        return self._q_newest_output

    def get_q_delayed_output_port(self):
        return self._q_delayed_output

    def get_window_output_port(self):
        return self._window_output

    def get_reset_output_port(self):
        return self._reset_output

    def get_holding_output_port(self):
        return self._holding_output

    def get_braking_distance_output_port(self):
        """``braking_distance`` (``on_collision = "stop"`` only; else RuntimeError)."""
        return self._stop_only_port(self._braking_distance_output, "braking_distance")

    def get_stop_status_output_port(self):
        """``stop_status`` (``on_collision = "stop"`` only; else RuntimeError)."""
        return self._stop_only_port(self._stop_status_output, "stop_status")

    def _stop_only_port(self, port, name):
        if port is None:
            raise RuntimeError(f"DelayFifo: the {name!r} output exists only with "
                               f"on_collision = 'stop' (this FIFO has "
                               f"{self._config.on_collision!r})")
        return port

    # -- the tick -------------------------------------------------------------------------

    def _tick(self, context) -> _Tick:
        """The tick at this time, computed once per context change (shared by every output
        port and the update)."""
        return self._tick_cache.Eval(context)

    def _compute_tick(self, context) -> _Tick:
        """The tick at this time (see the class docstring)."""
        n, lag = self._num_joints, self._lag
        queue = context.get_discrete_state(self._queue_state).get_value().reshape(lag, n)
        holding, clutch_released = context.get_discrete_state(self._hold_state).get_value()
        holding = holding > 0.5
        sample = self._q_target_input.Eval(context)
        collision = (
            self._collision_input.HasValue(context)
            and self._collision_input.Eval(context)[0] > 0.5
        ) or (self._stop_input.HasValue(context) and self._stop_input.Eval(context)[0] > 0.5)
        collision = collision or not np.all(np.isfinite(sample)) or sample.shape != (n,)
        enable = True
        if self._config.release == "clutch":
            if not self._enable_input.HasValue(context):
                raise RuntimeError(
                    "DelayFifo: release = 'clutch' needs the 'enable' input port connected"
                )
            enable = self._enable_input.Eval(context)[0] > 0.5
            clutch_released = clutch_released > 0.5 or (holding and not enable)
            released = clutch_released and enable
        else:
            released = True
            clutch_released = False
        if self._q_sent_input.HasValue(context):
            q_sent = np.asarray(self._q_sent_input.Eval(context), dtype=float)
        else:
            q_sent = context.get_discrete_state(self._last_delayed_state).get_value()
        if self._planner is not None:
            return self._compute_stop_tick(context, queue, sample, q_sent, collision, holding,
                                           released, clutch_released)
        hold = collision or (holding and not released)
        if hold:
            window = np.tile(q_sent, (lag + 1, 1))
        else:
            window = np.vstack([queue, sample[None, :]])
            clutch_released = False
        return _Tick(window, hold, clutch_released)

    def _compute_stop_tick(self, context, queue, sample, q_sent, collision, holding, released,
                           clutch_released) -> _Tick:
        """The tick with ``on_collision = "stop"``: plan at the collision tick that starts a
        hold, play the plan out, then hold at the sent (rest) pose."""
        n, lag = self._num_joints, self._lag
        history = self._history(context, q_sent)  # p_{k−3}, p_{k−2}, p_{k−1}
        plan = context.get_discrete_state(self._stop_plan_state).get_value().reshape(
            self._max_stop_ticks, n)
        info = context.get_discrete_state(self._stop_info_state).get_value().copy()
        distance = context.get_discrete_state(self._braking_distance_state).get_value()
        if collision and not holding:
            contingency = self._contingency_codec.unpack(
                context.get_discrete_state(self._contingency_state).get_value())
            if np.array_equal(contingency.history, history):
                plan, length = contingency.commands, contingency.length
                outcome, distance = contingency.outcome, contingency.braking_distance
            else:
                _logger.warning("%s: collision at t = %.3f s with no stop planned for this "
                                "history (a tick forced without the mid-period update): hold",
                                self.get_name() or "DelayFifo", context.get_time())
                plan, length = np.tile(q_sent, (self._max_stop_ticks, 1)), 1
                outcome, distance = StopOutcome.HOLD, np.zeros(n)
            info = np.array([float(outcome), float(length), 0.0])
        length, next_index = int(info[1]), int(info[2])
        stopping = next_index < length
        hold = collision or (holding and (not released or stopping))
        if hold and stopping:
            command = plan[next_index]
            info[2] = next_index + 1
        else:
            command = q_sent
        if hold:
            window = np.tile(command, (lag + 1, 1))
        else:
            window = np.vstack([queue, sample[None, :]])
            clutch_released = False
        return _Tick(window, hold, clutch_released, sent_history=history[1:], stop_plan=plan,
                     stop_info=info, braking_distance=np.array(distance, dtype=float))

    def _history(self, context, q_sent) -> np.ndarray:
        """[p_{k−3}, p_{k−2}, p_{k−1}]: the two sent commands in the state, then ``q_sent``."""
        earlier = context.get_discrete_state(self._sent_history_state).get_value().reshape(
            HISTORY_LENGTH - 1, self._num_joints)
        return np.vstack([earlier, np.asarray(q_sent, dtype=float)[None, :]])

    def _plan_contingency(self, history) -> _Contingency:
        """The stop from ``history`` (3, J), in the form kept in the state."""
        plan = plan_stop(self._planner, history, max_ticks=self._max_stop_ticks)
        commands = np.zeros((self._max_stop_ticks, self._num_joints))
        commands[:plan.ticks_to_rest] = plan.commands
        return _Contingency(history=np.array(history, dtype=float), outcome=plan.outcome,
                            length=plan.ticks_to_rest, commands=commands,
                            braking_distance=np.array(plan.braking_distance, dtype=float))

    def _update_contingency(self, context, discrete_state):
        """Mid-period: plans the stop a collision at the next tick would play (class
        docstring), unless holding or the history is the one already planned from."""
        holding = context.get_discrete_state(self._hold_state).get_value()[0] > 0.5
        if holding:
            return
        if self._q_sent_input.HasValue(context):
            q_sent = np.asarray(self._q_sent_input.Eval(context), dtype=float)
        else:
            q_sent = context.get_discrete_state(self._last_delayed_state).get_value()
        history = self._history(context, q_sent)
        stored = context.get_discrete_state(self._contingency_state).get_value()
        if np.array_equal(self._contingency_codec.unpack(stored).history, history):
            return
        discrete_state.get_mutable_vector(self._contingency_state).SetFromVector(
            self._contingency_codec.pack(self._plan_contingency(history)))

    def _update_queue(self, context, discrete_state):
        tick = self._tick(context)
        window, hold = tick.window, tick.hold
        discrete_state.get_mutable_vector(self._queue_state).SetFromVector(
            window[1:].ravel())
        discrete_state.get_mutable_vector(self._hold_state).SetFromVector(
            [float(hold), float(tick.clutch_released and hold)])
        discrete_state.get_mutable_vector(self._last_delayed_state).SetFromVector(window[0])
        if self._planner is not None:
            discrete_state.get_mutable_vector(self._sent_history_state).SetFromVector(
                tick.sent_history.ravel())
            discrete_state.get_mutable_vector(self._stop_plan_state).SetFromVector(
                tick.stop_plan.ravel())
            discrete_state.get_mutable_vector(self._stop_info_state).SetFromVector(
                tick.stop_info)
            discrete_state.get_mutable_vector(self._braking_distance_state).SetFromVector(
                tick.braking_distance)
