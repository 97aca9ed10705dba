"""The 0.75 s safety delay: a FIFO of 4 Hz joint-target samples with collision hold.

The ground station samples the 100 Hz inverse-kinematics stream once per uplink period and
queues the samples for ``delay_s`` (L = delay_s / period_s samples, 3 by default) before they
are sent, so that the pre-simulator, which shows the newest command, runs 0.75 s ahead of the
robot. When the pre-simulator reports a collision the queue is refilled with the command
already sent (SPEC §5.2, policy "hold"): everything queued that leads into the collision is
discarded and the robot holds. The FIFO is also the fixed-lag smoother's window (SPEC §5.1):
the smoother consumes the same samples at the same ticks, so smoothing adds no delay.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem, ValueProducer

from telesmooth.systems.timing import check_period, delay_in_samples

__all__ = ["DelayFifo", "DelayFifoConfig", "FIFO_RELEASE_POLICIES"]

FIFO_RELEASE_POLICIES = ("collision-clear", "clutch")


@dataclasses.dataclass(frozen=True)
class DelayFifoConfig:
    """Settings of the delay FIFO.

    Attributes:
        period_s: Uplink (sampling) period, s; 0.25 s for the 4 Hz link.
        delay_s: Safety delay, s; must be a whole number L >= 0 of periods (0.75 s → L = 3).
        release: When a collision hold ends. ``"collision-clear"`` (default): at the first
            tick whose ``collision_detected`` input is false. ``"clutch"``: additionally the
            operator must have released the clutch (``enable`` = 0 at some tick during the
            hold) and re-engaged it (haptic re-indexing, SPEC §5.2 follow-up); requires the
            ``enable`` input.
    """

    period_s: float = 0.25
    delay_s: float = 0.75
    release: str = "collision-clear"

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

    @property
    def lag(self) -> int:
        """L, the delay in samples."""
        return delay_in_samples(self.delay_s, self.period_s)


class DelayFifo(LeafSystem):
    r"""FIFO of L = delay_s/period_s joint-target samples, refilled with the sent command on
    collision.

    .. pydrake_system::

        name: DelayFifo
        input_ports:
        - q_target
        - collision_detected (optional)
        - q_sent (optional)
        - enable (optional)
        output_ports:
        - q_newest
        - q_delayed
        - window
        - reset
        - holding

    Ports (J = num_joints, L = lag):

    - ``q_target``: newest joint targets from the inverse kinematics, rad, (J,); sampled
      (latest value) at each tick. For the period-mean option feed it from a
      :class:`~telesmooth.systems.period_mean.PeriodMean` block.
    - ``collision_detected``: 1 if the pre-simulator saw a collision since the last tick
      (the collision checker's latched flag), (1,); unconnected = never.
    - ``q_sent``: the command most recently sent to the robot (the uplink output), rad, (J,);
      unconnected = this FIFO's own last ``q_delayed``.
    - ``enable``: the operator's clutch, (1,); used by ``release="clutch"`` only.
    - ``q_newest``: z_k, the sample entering the queue at this tick, rad, (J,).
    - ``q_delayed``: z_{k−L}, the sample leaving the queue (the raw delayed command), rad, (J,).
    - ``window``: [z_{k−L}, …, z_k], oldest first, rad, ((L+1)·J,): the smoother's window.
    - ``reset``: 1 when the queue is refilled at this tick (the smoother restarts), (1,).
    - ``holding``: 1 while a collision hold is in force, (1,).

    State (discrete, updated at t_k = k·period_s, offset 0): the L queued samples
    b = [z_{k−L}, …, z_{k−1}] (oldest first), the hold flag h, whether the clutch was seen
    released during the hold, and the last ``q_delayed`` (the fallback for ``q_sent``).

    Outputs are the values *of a tick taken at the current time*: they are computed from the
    state (which holds the queue up to the previous tick) and the current inputs, like Drake's
    ``DiscreteDerivative``. A consumer that samples them at t_k (the smoother, the uplink's
    zero-order hold) therefore gets the tick-k values with no extra period of delay; between
    ticks they preview the next tick. With s = q_target(t_k) and q_s the sent command:

        h_k = collision_k  or  (h_{k−1} and not released_k)
        window_k = [b, s]            if not h_k
                 = [q_s, …, q_s]     if h_k   (SPEC §5.2 hold: queue and newest discarded)
        q_newest = window_k[L];  q_delayed = window_k[0];  b ← window_k[1:]

    A non-finite ``q_target`` is never queued: it is treated like a collision (hold).
    At t = 0 the queue holds ``initial_position_rad`` (the robot's pose), so the first L
    ticks send that pose: the robot starts at rest.
    """

    def __init__(self, config: DelayFifoConfig = DelayFifoConfig(), *, num_joints: int,
                 initial_position_rad=None):
        super().__init__()
        if not isinstance(num_joints, (int, np.integer)) or num_joints < 1:
            raise ValueError(f"num_joints = {num_joints!r} must be a positive integer")
        self._config = config
        self._num_joints = int(num_joints)
        self._lag = config.lag
        q0 = np.zeros(num_joints) if initial_position_rad is None else np.asarray(
            initial_position_rad, dtype=float)
        if q0.shape != (num_joints,):
            raise ValueError(
                f"initial_position_rad = {initial_position_rad!r} must have {num_joints} values"
            )
        for joint, value in enumerate(q0):
            if not np.isfinite(value):
                raise ValueError(f"initial_position_rad[{joint}] = {float(value)!r} must be finite")
        n, lag = self._num_joints, self._lag

        self._q_target_input = self.DeclareVectorInputPort("q_target", n)
        self._collision_input = self.DeclareVectorInputPort("collision_detected", 1)
        self._q_sent_input = self.DeclareVectorInputPort("q_sent", n)
        self._enable_input = self.DeclareVectorInputPort("enable", 1)

        self._queue_state = self.DeclareDiscreteState(np.tile(q0, lag))
        # [holding, clutch seen released during the hold]
        self._hold_state = self.DeclareDiscreteState(np.zeros(2))
        self._last_delayed_state = self.DeclareDiscreteState(q0.copy())
        self._tick_cache = self.DeclareCacheEntry(
            "tick", ValueProducer(allocate=lambda: AbstractValue.Make(object()),
                                  calc=lambda c, value: value.set_value(self._compute_tick(c))))
        self.DeclarePeriodicDiscreteUpdateEvent(config.period_s, 0.0, self._update_queue)
        # A forced update runs the same tick on demand (CalcForcedDiscreteVariableUpdate).
        self.DeclareForcedDiscreteUpdateEvent(self._update_queue)

        self._q_newest_output = self.DeclareVectorOutputPort(
            "q_newest", n, lambda c, out: out.SetFromVector(self._tick(c)[0][lag]))
        self._q_delayed_output = self.DeclareVectorOutputPort(
            "q_delayed", n, lambda c, out: out.SetFromVector(self._tick(c)[0][0]))
        self._window_output = self.DeclareVectorOutputPort(
            "window", (lag + 1) * n, lambda c, out: out.SetFromVector(self._tick(c)[0].ravel()))
        self._reset_output = self.DeclareVectorOutputPort(
            "reset", 1, lambda c, out: out.SetAtIndex(0, float(self._tick(c)[1])))
        self._holding_output = self.DeclareVectorOutputPort(
            "holding", 1, lambda c, out: out.SetAtIndex(0, float(self._tick(c)[1])))

    # -- accessors ------------------------------------------------------------------------

    @property
    def lag(self) -> int:
        """L, the delay in samples."""
        return self._lag

    @property
    def config(self) -> DelayFifoConfig:
        return self._config

    def get_q_target_input_port(self):
        return self._q_target_input

    def get_collision_detected_input_port(self):
        return self._collision_input

    def get_q_sent_input_port(self):
        return self._q_sent_input

    def get_enable_input_port(self):
        return self._enable_input

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

    # -- the tick -------------------------------------------------------------------------

    def _tick(self, context):
        """The tick at this time, computed once per context change (shared by every output
        port and the update)."""
        return self._tick_cache.Eval(context)

    def _compute_tick(self, context):
        """(window (L+1, J), hold flag, clutch-released flag) of a tick at this time."""
        n, lag = self._num_joints, self._lag
        queue = context.get_discrete_state(self._queue_state).get_value().reshape(lag, n)
        holding, clutch_released = context.get_discrete_state(self._hold_state).get_value()
        sample = self._q_target_input.Eval(context)
        collision = (
            self._collision_input.HasValue(context)
            and self._collision_input.Eval(context)[0] > 0.5
        )
        collision = collision or not np.all(np.isfinite(sample)) or sample.shape != (n,)
        enable = True
        if self._config.release == "clutch":
            if not self._enable_input.HasValue(context):
                raise RuntimeError(
                    "DelayFifo: release = 'clutch' needs the 'enable' input port connected"
                )
            enable = self._enable_input.Eval(context)[0] > 0.5
            clutch_released = clutch_released > 0.5 or (holding > 0.5 and not enable)
            released = clutch_released and enable
        else:
            released = True
            clutch_released = False
        hold = collision or (holding > 0.5 and not released)
        if hold:
            if self._q_sent_input.HasValue(context):
                q_sent = self._q_sent_input.Eval(context)
            else:
                q_sent = context.get_discrete_state(self._last_delayed_state).get_value()
            window = np.tile(q_sent, (lag + 1, 1))
        else:
            window = np.vstack([queue, sample[None, :]])
            clutch_released = False
        return window, hold, clutch_released

    def _update_queue(self, context, discrete_state):
        window, hold, clutch_released = self._tick(context)
        discrete_state.get_mutable_vector(self._queue_state).SetFromVector(
            window[1:].ravel())
        discrete_state.get_mutable_vector(self._hold_state).SetFromVector(
            [float(hold), float(clutch_released and hold)])
        discrete_state.get_mutable_vector(self._last_delayed_state).SetFromVector(window[0])
