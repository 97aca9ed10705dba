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


class HapticCommandReceiver(LeafSystem):
    r"""Samples the latest haptic message; disengages the clutch on silence or bad data.

    .. pydrake_system::

        name: HapticCommandReceiver
        input_ports:
        - lcm_message
        output_ports:
        - pose_desired
        - enable
        - message_rejected

    - ``lcm_message``: latest ``lcmt_teleop_haptic_command`` (LcmSubscriberSystem output).
    - ``pose_desired``: the last valid pose, (m,) (``initial_pose`` before any).
    - ``enable``: the message's clutch if the last message was valid and is at most
      ``timeout_s`` old, else 0, (1,).
    - ``message_rejected``: 1 if the newest message had the wrong number of axes or a
      non-finite value, (1,).
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
        self._pose_state = self.DeclareDiscreteState(pose0)
        # [enable of last valid message, time it arrived, last seen utime, rejected]
        self._status_state = self.DeclareDiscreteState([0.0, -np.inf, -1.0, 0.0])
        self.DeclarePeriodicDiscreteUpdateEvent(config.period_s, 0.0, self._update_pose)
        self.DeclareForcedDiscreteUpdateEvent(self._update_pose)
        self._pose_output = self.DeclareStateOutputPort("pose_desired", self._pose_state)
        self._enable_output = self.DeclareVectorOutputPort("enable", 1, self._calc_enable)
        self._rejected_output = self.DeclareVectorOutputPort(
            "message_rejected", 1,
            lambda c, o: o.SetAtIndex(0, c.get_discrete_state(self._status_state).get_value()[3]))

    def get_lcm_message_input_port(self):
        return self._message_input

    def get_pose_desired_output_port(self):
        return self._pose_output

    def get_enable_output_port(self):
        return self._enable_output

    def get_message_rejected_output_port(self):
        return self._rejected_output

    def _calc_enable(self, context, output):
        enable, arrived, _, rejected = context.get_discrete_state(self._status_state).get_value()
        fresh = context.get_time() - arrived <= self._config.timeout_s
        output.SetAtIndex(0, 1.0 if (enable > 0.5 and fresh and rejected < 0.5) else 0.0)

    def _update_pose(self, context, discrete_state):
        enable, arrived, last_utime, rejected = \
            context.get_discrete_state(self._status_state).get_value()
        msg = self._message_input.Eval(context)
        is_new = msg.num_axes > 0 and msg.utime != last_utime
        if is_new:
            last_utime = float(msg.utime)
            pose = np.asarray(msg.pose_desired, dtype=float)
            if msg.num_axes == self._m and pose.shape == (self._m,) and np.all(np.isfinite(pose)):
                discrete_state.get_mutable_vector(self._pose_state).SetFromVector(pose)
                enable, arrived, rejected = float(bool(msg.enable)), context.get_time(), 0.0
            else:
                enable, rejected = 0.0, 1.0
        discrete_state.get_mutable_vector(self._status_state).SetFromVector(
            [enable, arrived, last_utime, rejected])
