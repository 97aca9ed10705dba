"""Onboard side of the uplink: accepts ``lcmt_teleop_joint_command`` packets, or holds.

A thin Drake system around the pure receiver :func:`telesmooth.link.receiver.receiver_step`
(whose docstring gives the checks every packet passes before it can move the robot: it
decodes, is authentic, is fresh, and names the robot's joints within their limits). Anything
not accepted is counted by class (:class:`~telesmooth.link.receiver.PacketClass`) and logged
with its reason, and the robot keeps the last accepted command. When packets stop arriving
the command holds and ``command_timeout`` is raised (the onboard
:class:`~telesmooth.systems.link_guard.LinkGuard` turns that silence into a jerk-limited
ramp-down).
"""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from telesmooth.arms.joint_vectors import check_joint_vector
from telesmooth.lcm_types import lcmt_teleop_joint_command
from telesmooth.link.auth import check_key
from telesmooth.link.receiver import (
    FLAGGED,
    PACKET_CLASSES,
    REJECTION_CLASSES,
    PacketClass,
    ReceiverInputs,
    ReceiverParams,
    ReceiverState,
    check_joint_command,
    classify_joint_command,
    receiver_initial_state,
    receiver_step,
)
from telesmooth.link.session import EPOCH_BITS
from telesmooth.systems.codec_state import CodecState
from telesmooth.systems.timing import check_period

__all__ = [
    "AUTHENTICATION_MODES",
    "PACKET_CLASSES",
    "REJECTION_CLASSES",
    "JointCommandReceiver",
    "JointCommandReceiverConfig",
    "PacketClass",
    "check_joint_command",
    "classify_joint_command",
]

AUTHENTICATION_MODES = ("off", "required")
"""``JointCommandReceiverConfig.authentication``: ``"off"`` only for in-process simulation."""

_logger = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class JointCommandReceiverConfig:
    """Settings of the onboard command receiver.

    Attributes:
        poll_period_s: How often the received packets are examined, s.
        timeout_s: Silence after which ``command_timeout`` is raised, s (4 missed packets
            at 4 Hz by default). The robot holds either way.
        authentication: ``"required"``: only packets with a valid HMAC tag (the uplink key)
            are accepted; ``"off"``: tags are not checked (in-process simulation only; the
            ground and onboard processes require a key).
    """

    poll_period_s: float = 0.01
    timeout_s: float = 1.0
    authentication: str = "off"

    def __post_init__(self) -> None:
        check_period("JointCommandReceiverConfig.poll_period_s", self.poll_period_s)
        check_period("JointCommandReceiverConfig.timeout_s", self.timeout_s)
        if self.authentication not in AUTHENTICATION_MODES:
            raise ValueError(
                f"JointCommandReceiverConfig.authentication = {self.authentication!r} must be "
                f"one of {AUTHENTICATION_MODES}")


