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

A thin Drake system around the pure step :func:`telesmooth.safety.fifo.fifo_step` (the hold,
the clutch release and the stop's playout) and
:func:`~telesmooth.safety.fifo.fifo_plan_contingency` (the stop planned between ticks): the
system holds the ports, and the step's
:class:`~telesmooth.safety.fifo.FifoState` lives in the Context as one discrete vector
(:class:`~telesmooth.systems.codec_state.CodecState`).
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem, ValueProducer

from telesmooth.arms.joint_vectors import check_finite_per_joint
from telesmooth.safety.fifo import (
    FifoInputs,
    FifoOutputs,
    FifoParams,
    FifoState,
    fifo_initial_state,
    fifo_plan_contingency,
    fifo_step,
)
from telesmooth.safety.stop import StopParams
from telesmooth.systems.codec_state import CodecState
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

    State (one discrete vector, a :class:`~telesmooth.safety.fifo.FifoState`, updated at
    t_k = k·period_s, offset 0): the L queued samples b = [z_{k−L}, …, z_{k−1}] (oldest
    first), the hold flag h, whether the clutch was seen released during the hold, and the
    last ``q_delayed`` (the fallback for ``q_sent``). With ``on_collision = "stop"`` also: the
    two sent commands before the last [p_{k−3}, p_{k−2}] (p_{k−1} is the ``q_sent`` input at
    tick k), the planned stop (max_stop_ticks × J), its outcome, length N and next index i,
    the braking distance, and the contingency (below).

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

        self._params = FifoParams(num_joints=n, lag=lag, release=config.release,
                                  stop=self._planner,
                                  max_stop_ticks=(config.max_stop_ticks
                                                  if self._planner is not None else 0))
        initial = fifo_initial_state(self._params, q0)
        self._state = CodecState(self, initial)
        if self._planner is not None:
            self.DeclarePeriodicDiscreteUpdateEvent(config.period_s, 0.5 * config.period_s,
                                                    self._update_contingency)
        self._tick_cache = self.DeclareCacheEntry(
            "tick", ValueProducer(allocate=lambda: AbstractValue.Make(object()),
                                  calc=lambda c, value: value.set_value(self._compute_tick(c))))
        self.DeclarePeriodicDiscreteUpdateEvent(config.period_s, 0.0, self._update_queue)
        # A forced update runs the same tick on demand (CalcForcedDiscreteVariableUpdate).
        self.DeclareForcedDiscreteUpdateEvent(self._update_queue)

        self._q_newest_output = self.DeclareVectorOutputPort(
            "q_newest", n, lambda c, out: out.SetFromVector(self._tick(c)[1].window[lag]))
        self._q_delayed_output = self.DeclareVectorOutputPort(
            "q_delayed", n, lambda c, out: out.SetFromVector(self._tick(c)[1].window[0]))
        self._window_output = self.DeclareVectorOutputPort(
            "window", (lag + 1) * n,
            lambda c, out: out.SetFromVector(self._tick(c)[1].window.ravel()))
        self._reset_output = self.DeclareVectorOutputPort(
            "reset", 1, lambda c, out: out.SetAtIndex(0, float(self._tick(c)[1].hold)))
        self._holding_output = self.DeclareVectorOutputPort(
            "holding", 1, lambda c, out: out.SetAtIndex(0, float(self._tick(c)[1].hold)))
        self._braking_distance_output = None
        self._stop_status_output = None
        if self._planner is not None:
            self._braking_distance_output = self.DeclareVectorOutputPort(
                "braking_distance", n,
                lambda c, out: out.SetFromVector(self._tick(c)[1].braking_distance))
            self._stop_status_output = self.DeclareVectorOutputPort(
                "stop_status", 1,
                lambda c, out: out.SetAtIndex(0, float(self._tick(c)[1].stop_outcome)))

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

    @property
    def params(self) -> FifoParams:
        """The immutable parameters of :func:`~telesmooth.safety.fifo.fifo_step`."""
        return self._params

    def fifo_state(self, context) -> FifoState:
        """The FIFO's state in ``context`` (between ticks)."""
        return self._state.get(context)

    # -- the tick -------------------------------------------------------------------------

    def _tick(self, context) -> tuple[FifoState, FifoOutputs]:
        """The tick at this time, computed once per context change (shared by every output
        port and the update)."""
        return self._tick_cache.Eval(context)

    def _q_sent(self, context):
        if self._q_sent_input.HasValue(context):
            return np.asarray(self._q_sent_input.Eval(context), dtype=float)
        return None

    def _compute_tick(self, context) -> tuple[FifoState, FifoOutputs]:
        """:func:`~telesmooth.safety.fifo.fifo_step` on the state and this time's inputs."""
        collision = (
            self._collision_input.HasValue(context)
            and self._collision_input.Eval(context)[0] > 0.5
        ) or (self._stop_input.HasValue(context) and self._stop_input.Eval(context)[0] > 0.5)
        enable = True
        if self._config.release == "clutch":
            if not self._enable_input.HasValue(context):
                raise RuntimeError(
                    "DelayFifo: release = 'clutch' needs the 'enable' input port connected"
                )
            enable = self._enable_input.Eval(context)[0] > 0.5
        inputs = FifoInputs(sample=self._q_target_input.Eval(context), collision=collision,
                            enable=enable, q_sent=self._q_sent(context))
        return fifo_step(self._params, self.fifo_state(context), inputs)

    def _update_contingency(self, context, discrete_state):
        """Mid-period: :func:`~telesmooth.safety.fifo.fifo_plan_contingency` (the stop a
        collision at the next tick would play)."""
        state = self.fifo_state(context)
        planned = fifo_plan_contingency(self._params, state, self._q_sent(context))
        if planned is not state:
            self._state.store(discrete_state, planned)

    def _update_queue(self, context, discrete_state):
        state, outputs = self._tick(context)
        if outputs.unplanned:   # logged when the tick is taken (outputs preview it between)
            _logger.warning("%s: collision at t = %.3f s with no stop planned for this "
                            "history (a tick forced without the mid-period update): hold",
                            self.get_name() or "DelayFifo", context.get_time())
        self._state.store(discrete_state, state)
