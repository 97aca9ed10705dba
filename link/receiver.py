"""The onboard packet receiver as a pure step: which uplink packets may move the robot.

Every packet is examined before it can move the robot, in this order (the first failing check
classifies it, :func:`classify_joint_command`):

1. **decodes** as an ``lcmt_teleop_joint_command`` (:attr:`PacketClass.UNDECODABLE`);
2. with a key, carries a valid HMAC-SHA256 tag over the whole message, sequence number and
   session included (:attr:`PacketClass.AUTH`: unsigned or forged; see
   :mod:`telesmooth.link.auth`);
3. it is **fresh** (:mod:`telesmooth.link.session`): it carries this onboard run's epoch
   (:attr:`PacketClass.SESSION` otherwise: a packet from before an onboard restart), and its
   (session_id, seq) follows the last accepted command: a newer seq of the same session, or
   the next session counter (:attr:`~PacketClass.DUPLICATE`: the same packet again, a
   duplicate or a replay; :attr:`~PacketClass.STALE`: older, i.e. late, reordered or a
   replay of an earlier packet; :attr:`~PacketClass.SESSION`: a session counter that skips
   ahead);
4. names the robot's joints in order, with finite positions inside the joint limits
   (:attr:`PacketClass.INVALID`).

A packet that passes all four is **accepted**: it becomes the command. Anything else is
counted by class and the robot keeps the last accepted command. An invalid, forged,
undecodable or foreign-session packet also raises the ``rejected`` flag until the next
accepted one (:data:`FLAGGED`); duplicates and stale packets are link artefacts and are only
counted. When no packet was accepted for longer than the timeout the ``timeout`` flag is
raised.

:func:`receiver_step` ``(params, state, inputs) -> (state, rejections)`` is one poll;
:class:`~telesmooth.systems.joint_command_receiver.JointCommandReceiver` is the thin Drake
system around it (ports, and the :class:`ReceiverState` as one Context vector).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from telesmooth.labelled_enum import LabelledEnum
from telesmooth.lcm_types import decode_exact, lcmt_teleop_joint_command
from telesmooth.link.auth import verify
from telesmooth.link.session import classify_session

__all__ = [
    "FLAGGED",
    "PACKET_CLASSES",
    "REJECTION_CLASSES",
    "PacketClass",
    "ReceiverInputs",
    "ReceiverParams",
    "ReceiverState",
    "Rejection",
    "RejectionCounts",
    "check_joint_command",
    "classify_joint_command",
    "receiver_initial_state",
    "receiver_step",
]


class PacketClass(LabelledEnum):
    """What a packet is; the rejections' values are their index in ``rejection_counts``."""

    INVALID = 0
    AUTH = 1
    DUPLICATE = 2
    STALE = 3
    UNDECODABLE = 4
    SESSION = 5
    ACCEPTED = 6
    IGNORED = 7
    """The sender's seq = −1 placeholder before its first packet: not a packet."""


REJECTION_CLASSES = tuple(kind.label for kind in PacketClass if kind < PacketClass.ACCEPTED)
"""The ways a packet is not accepted, in the order of ``rejection_counts``."""

PACKET_CLASSES = ("accepted",) + REJECTION_CLASSES + ("ignored",)
"""Every outcome of :func:`classify_joint_command`, as labels."""

FLAGGED = frozenset({PacketClass.INVALID, PacketClass.AUTH, PacketClass.UNDECODABLE,
                     PacketClass.SESSION})
"""The rejections that raise the ``rejected`` flag (the others are link artefacts)."""


class RejectionCounts(NamedTuple):
    """Packets not accepted so far, per class (fields in :class:`PacketClass` order)."""

    invalid: int = 0
    auth: int = 0
    duplicate: int = 0
    stale: int = 0
    undecodable: int = 0
    session: int = 0


@dataclasses.dataclass(frozen=True, eq=False)
class ReceiverParams:
    """The receiver's immutable settings.

    Attributes:
        joint_names: The robot's joints, in order.
        lower_rad, upper_rad: Their limits, (J,) rad.
        key: The uplink key; None: tags are not checked (in-process simulation only).
        onboard_epoch: This onboard run's epoch (0 in process).
        timeout_s: Silence after which ``timeout`` is raised, s.
    """

    joint_names: tuple
    lower_rad: np.ndarray
    upper_rad: np.ndarray
    key: bytes | None = None
    onboard_epoch: int = 0
    timeout_s: float = 1.0


class ReceiverState(NamedTuple):
    """The receiver between polls."""

    command: np.ndarray          # (J,) the last accepted positions (the start pose before)
    last_seq: int                # its seq; −1 before the first
    last_session: int            # its session_id; 0 before the first
    last_time: float             # when it was accepted, s (0 before the first)
    rejected: bool               # the newest examined packet was flagged (FLAGGED)
    timeout: bool                # nothing accepted for longer than the timeout
    examined_seq: int            # newest-message mode: the (session, seq) examined last
    examined_session: int
    last_packet: int             # packets mode: the largest arrival index examined; −1
    accepted: int                # packets accepted so far
    counts: RejectionCounts


class ReceiverInputs(NamedTuple):
    """One poll's inputs: ``packets`` when connected, else the newest decoded ``message``."""

    now: float
    packets: tuple | None = None   # ((arrival index, bytes), …), newest last
    message: object = None         # the newest decoded lcmt_teleop_joint_command
    undecodable: bool = False      # with ``message``: the newest packet did not decode


