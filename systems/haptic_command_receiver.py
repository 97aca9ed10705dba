"""A live haptic device over LCM: ``lcmt_teleop_haptic_command`` → pose and clutch, or hold.

Stand-in for :class:`~telesmooth.systems.haptic_source.HapticSource` when a real device
driver publishes on ``TELEOP_HAPTIC_COMMAND``. Until the first valid message, after a bad
one, and when messages stop, the clutch output is 0: the inverse kinematics then holds its
target, so a silent or broken device can never move the arm. A thin Drake system around the
pure step :func:`telesmooth.link.haptic.haptic_step`, whose state lives in the Context as one
vector.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from telesmooth.lcm_types import lcmt_teleop_haptic_command
from telesmooth.link.haptic import (
    HapticInputs,
    HapticState,
    haptic_flags,
    haptic_initial_state,
    haptic_step,
)
from telesmooth.systems.codec_state import CodecState
from telesmooth.systems.timing import check_period

__all__ = ["HapticCommandReceiver", "HapticCommandReceiverConfig"]


@dataclasses.dataclass(frozen=True)
class HapticCommandReceiverConfig:
    """Settings of the live haptic receiver.

    Attributes:
        period_s: Sampling period of the received stream, s (100 Hz device).
        timeout_s: Silence after which the clutch is forced off, s.
    """

    period_s: float = 0.01
    timeout_s: float = 0.1

    def __post_init__(self) -> None:
        check_period("HapticCommandReceiverConfig.period_s", self.period_s)
        check_period("HapticCommandReceiverConfig.timeout_s", self.timeout_s)


class HapticCommandReceiver(LeafSystem):
    r"""Samples the latest haptic message; disengages the clutch on silence or bad data.

    .. pydrake_system::

        name: HapticCommandReceiver
        input_ports:
        - lcm_message
        - message_undecodable (optional)
        output_ports:
        - pose_desired
        - enable
        - message_rejected
        - stop_requested

    - ``lcm_message``: latest ``lcmt_teleop_haptic_command`` (the subscriber's output; a
      default-constructed message before anything arrives).
    - ``message_undecodable``: optional, (1,): 1 while the newest packet on the channel could
      not be decoded (:class:`~telesmooth.systems.lcm_safe_subscriber.LcmSafeSubscriber`);
      unconnected means 0.
    - ``pose_desired``: the last valid pose, (m,) (``initial_pose`` before any).
    - ``enable``: the message's clutch if the last message was valid and is at most
      ``timeout_s`` old, else 0, (1,).
    - ``message_rejected``: 1 if the newest message had the wrong number of axes (including
      none: ``num_axes`` <= 0), a non-finite value, or could not be decoded, (1,).
    - ``stop_requested``: the operator's stop (the message's ``stop``) of the last valid
      message while it is at most ``timeout_s`` old, else 0, (1,) (a device that falls
      silent releases the clutch, it does not stop: the robot drains the FIFO to the
      held target).

    Update every ``period_s``: a message is new when it differs in ``utime`` from the last one
    examined (any int64 utime, compared exactly); before any message has been examined, every
    message except the default-constructed one (utime 0, seq 0, no axes, clutch off: what the
    subscriber outputs while nothing has arrived) is new, whatever its utime. A new message
    with ``num_axes`` = m, m pose values and all of them finite becomes the pose and its
    clutch; any other new message is rejected (clutch off, pose held). Then, if the newest
    packet was undecodable, the message is flagged rejected too (the pose holds).
    """

    def __init__(self, config: HapticCommandReceiverConfig = HapticCommandReceiverConfig(), *,
                 initial_pose):
        super().__init__()
        pose0 = np.asarray(initial_pose, dtype=float)
        if pose0.ndim != 1 or pose0.size == 0 or not np.all(np.isfinite(pose0)):
            raise ValueError(f"initial_pose = {initial_pose!r} must be a finite, non-empty vector")
        self._config = config
        self._message_input = self.DeclareAbstractInputPort(
            "lcm_message", AbstractValue.Make(lcmt_teleop_haptic_command()))
        self._undecodable_input = self.DeclareVectorInputPort("message_undecodable", 1)
        self._state = CodecState(self, haptic_initial_state(pose0))
        self.DeclarePeriodicDiscreteUpdateEvent(config.period_s, 0.0, self._update_pose)
        self.DeclareForcedDiscreteUpdateEvent(self._update_pose)
        self._pose_output = self._state.output("pose_desired", "pose")
        self._enable_output = self.DeclareVectorOutputPort(
            "enable", 1, lambda c, o: o.SetAtIndex(0, float(self._flags(c)[0])))
        self._rejected_output = self._state.output("message_rejected", "rejected")
        self._stop_output = self.DeclareVectorOutputPort(
            "stop_requested", 1, lambda c, o: o.SetAtIndex(0, float(self._flags(c)[1])))

    def get_lcm_message_input_port(self):
        return self._message_input

    def get_message_undecodable_input_port(self):
        return self._undecodable_input

    def get_pose_desired_output_port(self):
        return self._pose_output

    def get_enable_output_port(self):
        return self._enable_output

    def get_message_rejected_output_port(self):
        return self._rejected_output

    def get_stop_requested_output_port(self):
        return self._stop_output

    def haptic_state(self, context) -> HapticState:
        """The stream, as :func:`~telesmooth.link.haptic.haptic_step` left it."""
        return self._state.get(context)

    def _flags(self, context) -> tuple[bool, bool]:
        return haptic_flags(self.haptic_state(context), context.get_time(),
                            self._config.timeout_s)

    def _update_pose(self, context, discrete_state):
        undecodable = self._undecodable_input
        inputs = HapticInputs(
            now=context.get_time(), message=self._message_input.Eval(context),
            undecodable=bool(undecodable.HasValue(context)
                             and undecodable.Eval(context)[0] > 0.5))
        before = self.haptic_state(context)
        after = haptic_step(before, inputs)
        if after is not before:      # an old message examined again changes nothing
            self._state.store(discrete_state, after)
