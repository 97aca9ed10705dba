"""Ground-side link status from the onboard telemetry (``lcmt_onboard_joint_status``).

The ground process cannot see the link itself; it sees what the robot reports: the last
command the robot accepted (session and seq), the onboard link guard's mode, and how many
packets the robot rejected or dropped, by class. :class:`LinkMonitor` turns that into one
status an operator can read, and the ground process prints it whenever it changes.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from telesmooth.lcm_types import lcmt_onboard_joint_status
from telesmooth.link.session import NONCE_BITS, next_session
from telesmooth.systems.joint_command_receiver import REJECTION_CLASSES
from telesmooth.systems.timing import check_period

__all__ = ["LINK_STATUSES", "LinkMonitor", "LinkMonitorConfig", "ONBOARD_COUNTS",
           "link_status"]

LINK_STATUSES = ("no-telemetry", "ok", "degraded", "lost")
"""``link_status`` values, by index."""

ONBOARD_COUNTS = ("accepted",) + REJECTION_CLASSES
"""The ``onboard_counts`` output, in this order (the telemetry's counters)."""

# Layout of the monitor's state vector.
(_STATUS, _ARRIVAL, _COUNT, _UNACKNOWLEDGED, _GUARD_MODE, _FLAGGED) = range(6)
_COUNTS = 6
_EPOCH = _COUNTS + len(ONBOARD_COUNTS)
_SESSION, _DISTANCE, _ROBOT_SESSION = _EPOCH + 1, _EPOCH + 2, _EPOCH + 3
_SIZE = _EPOCH + 4


@dataclasses.dataclass(frozen=True)
class LinkMonitorConfig:
    """Settings of the ground's link monitor.

    Attributes:
        poll_period_s: How often the status is recomputed, s.
        telemetry_timeout_s: Telemetry older than this means the link is ``"lost"``, s.
        max_unacknowledged: More packets sent than the robot has accepted (same session)
            makes the link ``"degraded"``; 4 = one second at 4 Hz.
    """

    poll_period_s: float = 0.05
    telemetry_timeout_s: float = 1.0
    max_unacknowledged: int = 4

    def __post_init__(self) -> None:
        check_period("LinkMonitorConfig.poll_period_s", self.poll_period_s)
        check_period("LinkMonitorConfig.telemetry_timeout_s", self.telemetry_timeout_s)
        if isinstance(self.max_unacknowledged, bool) or not isinstance(
                self.max_unacknowledged, int) or self.max_unacknowledged < 0:
            raise ValueError(f"LinkMonitorConfig.max_unacknowledged = "
                             f"{self.max_unacknowledged!r} must be a non-negative integer")


def link_status(*, telemetry_age_s: float | None, unacknowledged: int, guard_mode: int,
                rejected_recently: bool, config: LinkMonitorConfig) -> int:
    """The status index (:data:`LINK_STATUSES`) from what the telemetry says.

    ``"no-telemetry"`` before any telemetry; ``"lost"`` when it is older than
    ``telemetry_timeout_s``; ``"degraded"`` when the robot is more than
    ``max_unacknowledged`` packets behind, its link guard is not tracking (stopping, held or
    resuming), or it rejected a packet since the previous telemetry; else ``"ok"``.
    """
    if telemetry_age_s is None:
        return 0
    if telemetry_age_s > config.telemetry_timeout_s:
        return 3
    if unacknowledged > config.max_unacknowledged or guard_mode != 0 or rejected_recently:
        return 2
    return 1


class LinkMonitor(LeafSystem):
    r"""Link status of the ground process, from the robot's telemetry.

    .. pydrake_system::

        name: LinkMonitor
        input_ports:
        - telemetry
        - telemetry_count
        - sequence_number
        output_ports:
        - link_status
        - telemetry_age
        - unacknowledged
        - onboard_guard_mode
        - onboard_counts
        - onboard_epoch
        - session_id
        - stream_distance
        - robot_session

    - ``telemetry``: the newest ``lcmt_onboard_joint_status`` (an ``LcmSafeSubscriber``'s
      ``lcm_message``); ``telemetry_count``: its ``message_count`` (a change = a new message).
    - ``sequence_number``: the uplink's newest packet number (−1 before the first).
    - ``link_status``: index into :data:`LINK_STATUSES` (:func:`link_status`), (1,).
    - ``telemetry_age``: seconds since the newest telemetry arrived (−1 before any), (1,).
    - ``unacknowledged``: packets sent in this session that the robot has not accepted yet
      (sent seq − onboard last_command_seq; all sent ones when the robot's last command is
      from another session), (1,).
    - ``onboard_guard_mode``: the robot's link guard mode (0 track, 1 stopping, 2 held,
      3 resuming; −1 before telemetry), (1,).
    - ``onboard_counts``: the robot's packet counts (:data:`ONBOARD_COUNTS`), (7,).
    - ``onboard_epoch``: the epoch the robot announces (0 before telemetry), and
      ``session_id``: the session this ground run's commands carry
      (:mod:`telesmooth.link.session`), (1,) each: connect both to the ``JointCommandSender``. With
      a ``session_nonce`` the session follows the telemetry: whenever a new epoch appears (the
      first telemetry, a restarted robot) it becomes the counter after the robot's last accepted
      session, with this run's nonce. Without one both stay at the constructor's values.
    - ``stream_distance``: how far the robot's command is from the stream it accepted, rad
      (the telemetry's; 0 before), (1,).
    - ``robot_session``: the session of the robot's last accepted command (0 before), (1,).
    """

    def __init__(self, config: LinkMonitorConfig = LinkMonitorConfig(), *, session_id: int = 0,
                 session_nonce: int | None = None, onboard_epoch: int = 0):
        super().__init__()
        self._config = config
        self._session_id = int(session_id)
        if session_nonce is not None and not 0 <= session_nonce < 2**NONCE_BITS:
            raise ValueError(f"session_nonce = {session_nonce!r} must be in "
                             f"[0, 2^{NONCE_BITS})")
        self._nonce = session_nonce
        self._telemetry_input = self.DeclareAbstractInputPort(
            "telemetry", AbstractValue.Make(lcmt_onboard_joint_status()))
        self._count_input = self.DeclareVectorInputPort("telemetry_count", 1)
        self._sequence_input = self.DeclareVectorInputPort("sequence_number", 1)
        # [status, arrival time of the newest telemetry (−1: none), its count,
        #  unacknowledged, guard mode, rejections at the previous telemetry, 7 counts, epoch,
        #  session, the robot's stream distance, the robot's session]
        initial = np.zeros(_SIZE)
        initial[_ARRIVAL], initial[_GUARD_MODE] = -1.0, -1.0
        initial[_EPOCH], initial[_SESSION] = float(onboard_epoch), float(session_id)
        self._state = self.DeclareDiscreteState(initial)
        self.DeclarePeriodicDiscreteUpdateEvent(config.poll_period_s, 0.0, self._update)
        self.DeclareForcedDiscreteUpdateEvent(self._update)

        def scalar(index):
            return lambda c, o: o.SetAtIndex(0, self._values(c)[index])

        self.DeclareVectorOutputPort("link_status", 1, scalar(_STATUS), {self.xd_ticket()})
        self.DeclareVectorOutputPort(
            "telemetry_age", 1,
            lambda c, o: o.SetAtIndex(0, -1.0 if self._values(c)[_ARRIVAL] < 0
                                      else c.get_time() - self._values(c)[_ARRIVAL]),
            {self.xd_ticket(), self.time_ticket()})
        self.DeclareVectorOutputPort("unacknowledged", 1, scalar(_UNACKNOWLEDGED),
                                     {self.xd_ticket()})
        self.DeclareVectorOutputPort("onboard_guard_mode", 1, scalar(_GUARD_MODE),
                                     {self.xd_ticket()})
        self.DeclareVectorOutputPort(
            "onboard_counts", len(ONBOARD_COUNTS),
            lambda c, o: o.SetFromVector(self._values(c)[_COUNTS:_EPOCH]), {self.xd_ticket()})
        self.DeclareVectorOutputPort("onboard_epoch", 1, scalar(_EPOCH), {self.xd_ticket()})
        self.DeclareVectorOutputPort("session_id", 1, scalar(_SESSION), {self.xd_ticket()})
        self.DeclareVectorOutputPort("stream_distance", 1, scalar(_DISTANCE),
                                     {self.xd_ticket()})
        self.DeclareVectorOutputPort("robot_session", 1, scalar(_ROBOT_SESSION),
                                     {self.xd_ticket()})

    def _values(self, context):
        return context.get_discrete_state(self._state).get_value()

    def _update(self, context, discrete_state):
        values = self._values(context).copy()
        now = context.get_time()
        count = self._count_input.Eval(context)[0] if self._count_input.HasValue(context) \
            else 0.0
        sent = self._sequence_input.Eval(context)[0] if self._sequence_input.HasValue(
            context) else -1.0
        rejected_recently = False
        if count != values[_COUNT] and count > 0:
            msg = self._telemetry_input.Eval(context)
            values[_ARRIVAL], values[_COUNT] = now, count
            counts = [msg.accepted_count, msg.rejected_invalid_count, msg.rejected_auth_count,
                      msg.dropped_duplicate_count, msg.dropped_stale_count,
                      msg.undecodable_count, msg.rejected_session_count]
            flagged = msg.rejected_invalid_count + msg.rejected_auth_count + \
                msg.undecodable_count + msg.rejected_session_count
            rejected_recently = flagged > values[_FLAGGED] or bool(msg.command_rejected)
            values[_FLAGGED] = flagged
            values[_COUNTS:_EPOCH] = counts
            values[_GUARD_MODE] = msg.guard_mode
            values[_DISTANCE] = msg.stream_distance_rad
            values[_ROBOT_SESSION] = msg.last_command_session_id
            if self._nonce is not None and msg.onboard_epoch != int(values[_EPOCH]):
                # A robot we have not addressed yet (the first telemetry, or a restart): the
                # next session after the one it accepted last.
                values[_EPOCH] = msg.onboard_epoch
                values[_SESSION] = next_session(msg.last_command_session_id, self._nonce)
            acked = msg.last_command_seq if msg.last_command_session_id == int(
                values[_SESSION]) else -1
            values[_UNACKNOWLEDGED] = max(0.0, sent - acked)
        age = None if values[_ARRIVAL] < 0 else now - values[_ARRIVAL]
        values[_STATUS] = link_status(
            telemetry_age_s=age, unacknowledged=int(values[_UNACKNOWLEDGED]),
            guard_mode=int(values[_GUARD_MODE]), rejected_recently=rejected_recently,
            config=self._config)
        discrete_state.get_mutable_vector(self._state).SetFromVector(values)
