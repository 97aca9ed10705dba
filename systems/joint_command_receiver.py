"""Onboard side of the uplink: accepts ``lcmt_teleop_joint_command`` packets, or holds.

Every packet is examined before it can move the robot, in this order (the first failing check
classifies it, :func:`classify_joint_command`):

1. **decodes** as an ``lcmt_teleop_joint_command`` (``"undecodable"``);
2. with ``authentication = "required"``, carries a valid HMAC-SHA256 tag over the whole
   message, sequence number and session included (``"auth"``: unsigned or forged; see
   :mod:`telesmooth.link.auth`);
3. it is **fresh** (:mod:`telesmooth.link.session`): it carries this onboard run's epoch
   (``"session"`` otherwise: a packet from before an onboard restart), and its
   (session_id, seq) follows the last accepted command: a newer seq of the same session, or
   the next session counter (``"duplicate"``: the same packet again, a duplicate or a
   replay; ``"stale"``: older, i.e. late, reordered or a replay of an earlier packet;
   ``"session"``: a session counter that skips ahead);
4. names the robot's joints in order, with finite positions inside the joint limits
   (``"invalid"``).

A packet that passes all four is **accepted**: it becomes the command. Anything else is
counted by class, logged with its reason, and the robot keeps the last accepted command. An
invalid, forged or undecodable packet also raises the ``command_rejected`` flag until the next
accepted one; duplicates and stale packets are link artefacts and are only counted. When
packets stop arriving the command holds and ``command_timeout`` is raised (the onboard
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
from telesmooth.lcm_types import decode_exact, lcmt_teleop_joint_command
from telesmooth.link.auth import check_key, verify
from telesmooth.link.session import EPOCH_BITS, classify_session
from telesmooth.systems.timing import check_period

__all__ = [
    "AUTHENTICATION_MODES",
    "PACKET_CLASSES",
    "REJECTION_CLASSES",
    "JointCommandReceiver",
    "JointCommandReceiverConfig",
    "check_joint_command",
    "classify_joint_command",
]

AUTHENTICATION_MODES = ("off", "required")
"""``JointCommandReceiverConfig.authentication``: ``"off"`` only for in-process simulation."""

REJECTION_CLASSES = ("invalid", "auth", "duplicate", "stale", "undecodable", "session")
"""The ways a packet is not accepted; ``rejection_counts`` is in this order."""

PACKET_CLASSES = ("accepted",) + REJECTION_CLASSES + ("ignored",)
"""Every outcome of :func:`classify_joint_command` (``"ignored"``: the sender's seq = −1
placeholder before its first packet)."""

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


def check_joint_command(msg, *, joint_names, lower_rad, upper_rad) -> str | None:
    """Why ``msg`` must not move the robot (a message naming field, joint and value), or None."""
    n = len(joint_names)
    if msg.num_joints != n or len(msg.joint_position_smoothed) != n:
        return f"num_joints = {msg.num_joints} but the robot has {n} joints"
    if tuple(msg.joint_name) != tuple(joint_names):
        return (f"joint_name = {list(msg.joint_name)!r} differs from the robot's "
                f"{list(joint_names)!r}")
    for name, value, lo, hi in zip(joint_names, msg.joint_position_smoothed, lower_rad,
                                   upper_rad):
        if not np.isfinite(value):
            return f"joint_position_smoothed[{name!r}] = {value!r} is not finite"
        if not lo <= value <= hi:
            return (f"joint_position_smoothed[{name!r}] = {value!r} rad is outside the limits "
                    f"[{lo!r}, {hi!r}]")
    return None


def classify_joint_command(msg, *, last_accepted, joint_names, lower_rad, upper_rad,
                           key: bytes | None = None, onboard_epoch: int = 0) -> tuple[str, str]:
    """The class of one decoded packet (see the module docstring) and the reason, for people.

    Args:
        msg: A decoded ``lcmt_teleop_joint_command``.
        last_accepted: (session_id, seq) of the last accepted command, or None before the first.
        joint_names, lower_rad, upper_rad: The robot's joints and limits, rad.
        key: The uplink key; None = authentication off.
        onboard_epoch: This onboard run's epoch (0 in process).

    Returns:
        (class, reason): class in :data:`PACKET_CLASSES`; reason is "" when accepted.
    """
    if msg.seq < 0:
        return "ignored", f"seq = {msg.seq}: the sender has not formed a packet yet"
    if key is not None:
        problem = verify(msg, key)
        if problem is not None:
            return "auth", problem
    if int(msg.onboard_epoch) != int(onboard_epoch):
        return "session", (f"onboard_epoch = {int(msg.onboard_epoch)} is not this onboard "
                           f"run's {int(onboard_epoch)} (a packet from before a restart, or a "
                           "ground that has not read this robot's telemetry yet)")
    kind, reason = classify_session(msg.session_id, msg.seq, last_accepted)
    if kind != "accepted":
        return kind, reason
    problem = check_joint_command(msg, joint_names=joint_names, lower_rad=lower_rad,
                                  upper_rad=upper_rad)
    if problem is not None:
        return "invalid", problem
    return "accepted", ""


# Layout of the discrete status state.
(_LAST_SEQ, _LAST_TIME, _REJECTED, _TIMEOUT, _EXAMINED_SEQ, _LAST_SESSION, _LAST_PACKET,
 _ACCEPTED, _COUNTS) = range(9)
_EXAMINED_SESSION = _COUNTS + len(REJECTION_CLASSES)
_STATUS_SIZE = _EXAMINED_SESSION + 1
_FLAGGED = ("invalid", "auth", "undecodable", "session")


def _is_default(msg) -> bool:
    """Whether ``msg`` is a default-constructed message (a subscriber's "nothing yet").

    Compared field by field: an in-process message whose counts disagree with its arrays
    cannot be encoded, and must not raise here."""
    return (msg.utime == 0 and msg.seq == 0 and msg.sample_utime == 0 and msg.num_joints == 0
            and not msg.joint_name and not msg.joint_position_smoothed
            and not msg.joint_velocity_smoothed and msg.mode == 0 and msg.session_id == 0
            and msg.auth_tag_size == 0 and not msg.auth_tag)


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
        self._command_state = self.DeclareDiscreteState(q0)
        status = np.zeros(_STATUS_SIZE)
        status[[_LAST_SEQ, _EXAMINED_SEQ, _LAST_PACKET]] = -1.0
        self._status_state = self.DeclareDiscreteState(status)
        self._rejection_state = self.DeclareAbstractState(AbstractValue.Make(""))
        self.DeclarePeriodicUnrestrictedUpdateEvent(config.poll_period_s, 0.0,
                                                    self._update_command)
        self.DeclareInitializationUnrestrictedUpdateEvent(self._update_command)
        self.DeclareForcedUnrestrictedUpdateEvent(self._update_command)
        self._q_output = self.DeclareStateOutputPort("q_commanded", self._command_state)

        def scalar(index):
            return lambda c, o: o.SetAtIndex(0, self._status(c)[index])

        self._seq_output = self.DeclareVectorOutputPort(
            "last_command_seq", 1, scalar(_LAST_SEQ), {self.xd_ticket()})
        self._session_output = self.DeclareVectorOutputPort(
            "last_command_session", 1, scalar(_LAST_SESSION), {self.xd_ticket()})
        self._rejected_output = self.DeclareVectorOutputPort(
            "command_rejected", 1, scalar(_REJECTED), {self.xd_ticket()})
        self._timeout_output = self.DeclareVectorOutputPort(
            "command_timeout", 1, scalar(_TIMEOUT), {self.xd_ticket()})
        self._accepted_output = self.DeclareVectorOutputPort(
            "accepted_count", 1, scalar(_ACCEPTED), {self.xd_ticket()})
        self._counts_output = self.DeclareVectorOutputPort(
            "rejection_counts", len(REJECTION_CLASSES),
            lambda c, o: o.SetFromVector(
                self._status(c)[_COUNTS:_COUNTS + len(REJECTION_CLASSES)]),
            {self.xd_ticket()})
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

    def rejection_counts(self, context) -> dict:
        """{class: count} of the packets not accepted so far (plus "accepted")."""
        status = self._status(context)
        counts = {name: int(status[_COUNTS + i]) for i, name in enumerate(REJECTION_CLASSES)}
        counts["accepted"] = int(status[_ACCEPTED])
        return counts

    def _status(self, context):
        return context.get_discrete_state(self._status_state).get_value()

    def _examine(self, msg, status, now, command, reasons) -> None:
        """Classifies one decoded packet and updates ``status``/``command`` in place."""
        last = None if status[_LAST_SEQ] < 0 else (int(status[_LAST_SESSION]),
                                                   int(status[_LAST_SEQ]))
        kind, reason = classify_joint_command(
            msg, last_accepted=last, joint_names=self._joint_names, lower_rad=self._lower,
            upper_rad=self._upper, key=self._key, onboard_epoch=self._epoch)
        if kind == "ignored":
            return
        if kind == "accepted":
            command[:] = np.asarray(msg.joint_position_smoothed, dtype=float)
            status[[_LAST_SEQ, _LAST_SESSION, _LAST_TIME, _REJECTED]] = [
                msg.seq, msg.session_id, now, 0.0]
            status[_ACCEPTED] += 1
            return
        self._reject(kind, reason, status, now, reasons)

    def _reject(self, kind, reason, status, now, reasons) -> None:
        status[_COUNTS + REJECTION_CLASSES.index(kind)] += 1
        if kind in _FLAGGED:
            status[_REJECTED] = 1.0
        text = f"{kind}: {reason}"
        reasons.append(text)
        log = _logger.warning if kind in _FLAGGED else _logger.info
        log("%s: packet rejected at t = %.3f s (%s)",
            self.get_name() or "JointCommandReceiver", now, text)

    def _update_command(self, context, state):
        status = self._status(context).copy()
        command = context.get_discrete_state(self._command_state).get_value().copy()
        now = context.get_time()
        reasons = []
        if self._packets_input.HasValue(context):
            for index, data in self._packets_input.Eval(context):
                if index <= status[_LAST_PACKET]:
                    continue
                status[_LAST_PACKET] = index
                try:
                    msg = decode_exact(lcmt_teleop_joint_command, data)
                except Exception as error:  # noqa: BLE001 - any failure = not this type
                    self._reject("undecodable", f"{len(data)} bytes: {type(error).__name__}: "
                                 f"{error}", status, now, reasons)
                    continue
                self._examine(msg, status, now, command, reasons)
        elif self._message_input.HasValue(context):
            # Only the newest message is visible here: it is examined once if it is newer
            # than the last accepted one; older or equal ones are ignored, uncounted.
            msg = self._message_input.Eval(context)
            pair = (int(msg.session_id), int(msg.seq))
            newer = status[_LAST_SEQ] < 0 or pair > (int(status[_LAST_SESSION]),
                                                     int(status[_LAST_SEQ]))
            if newer and msg.seq >= 0 and pair != (
                    int(status[_EXAMINED_SESSION]), int(status[_EXAMINED_SEQ])) and (
                    not _is_default(msg)):
                status[_EXAMINED_SESSION], status[_EXAMINED_SEQ] = pair
                self._examine(msg, status, now, command, reasons)
            undecodable = self._undecodable_input
            if undecodable.HasValue(context) and undecodable.Eval(context)[0] > 0.5:
                status[_REJECTED] = 1.0
        status[_TIMEOUT] = 1.0 if now - status[_LAST_TIME] > self._config.timeout_s else 0.0
        state.get_mutable_discrete_state(self._command_state).SetFromVector(command)
        state.get_mutable_discrete_state(self._status_state).SetFromVector(status)
        if reasons:
            state.get_mutable_abstract_state(self._rejection_state).set_value(reasons[-1])
