"""The ground's safety delay as a pure step: the FIFO's collision hold, clutch release and stop.

The 0.75 s FIFO (:class:`~telesmooth.systems.delay_fifo.DelayFifo`, the thin Drake system
around this module) queues the 4 Hz joint-target samples for L periods. Its safety logic lives
here, as pure functions over immutable parameters and states, beside the stop planner it plays
(:func:`~telesmooth.safety.stop.plan_stop`):

* :func:`fifo_step` ``(params, state, inputs) -> (state, outputs)``: one tick. Without a
  collision the sample is queued and the oldest leaves; on a collision (or the operator's stop,
  or a non-finite sample) the queue is refilled with the sent command (policy "hold", the
  paper's §5.2) or with the jerk-limited stop planned before the tick and then the sent rest
  pose (policy "stop"). The hold ends when the collision clears (``release =
  "collision-clear"``), or only after the operator released and re-engaged the clutch
  (``"clutch"``), and never before a stop is at rest.
* :func:`fifo_plan_contingency` ``(params, state, q_sent) -> state``: between ticks, the stop a
  collision at the next tick would play, planned from the sent history it will have then (so
  no plan is ever made at the tick itself).

The tick's equations are in :class:`~telesmooth.systems.delay_fifo.DelayFifo`'s docstring.
A state is a :class:`FifoState` (NamedTuple of arrays, flags and an enum), stored in a Drake
Context as one vector by :class:`~telesmooth.safety.state_codec.VectorCodec`.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from telesmooth.safety.limiter import HISTORY_LENGTH
from telesmooth.safety.stop import StopOutcome, StopParams, plan_stop

__all__ = ["Contingency", "FifoInputs", "FifoOutputs", "FifoParams", "FifoState",
           "fifo_initial_state", "fifo_plan_contingency", "fifo_step"]


@dataclasses.dataclass(frozen=True, eq=False)
class FifoParams:
    """The FIFO's immutable settings.

    Attributes:
        num_joints: J.
        lag: L, the delay in samples (≥ 0).
        release: ``"collision-clear"`` or ``"clutch"`` (see the module docstring).
        stop: The stop planner's parameters with ``on_collision = "stop"``; None: the hold.
        max_stop_ticks: The longest stop, in ticks (0 without ``stop``).
    """

    num_joints: int
    lag: int
    release: str = "collision-clear"
    stop: StopParams | None = None
    max_stop_ticks: int = 0


class Contingency(NamedTuple):
    """The stop the FIFO would play if a collision came at the next tick, planned between
    ticks from the sent history it will have then."""

    history: np.ndarray           # (3, J) [p_{k−3}, p_{k−2}, p_{k−1}] it was planned from
    outcome: StopOutcome
    length: int                   # N, the planned commands (1 for a hold fallback)
    commands: np.ndarray          # (max_stop_ticks, J), the first N rows used
    braking_distance: np.ndarray  # (J,)


class FifoState(NamedTuple):
    """The FIFO between ticks (the stop fields are empty or unused with the hold policy)."""

    queue: np.ndarray             # (L, J) b = [z_{k−L}, …, z_{k−1}], oldest first
    holding: bool                 # a collision hold (or stop) is in force
    clutch_released: bool         # the clutch was seen released during the hold
    last_delayed: np.ndarray      # (J,) the last q_delayed: q_sent when that is unconnected
    sent_history: np.ndarray      # (2, J) [p_{k−3}, p_{k−2}] of the sent commands
    stop_plan: np.ndarray         # (max_stop_ticks, J) the stop being played
    stop_outcome: StopOutcome     # of the last collision
    stop_length: int              # N of the stop being played
    stop_index: int               # its next command
    braking_distance: np.ndarray  # (J,) of the last collision's stop
    contingency: Contingency


class FifoInputs(NamedTuple):
    """One tick's inputs."""

    sample: np.ndarray            # (J,) q_target at the tick
    collision: bool               # the pre-simulator's flag or the operator's stop
    enable: bool                  # the operator's clutch (read with release = "clutch")
    q_sent: np.ndarray | None     # (J,) the command sent last; None: the state's last_delayed


class FifoOutputs(NamedTuple):
    """One tick's values."""

    window: np.ndarray            # (L+1, J) [z_{k−L}, …, z_k], oldest first
    hold: bool                    # a collision hold (or stop) is in force at this tick
    braking_distance: np.ndarray  # (J,) zeros with the hold policy
    stop_outcome: StopOutcome     # of the last collision (NONE with the hold policy)
    unplanned: bool               # a collision found no stop planned for its history: hold


