"""Onboard side of the uplink: accepts ``lcmt_teleop_joint_command`` packets, or holds.

Every packet is checked before it can move the robot: sequence newer than the last accepted,
the same joints in the same order, finite positions inside the joint limits. Anything else
is rejected and the robot keeps the last accepted command (and says so on a flag). When
packets stop arriving the command simply holds and a timeout flag is raised.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from telesmooth.lcm_types import lcmt_teleop_joint_command
from telesmooth.systems.timing import check_period

__all__ = ["JointCommandReceiver", "JointCommandReceiverConfig", "check_joint_command"]


@dataclasses.dataclass(frozen=True)
class JointCommandReceiverConfig:
    """Settings of the onboard command receiver.

    Attributes:
        poll_period_s: How often the latest received message is examined, s.
        timeout_s: Silence after which ``command_timeout`` is raised, s (4 missed packets
            at 4 Hz by default). The robot holds either way.
    """

    poll_period_s: float = 0.01
    timeout_s: float = 1.0

    def __post_init__(self) -> None:
        check_period("JointCommandReceiverConfig.poll_period_s", self.poll_period_s)
        check_period("JointCommandReceiverConfig.timeout_s", self.timeout_s)


def check_joint_command(msg, *, joint_names, lower_rad, upper_rad) -> str | None:
    """Why ``msg`` must not move the robot (a message naming field, joint and value), or None."""
    n = len(joint_names)
    if msg.num_joints != n or len(msg.joint_position_smoothed) != n:
        return f"num_joints = {msg.num_joints} but the robot has {n} joints"
    if tuple(msg.joint_name) != tuple(joint_names):
        return f"joint_name = {list(msg.joint_name)!r} differs from the robot's {list(joint_names)!r}"
    for name, value, lo, hi in zip(joint_names, msg.joint_position_smoothed, lower_rad,
                                   upper_rad):
        if not np.isfinite(value):
            return f"joint_position_smoothed[{name!r}] = {value!r} is not finite"
        if not lo <= value <= hi:
            return (f"joint_position_smoothed[{name!r}] = {value!r} rad is outside the limits "
                    f"[{lo!r}, {hi!r}]")
    return None


class JointCommandReceiver(LeafSystem):
    r"""Validated, held joint command from the LCM uplink.

    .. pydrake_system::

        name: JointCommandReceiver
        input_ports:
        - lcm_message
        - message_undecodable (optional)
        output_ports:
        - q_commanded
        - last_command_seq
        - command_rejected
        - command_timeout

    - ``lcm_message``: the latest ``lcmt_teleop_joint_command`` (the subscriber's output); a
      default message (seq 0, no joints) before anything arrives.
    - ``message_undecodable``: optional, (1,): 1 while the newest packet on the channel could
      not be decoded (:class:`~telesmooth.systems.lcm_safe_subscriber.LcmSafeSubscriber`);
      unconnected means 0.
    - ``q_commanded``: the last accepted joint positions, rad, (J,); ``initial_position_rad``
      until the first accepted packet.
    - ``last_command_seq``: its sequence number, (1,); −1 before the first.
    - ``command_rejected``: 1 if the newest packet was rejected (see
      :func:`check_joint_command`) or could not be decoded, until a packet is accepted, (1,).
    - ``command_timeout``: 1 while no packet was accepted for more than ``timeout_s``,
      counted from t = 0 before the first, (1,).

    Update every ``poll_period_s``: a message with seq > last accepted and a non-empty joint
    list is examined once; if valid it becomes the command, otherwise the rejected flag is
    raised and the command holds. Stale or repeated packets (seq ≤ last) are ignored. Then,
    if the newest packet was undecodable, the rejected flag is raised (the command holds; a
    valid message that arrived before it has still been accepted).
    """

    def __init__(self, config: JointCommandReceiverConfig = JointCommandReceiverConfig(), *,
                 joint_names, lower_rad, upper_rad, initial_position_rad):
        super().__init__()
        self._joint_names = tuple(str(name) for name in joint_names)
        n = len(self._joint_names)
        self._lower = np.asarray(lower_rad, dtype=float)
        self._upper = np.asarray(upper_rad, dtype=float)
        q0 = np.asarray(initial_position_rad, dtype=float)
        for field, array in (("lower_rad", self._lower), ("upper_rad", self._upper),
                             ("initial_position_rad", q0)):
            if array.shape != (n,):
                raise ValueError(f"{field} = {array.tolist()!r} must have {n} values")
        for name, value, lo, hi in zip(self._joint_names, q0, self._lower, self._upper):
            if not (np.isfinite(value) and lo <= value <= hi):
                raise ValueError(
                    f"initial_position_rad[{name!r}] = {float(value)!r} must be finite and "
                    f"within [{lo!r}, {hi!r}]")
        self._config = config
        self._message_input = self.DeclareAbstractInputPort(
            "lcm_message", AbstractValue.Make(lcmt_teleop_joint_command()))
        self._undecodable_input = self.DeclareVectorInputPort("message_undecodable", 1)
        self._command_state = self.DeclareDiscreteState(q0)
        # [last accepted seq, time of last accepted packet (or 0), rejected, timeout,
        #  last examined seq]
        self._status_state = self.DeclareDiscreteState([-1.0, 0.0, 0.0, 0.0, -1.0])
        self.DeclarePeriodicDiscreteUpdateEvent(config.poll_period_s, 0.0, self._update_command)
        self.DeclareForcedDiscreteUpdateEvent(self._update_command)
        self._q_output = self.DeclareStateOutputPort("q_commanded", self._command_state)
        self._seq_output = self.DeclareVectorOutputPort(
            "last_command_seq", 1, lambda c, o: o.SetAtIndex(0, self._status(c)[0]))
        self._rejected_output = self.DeclareVectorOutputPort(
            "command_rejected", 1, lambda c, o: o.SetAtIndex(0, self._status(c)[2]))
        self._timeout_output = self.DeclareVectorOutputPort(
            "command_timeout", 1, lambda c, o: o.SetAtIndex(0, self._status(c)[3]))

    def get_lcm_message_input_port(self):
        return self._message_input

    def get_message_undecodable_input_port(self):
        return self._undecodable_input

    def get_q_commanded_output_port(self):
        return self._q_output

    def get_last_command_seq_output_port(self):
        return self._seq_output

    def get_command_rejected_output_port(self):
        return self._rejected_output

    def get_command_timeout_output_port(self):
        return self._timeout_output

    def _status(self, context):
        return context.get_discrete_state(self._status_state).get_value()

    def _update_command(self, context, discrete_state):
        last_seq, last_time, rejected, _, examined = self._status(context)
        msg = self._message_input.Eval(context)
        now = context.get_time()
        if msg.num_joints > 0 and msg.seq > last_seq and msg.seq != examined:
            examined = float(msg.seq)
            problem = check_joint_command(msg, joint_names=self._joint_names,
                                          lower_rad=self._lower, upper_rad=self._upper)
            if problem is None:
                discrete_state.get_mutable_vector(self._command_state).SetFromVector(
                    np.asarray(msg.joint_position_smoothed, dtype=float))
                last_seq, last_time, rejected = float(msg.seq), now, 0.0
            else:
                rejected = 1.0
        undecodable = self._undecodable_input
        if undecodable.HasValue(context) and undecodable.Eval(context)[0] > 0.5:
            rejected = 1.0
        timeout = 1.0 if now - last_time > self._config.timeout_s else 0.0
        discrete_state.get_mutable_vector(self._status_state).SetFromVector(
            [last_seq, last_time, rejected, timeout, examined])