class JointCommandReceiver(LeafSystem):
    r"""Validated, held joint command from the LCM uplink.

    .. pydrake_system::

        name: JointCommandReceiver
        input_ports:
        - lcm_message (optional)
        - message_undecodable (optional)
        - packets (optional)
        output_ports:
        - q_commanded
        - last_command_seq
        - last_command_session
        - command_rejected
        - command_timeout
        - accepted_count
        - rejection_counts
        - last_rejection

    Inputs (connect ``packets``, or ``lcm_message`` and optionally ``message_undecodable``):

    - ``packets``: every raw packet received so far, newest last, as a tuple of
      (arrival index, bytes) pairs (the ``packets`` output of
      :class:`~telesmooth.systems.lcm_safe_subscriber.LcmSafeSubscriber` or of the in-process
      :class:`~telesmooth.systems.link_channel.LinkChannel`; at least the packets since the
      previous poll). Each packet with a larger index than the last examined one is examined
      once, in arrival order, so every duplicate, replay and forgery is counted.
    - ``lcm_message``: the latest decoded message (Drake's ``LcmSubscriberSystem`` output),
      used when ``packets`` is unconnected. Only the newest packet is visible, so a message
      is examined once, when its (session_id, seq) is newer than the last accepted one and
      differs from the last examined one; stale and duplicate packets are then ignored
      without being counted (connect ``packets`` to count them). The default message (what
      a subscriber holds before anything arrives) is not a packet.
    - ``message_undecodable``: with ``lcm_message``, 1 while the newest packet on the channel
      could not be decoded; unconnected means 0.

    Outputs:

    - ``q_commanded``: the last accepted joint positions, rad, (J,); ``initial_position_rad``
      until the first accepted packet.
    - ``last_command_seq``, ``last_command_session``: its seq (−1 before the first) and
      session_id (0 before the first), (1,) each.
    - ``command_rejected``: 1 if the newest examined packet was invalid, forged/unsigned,
      undecodable or of another onboard run or session, until a packet is accepted, (1,).
    - ``command_timeout``: 1 while no packet was accepted for more than ``timeout_s``,
      counted from t = 0 before the first, (1,).
    - ``accepted_count``: packets accepted so far, (1,) (the link guard's trigger).
    - ``rejection_counts``: packets not accepted so far, per class of
      :data:`REJECTION_CLASSES` (invalid, auth, duplicate, stale, undecodable, session),
      (6,).
    - ``last_rejection``: abstract str, "<class>: <reason>" of the newest packet not accepted
      ("" before any).

    Update every ``poll_period_s`` (and at initialization): the new packets are examined
    (:func:`classify_joint_command`); each accepted one becomes the command in turn (the newest
    accepted one wins the poll). Then the timeout flag is recomputed.
    """

    def __init__(self, config: JointCommandReceiverConfig = JointCommandReceiverConfig(), *,
                 joint_names, lower_rad, upper_rad, initial_position_rad,
                 uplink_key: bytes | None = None, onboard_epoch: int = 0):
        """Args:
            config: Poll period, timeout and the authentication mode.
            joint_names, lower_rad, upper_rad: The robot's joints and limits, rad.
            initial_position_rad: What the robot holds before the first command, rad.
            uplink_key: The shared HMAC key (:func:`telesmooth.link.auth.load_key`); required
                when ``config.authentication == "required"``, unused otherwise.
            onboard_epoch: This onboard run's epoch
                (:func:`telesmooth.link.session.new_epoch`; 0 in process): only commands that
                carry it are accepted.

        Raises:
            ValueError: naming the field (and joint and value) of a bad argument.
        """
        super().__init__()
        self._joint_names = tuple(str(name) for name in joint_names)
        self._lower = check_joint_vector("lower_rad", lower_rad, self._joint_names)
        self._upper = check_joint_vector("upper_rad", upper_rad, self._joint_names)
        q0 = check_joint_vector("initial_position_rad", initial_position_rad,
                                self._joint_names, lower=self._lower, upper=self._upper)
        if config.authentication == "required":
            if uplink_key is None:
                raise ValueError(
                    "uplink_key = None but command_receiver.authentication = 'required': "
                    "load the shared key (telesmooth.link.auth.load_key)")
            uplink_key = check_key(uplink_key, field="uplink_key")
        self._key = uplink_key if config.authentication == "required" else None
        if isinstance(onboard_epoch, bool) or not isinstance(onboard_epoch, (int, np.integer)) \
                or not 0 <= onboard_epoch < 2**EPOCH_BITS:
            raise ValueError(f"onboard_epoch = {onboard_epoch!r} must be an integer in "
                             f"[0, 2^{EPOCH_BITS})")
        self._epoch = int(onboard_epoch)
        self._config = config
        self._message_input = self.DeclareAbstractInputPort(
            "lcm_message", AbstractValue.Make(lcmt_teleop_joint_command()))
        self._undecodable_input = self.DeclareVectorInputPort("message_undecodable", 1)
        self._packets_input = self.DeclareAbstractInputPort("packets", AbstractValue.Make(()))
        self._params = ReceiverParams(joint_names=self._joint_names, lower_rad=self._lower,
                                      upper_rad=self._upper, key=self._key,
                                      onboard_epoch=self._epoch, timeout_s=config.timeout_s)
        initial = receiver_initial_state(q0)
        self._state = CodecState(self, initial)
        self._rejection_state = self.DeclareAbstractState(AbstractValue.Make(""))
        self.DeclarePeriodicUnrestrictedUpdateEvent(config.poll_period_s, 0.0,
                                                    self._update_command)
        self.DeclareInitializationUnrestrictedUpdateEvent(self._update_command)
        self.DeclareForcedUnrestrictedUpdateEvent(self._update_command)

        self._q_output = self._state.output("q_commanded", "command")
        self._seq_output = self._state.output("last_command_seq", "last_seq")
        self._session_output = self._state.output("last_command_session", "last_session")
        self._rejected_output = self._state.output("command_rejected", "rejected")
        self._timeout_output = self._state.output("command_timeout", "timeout")
        self._accepted_output = self._state.output("accepted_count", "accepted")
        self._counts_output = self._state.output("rejection_counts", "counts")
        self._last_rejection_output = self.DeclareStateOutputPort(
            "last_rejection", self._rejection_state)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._joint_names

    @property
    def onboard_epoch(self) -> int:
        """The epoch commands must carry (0 in process)."""
        return self._epoch

    def get_lcm_message_input_port(self):
        return self._message_input

    def get_message_undecodable_input_port(self):
        return self._undecodable_input

    def get_packets_input_port(self):
        return self._packets_input

    def get_q_commanded_output_port(self):
        return self._q_output

    def get_last_command_seq_output_port(self):
        return self._seq_output

    def get_last_command_session_output_port(self):
        return self._session_output

    def get_command_rejected_output_port(self):
        return self._rejected_output

    def get_command_timeout_output_port(self):
        return self._timeout_output

    def get_accepted_count_output_port(self):
        return self._accepted_output

    def get_rejection_counts_output_port(self):
        return self._counts_output

    def get_last_rejection_output_port(self):
        return self._last_rejection_output

    @property
    def params(self) -> ReceiverParams:
        """The immutable parameters of :func:`~telesmooth.link.receiver.receiver_step`."""
        return self._params

    def receiver_state(self, context) -> ReceiverState:
        """The receiver's state in ``context`` (between polls)."""
        return self._state.get(context)

    def rejection_counts(self, context) -> dict:
        """{class: count} of the packets not accepted so far (plus "accepted")."""
        state = self.receiver_state(context)
        counts = dict(state.counts._asdict())
        counts["accepted"] = state.accepted
        return counts

    def _update_command(self, context, state):
        now = context.get_time()
        packets = message = None
        undecodable = False
        if self._packets_input.HasValue(context):
            packets = self._packets_input.Eval(context)
        elif self._message_input.HasValue(context):
            message = self._message_input.Eval(context)
            undecodable = (self._undecodable_input.HasValue(context)
                           and self._undecodable_input.Eval(context)[0] > 0.5)
        after, rejections = receiver_step(
            self._params, self.receiver_state(context),
            ReceiverInputs(now=now, packets=packets, message=message, undecodable=undecodable))
        for rejection in rejections:
            log = _logger.warning if rejection.kind in FLAGGED else _logger.info
            log("%s: packet rejected at t = %.3f s (%s)",
                self.get_name() or "JointCommandReceiver", now, rejection)
        self._state.store(state, after)
        if rejections:
            state.get_mutable_abstract_state(self._rejection_state).set_value(
                str(rejections[-1]))
