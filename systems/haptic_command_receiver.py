"""A live haptic device over LCM: ``lcmt_teleop_haptic_command`` → pose and clutch, or hold.

Stand-in for :class:`~telesmooth.systems.haptic_source.HapticSource` when a real device
driver publishes on ``TELEOP_HAPTIC_COMMAND``. Until the first valid message, after a bad
one, and when messages stop, the clutch output is 0: the inverse kinematics then holds its
target, so a silent or broken device can never move the arm.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from telesmooth.lcm_types import lcmt_teleop_haptic_command
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


# Layout of the status state (a float64 vector; the utime is kept exactly as two halves).
_ENABLE, _ARRIVED, _HAVE_MESSAGE, _UTIME_HIGH, _UTIME_LOW, _REJECTED, _STOP = range(7)


def _split_utime(utime) -> tuple[float, float]:
    """An int64 as (signed high 32 bits, unsigned low 32 bits), both exact in a float64."""
    value = int(utime)
    return float(value >> 32), float(value & 0xFFFF_FFFF)


def _join_utime(high: float, low: float) -> int:
    """The int64 that :func:`_split_utime` split."""
    return (int(high) << 32) | int(low)


def _is_default_message(msg) -> bool:
    """True for the default-constructed message a subscriber outputs before any arrives."""
    return (msg.utime == 0 and msg.seq == 0 and msg.num_axes == 0
            and len(msg.pose_desired) == 0 and not msg.enable)


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
        self._m = pose0.size
        self._message_input = self.DeclareAbstractInputPort(
            "lcm_message", AbstractValue.Make(lcmt_teleop_haptic_command()))
        self._undecodable_input = self.DeclareVectorInputPort("message_undecodable", 1)
        self._pose_state = self.DeclareDiscreteState(pose0)
        # [enable of last valid message, time it arrived, a message was examined (0/1),
        #  high and low 32 bits of its utime, rejected]; see the _ENABLE... indices.
        self._status_state = self.DeclareDiscreteState([0.0, -np.inf, 0.0, 0.0, 0.0, 0.0, 0.0])
        self.DeclarePeriodicDiscreteUpdateEvent(config.period_s, 0.0, self._update_pose)
        self.DeclareForcedDiscreteUpdateEvent(self._update_pose)
        self._pose_output = self.DeclareStateOutputPort("pose_desired", self._pose_state)
        self._enable_output = self.DeclareVectorOutputPort("enable", 1, self._calc_enable)
        self._rejected_output = self.DeclareVectorOutputPort(
            "message_rejected", 1,
            lambda c, o: o.SetAtIndex(0, self._status(c)[_REJECTED]))
        self._stop_output = self.DeclareVectorOutputPort(
            "stop_requested", 1, self._calc_stop)

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

    def _status(self, context):
        return context.get_discrete_state(self._status_state).get_value()

    def _calc_enable(self, context, output):
        output.SetAtIndex(0, 1.0 if self._fresh_flag(context, _ENABLE) else 0.0)

    def _calc_stop(self, context, output):
        output.SetAtIndex(0, 1.0 if self._fresh_flag(context, _STOP) else 0.0)

    def _fresh_flag(self, context, index) -> bool:
        """The flag ``index`` of the last valid message, while it is fresh and not rejected."""
        status = self._status(context)
        fresh = context.get_time() - status[_ARRIVED] <= self._config.timeout_s
        return bool(status[index] > 0.5 and fresh and status[_REJECTED] < 0.5)

    def _update_pose(self, context, discrete_state):
        status = np.array(self._status(context))
        msg = self._message_input.Eval(context)
        if status[_HAVE_MESSAGE] > 0.5:
            is_new = int(msg.utime) != _join_utime(status[_UTIME_HIGH], status[_UTIME_LOW])
        else:
            is_new = not _is_default_message(msg)
        if is_new:
            status[_HAVE_MESSAGE] = 1.0
            status[_UTIME_HIGH], status[_UTIME_LOW] = _split_utime(msg.utime)
            pose = np.asarray(msg.pose_desired, dtype=float)
            if msg.num_axes == self._m and pose.shape == (self._m,) and np.all(np.isfinite(pose)):
                discrete_state.get_mutable_vector(self._pose_state).SetFromVector(pose)
                status[_ENABLE], status[_ARRIVED] = float(bool(msg.enable)), context.get_time()
                status[_STOP] = float(bool(msg.stop))
                status[_REJECTED] = 0.0
            else:
                status[_ENABLE], status[_STOP], status[_REJECTED] = 0.0, 0.0, 1.0
        undecodable = self._undecodable_input
        if undecodable.HasValue(context) and undecodable.Eval(context)[0] > 0.5:
            status[_ENABLE], status[_STOP], status[_REJECTED] = 0.0, 0.0, 1.0
        discrete_state.get_mutable_vector(self._status_state).SetFromVector(status)
