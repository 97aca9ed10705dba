"""The ground's view of the link as a pure step: one status from the robot's telemetry.

The ground cannot see the link itself; it sees what the robot reports in its telemetry
(``lcmt_onboard_joint_status``): the last command the robot accepted (session and seq), the
onboard link guard's mode and how many packets the robot rejected or dropped, by class.
:func:`monitor_step` ``(params, state, inputs) -> state`` turns that into one
:class:`LinkStatus` an operator can read, and follows the robot's epoch with this ground run's
session (:mod:`telesmooth.link.session`).
:class:`~telesmooth.systems.link_monitor.LinkMonitor` is the thin Drake system around it.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

from telesmooth.labelled_enum import LabelledEnum
from telesmooth.link.receiver import FLAGGED, REJECTION_CLASSES, RejectionCounts
from telesmooth.link.session import NONCE_BITS, next_session

__all__ = ["LINK_STATUSES", "LinkStatus", "MonitorInputs", "MonitorParams", "MonitorState",
           "ONBOARD_COUNTS", "OnboardCounts", "link_status", "monitor_initial_state",
           "monitor_step"]


class LinkStatus(LabelledEnum):
    """The link as the ground sees it (the values are the ``link_status`` port's)."""

    NO_TELEMETRY = 0
    OK = 1
    DEGRADED = 2
    LOST = 3


LINK_STATUSES = tuple(status.label for status in LinkStatus)
"""``link_status`` values, by index."""

ONBOARD_COUNTS = ("accepted",) + REJECTION_CLASSES
"""The robot's packet counters as the telemetry gives them, in this order."""


class OnboardCounts(NamedTuple):
    """The robot's packet counts, as :data:`ONBOARD_COUNTS` orders them."""

    accepted: int = 0
    rejected: RejectionCounts = RejectionCounts()

    @classmethod
    def of(cls, msg) -> OnboardCounts:
        """The counts a telemetry message carries."""
        return cls(msg.accepted_count, RejectionCounts(
            msg.rejected_invalid_count, msg.rejected_auth_count, msg.dropped_duplicate_count,
            msg.dropped_stale_count, msg.undecodable_count, msg.rejected_session_count))

    @property
    def flagged(self) -> int:
        """The rejections that raise the robot's flag (``receiver.FLAGGED``)."""
        return sum(getattr(self.rejected, kind.label) for kind in FLAGGED)


@dataclasses.dataclass(frozen=True)
class MonitorParams:
    """The monitor's immutable settings.

    Attributes:
        telemetry_timeout_s: Telemetry older than this means the link is lost, s.
        max_unacknowledged: More packets sent than the robot has accepted (same session)
            makes the link degraded.
        session_nonce: This ground run's nonce: with it, the session follows the robot's
            epoch (a new epoch → the session after the robot's last accepted one); None: the
            session stays as it started.
    """

    telemetry_timeout_s: float = 1.0
    max_unacknowledged: int = 4
    session_nonce: int | None = None

    def __post_init__(self) -> None:
        if self.session_nonce is not None and not 0 <= self.session_nonce < 2**NONCE_BITS:
            raise ValueError(f"session_nonce = {self.session_nonce!r} must be in "
                             f"[0, 2^{NONCE_BITS})")


class MonitorState(NamedTuple):
    """The monitor between polls."""

    status: LinkStatus
    arrival: float               # when the newest telemetry arrived, s; −1 before any
    count: float                 # the subscriber's message count at that telemetry
    unacknowledged: int          # packets sent in this session the robot has not accepted
    guard_mode: int              # the robot's link guard mode; −1 before telemetry
    counts: OnboardCounts
    epoch: int                   # the epoch this ground addresses
    session: int                 # the session its commands carry
    stream_distance: float       # the robot's command from its accepted stream, rad
    robot_session: int           # the session of the robot's last accepted command


class MonitorInputs(NamedTuple):
    """One poll's inputs."""

    now: float
    count: float                 # the subscriber's message count (a change: a new message)
    sent: float                  # the uplink's newest packet number; −1 before the first
    message: object = None       # the newest lcmt_onboard_joint_status (read when count is new)


def link_status(*, telemetry_age_s: float | None, unacknowledged: int, guard_mode: int,
                rejected_recently: bool, params: MonitorParams) -> LinkStatus:
    """The status from what the telemetry says.

    No telemetry before any; lost when it is older than ``telemetry_timeout_s``; degraded when
    the robot is more than ``max_unacknowledged`` packets behind, its link guard is not
    tracking (stopping, held or resuming), or it rejected a packet since the previous
    telemetry; else ok.
    """
    if telemetry_age_s is None:
        return LinkStatus.NO_TELEMETRY
    if telemetry_age_s > params.telemetry_timeout_s:
        return LinkStatus.LOST
    if unacknowledged > params.max_unacknowledged or guard_mode != 0 or rejected_recently:
        return LinkStatus.DEGRADED
    return LinkStatus.OK


def monitor_initial_state(*, session_id: int = 0, onboard_epoch: int = 0) -> MonitorState:
    """Before any telemetry, addressing ``onboard_epoch`` with ``session_id``."""
    return MonitorState(status=LinkStatus.NO_TELEMETRY, arrival=-1.0, count=0.0,
                        unacknowledged=0, guard_mode=-1, counts=OnboardCounts(),
                        epoch=int(onboard_epoch), session=int(session_id),
                        stream_distance=0.0, robot_session=0)


def monitor_step(params: MonitorParams, state: MonitorState,
                 inputs: MonitorInputs) -> MonitorState:
    """One poll: a new telemetry message (its count changed) updates what the robot said;
    then the status is recomputed for this instant."""
    rejected_recently = False
    if inputs.count != state.count and inputs.count > 0:
        msg = inputs.message
        counts = OnboardCounts.of(msg)
        rejected_recently = counts.flagged > state.counts.flagged or bool(msg.command_rejected)
        epoch, session = state.epoch, state.session
        if params.session_nonce is not None and msg.onboard_epoch != epoch:
            # A robot not addressed yet (the first telemetry, or a restart): the next
            # session after the one it accepted last.
            epoch = int(msg.onboard_epoch)
            session = next_session(msg.last_command_session_id, params.session_nonce)
        acked = msg.last_command_seq if msg.last_command_session_id == session else -1
        state = state._replace(
            arrival=float(inputs.now), count=float(inputs.count),
            counts=counts, guard_mode=int(msg.guard_mode),
            stream_distance=float(msg.stream_distance_rad),
            robot_session=int(msg.last_command_session_id), epoch=epoch, session=session,
            unacknowledged=int(max(0.0, inputs.sent - acked)))
    age = None if state.arrival < 0 else inputs.now - state.arrival
    return state._replace(status=link_status(
        telemetry_age_s=age, unacknowledged=state.unacknowledged, guard_mode=state.guard_mode,
        rejected_recently=rejected_recently, params=params))