def plan_contingency(params: FifoParams, history) -> Contingency:
    """The stop from ``history`` (3, J), in the form the state keeps."""
    plan = plan_stop(params.stop, history, max_ticks=params.max_stop_ticks)
    commands = np.zeros((params.max_stop_ticks, params.num_joints))
    commands[:plan.ticks_to_rest] = plan.commands
    return Contingency(history=np.array(history, dtype=float), outcome=plan.outcome,
                       length=plan.ticks_to_rest, commands=commands,
                       braking_distance=np.array(plan.braking_distance, dtype=float))


def fifo_initial_state(params: FifoParams, initial_position) -> FifoState:
    """At rest at ``initial_position`` (J,): the queue full of it, no hold; with the stop
    policy the contingency is the stop from rest there."""
    n, lag = params.num_joints, params.lag
    q0 = np.array(initial_position, dtype=float)
    if params.stop is not None:
        contingency = plan_contingency(params, np.tile(q0, (HISTORY_LENGTH, 1)))
    else:
        contingency = Contingency(np.zeros((HISTORY_LENGTH, n)), StopOutcome.NONE, 0,
                                  np.zeros((0, n)), np.zeros(n))
    return FifoState(queue=np.tile(q0, (lag, 1)), holding=False, clutch_released=False,
                     last_delayed=q0.copy(),
                     sent_history=np.tile(q0, (HISTORY_LENGTH - 1, 1)),
                     stop_plan=np.zeros((params.max_stop_ticks, n)),
                     stop_outcome=StopOutcome.NONE, stop_length=0, stop_index=0,
                     braking_distance=np.zeros(n), contingency=contingency)


def _sent(state: FifoState, inputs_q_sent) -> np.ndarray:
    if inputs_q_sent is None:
        return state.last_delayed
    return np.asarray(inputs_q_sent, dtype=float)


def fifo_step(params: FifoParams, state: FifoState,
              inputs: FifoInputs) -> tuple[FifoState, FifoOutputs]:
    """One tick (module docstring): the state after it and the tick's values."""
    n, lag = params.num_joints, params.lag
    sample = np.asarray(inputs.sample, dtype=float)
    collision = (bool(inputs.collision) or sample.shape != (n,)
                 or not np.all(np.isfinite(sample)))
    holding = state.holding
    if params.release == "clutch":
        clutch_released = state.clutch_released or (holding and not inputs.enable)
        released = clutch_released and bool(inputs.enable)
    else:
        clutch_released, released = False, True
    q_sent = _sent(state, inputs.q_sent)
    plan, outcome, length = state.stop_plan, state.stop_outcome, state.stop_length
    next_index, distance, unplanned = state.stop_index, state.braking_distance, False
    history = None
    if params.stop is not None:
        history = np.vstack([state.sent_history, q_sent[None, :]])  # p_{k−3}, p_{k−2}, p_{k−1}
        if collision and not holding:
            contingency = state.contingency
            if np.array_equal(contingency.history, history):
                plan, length = contingency.commands, contingency.length
                outcome, distance = contingency.outcome, contingency.braking_distance
            else:
                plan, length = np.tile(q_sent, (params.max_stop_ticks, 1)), 1
                outcome, distance, unplanned = StopOutcome.HOLD, np.zeros(n), True
            next_index = 0
    stopping = next_index < length
    hold = collision or (holding and (not released or (params.stop is not None and stopping)))
    command = q_sent
    if params.stop is not None and hold and stopping:
        command = plan[next_index]
        next_index += 1
    if hold:
        window = np.tile(command, (lag + 1, 1))
    else:
        window = np.vstack([state.queue, sample[None, :]])
    new_state = state._replace(
        queue=window[1:], holding=hold, clutch_released=clutch_released and hold,
        last_delayed=window[0])
    if params.stop is not None:
        new_state = new_state._replace(
            sent_history=history[1:], stop_plan=plan, stop_outcome=outcome,
            stop_length=int(length), stop_index=int(next_index),
            braking_distance=np.array(distance, dtype=float))
    outputs = FifoOutputs(window=window, hold=hold,
                          braking_distance=np.array(new_state.braking_distance, dtype=float),
                          stop_outcome=new_state.stop_outcome, unplanned=unplanned)
    return new_state, outputs


def fifo_plan_contingency(params: FifoParams, state: FifoState, q_sent) -> FifoState:
    """Between ticks: ``state`` with the stop a collision at the next tick would play,
    planned from [p_{k−2}, p_{k−1}, ``q_sent``]; ``state`` itself (the same object) while
    holding, without the stop policy, or when that history is the one already planned from."""
    if params.stop is None or state.holding:
        return state
    history = np.vstack([state.sent_history, _sent(state, q_sent)[None, :]])
    if np.array_equal(state.contingency.history, history):
        return state
    return state._replace(contingency=plan_contingency(params, history))