class Rejection(NamedTuple):
    """A packet not accepted, and why (for people)."""

    kind: PacketClass
    reason: str

    def __str__(self) -> str:
        return f"{self.kind.label}: {self.reason}"


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
                           key: bytes | None = None,
                           onboard_epoch: int = 0) -> tuple[PacketClass, str]:
    """The class of one decoded packet (see the module docstring) and the reason, for people.

    Args:
        msg: A decoded ``lcmt_teleop_joint_command``.
        last_accepted: (session_id, seq) of the last accepted command, or None before the first.
        joint_names, lower_rad, upper_rad: The robot's joints and limits, rad.
        key: The uplink key; None = authentication off.
        onboard_epoch: This onboard run's epoch (0 in process).

    Returns:
        (class, reason); reason is "" when accepted.
    """
    if msg.seq < 0:
        return PacketClass.IGNORED, f"seq = {msg.seq}: the sender has not formed a packet yet"
    if key is not None:
        problem = verify(msg, key)
        if problem is not None:
            return PacketClass.AUTH, problem
    if int(msg.onboard_epoch) != int(onboard_epoch):
        return PacketClass.SESSION, (
            f"onboard_epoch = {int(msg.onboard_epoch)} is not this onboard run's "
            f"{int(onboard_epoch)} (a packet from before a restart, or a ground that has not "
            "read this robot's telemetry yet)")
    kind, reason = classify_session(msg.session_id, msg.seq, last_accepted)
    if kind != "accepted":
        return PacketClass[kind.upper()], reason
    problem = check_joint_command(msg, joint_names=joint_names, lower_rad=lower_rad,
                                  upper_rad=upper_rad)
    if problem is not None:
        return PacketClass.INVALID, problem
    return PacketClass.ACCEPTED, ""


def receiver_initial_state(initial_position) -> ReceiverState:
    """Before any packet: holding ``initial_position`` (J,)."""
    return ReceiverState(command=np.array(initial_position, dtype=float), last_seq=-1,
                         last_session=0, last_time=0.0, rejected=False, timeout=False,
                         examined_seq=-1, examined_session=0, last_packet=-1, accepted=0,
                         counts=RejectionCounts())


def _is_default(msg) -> bool:
    """Whether ``msg`` is a default-constructed message (a subscriber's "nothing yet").

    Compared field by field: an in-process message whose counts disagree with its arrays
    cannot be encoded, and must not raise here."""
    return (msg.utime == 0 and msg.seq == 0 and msg.sample_utime == 0 and msg.num_joints == 0
            and not msg.joint_name and not msg.joint_position_smoothed
            and not msg.joint_velocity_smoothed and msg.mode == 0 and msg.session_id == 0
            and msg.auth_tag_size == 0 and not msg.auth_tag)


def _rejected(state: ReceiverState, rejection: Rejection) -> ReceiverState:
    counts = state.counts._replace(**{
        rejection.kind.label: getattr(state.counts, rejection.kind.label) + 1})
    return state._replace(counts=counts,
                          rejected=state.rejected or rejection.kind in FLAGGED)


def _examined(params: ReceiverParams, state: ReceiverState, msg, now: float,
              rejections: list) -> ReceiverState:
    last = None if state.last_seq < 0 else (state.last_session, state.last_seq)
    kind, reason = classify_joint_command(
        msg, last_accepted=last, joint_names=params.joint_names, lower_rad=params.lower_rad,
        upper_rad=params.upper_rad, key=params.key, onboard_epoch=params.onboard_epoch)
    if kind == PacketClass.IGNORED:
        return state
    if kind == PacketClass.ACCEPTED:
        return state._replace(
            command=np.asarray(msg.joint_position_smoothed, dtype=float),
            last_seq=int(msg.seq), last_session=int(msg.session_id), last_time=float(now),
            rejected=False, accepted=state.accepted + 1)
    rejections.append(Rejection(kind, reason))
    return _rejected(state, rejections[-1])


def receiver_step(params: ReceiverParams, state: ReceiverState,
                  inputs: ReceiverInputs) -> tuple[ReceiverState, tuple[Rejection, ...]]:
    """One poll: every new packet examined in arrival order (each accepted one becomes the
    command in turn: the newest accepted wins the poll), then the timeout recomputed.

    With ``packets``, each packet whose arrival index is above the last examined one is
    examined once, so every duplicate, replay and forgery is counted. With only the newest
    decoded ``message``, it is examined once, when its (session_id, seq) is newer than the
    last accepted one and differs from the last examined one (stale and duplicate packets are
    then not seen, hence not counted); ``undecodable`` raises the flag.

    Returns:
        The state after the poll, and the packets not accepted in it, in order.
    """
    now = float(inputs.now)
    rejections: list[Rejection] = []
    if inputs.packets is not None:
        for index, data in inputs.packets:
            if index <= state.last_packet:
                continue
            state = state._replace(last_packet=int(index))
            try:
                msg = decode_exact(lcmt_teleop_joint_command, data)
            except Exception as error:  # noqa: BLE001 - any failure = not this type
                rejections.append(Rejection(PacketClass.UNDECODABLE, (
                    f"{len(data)} bytes: {type(error).__name__}: {error}")))
                state = _rejected(state, rejections[-1])
                continue
            state = _examined(params, state, msg, now, rejections)
    elif inputs.message is not None:
        msg = inputs.message
        pair = (int(msg.session_id), int(msg.seq))
        newer = state.last_seq < 0 or pair > (state.last_session, state.last_seq)
        if newer and msg.seq >= 0 and pair != (state.examined_session, state.examined_seq) \
                and not _is_default(msg):
            state = state._replace(examined_session=pair[0], examined_seq=pair[1])
            state = _examined(params, state, msg, now, rejections)
        if inputs.undecodable:
            state = state._replace(rejected=True)
    state = state._replace(timeout=now - state.last_time > params.timeout_s)
    return state, tuple(rejections)
