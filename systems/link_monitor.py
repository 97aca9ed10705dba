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
from telesmooth.systems.joint_command_receiver import REJECTION_CLASSES
from telesmooth.systems.timing import check_period

__all__ = ["LINK_STATUSES", "LinkMonitor", "LinkMonitorConfig", "ONBOARD_COUNTS",
           "link_status"]

LINK_STATUSES = ("no-telemetry", "ok", "degraded", "lost")
"""``link_status`` values, by index."""

ONBOARD_COUNTS = ("accepted",) + REJECTION_CLASSES
"""The ``onboard_counts`` output, in this order (the telemetry's counters)."""


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
    - ``onboard_counts``: the robot's packet counts (:data:`ONBOARD_COUNTS`), (6,).
    """

    def __init__(self, config: LinkMonitorConfig = LinkMonitorConfig(), *, session_id: int = 0):
        super().__init__()
        self._config = config
        self._session_id = int(session_id)
        self._telemetry_input = self.DeclareAbstractInputPort(
            "telemetry", AbstractValue.Make(lcmt_onboard_joint_status()))
        self._count_input = self.DeclareVectorInputPort("telemetry_count", 1)
        self._sequence_input = self.DeclareVectorInputPort("sequence_number", 1)
        # [status, arrival time of the newest telemetry (−1: none), its count,
        #  unacknowledged, guard mode, rejections at the previous telemetry, 6 counts]
        initial = np.zeros(12)
        initial[1], initial[4] = -1.0, -1.0
        self._state = self.DeclareDiscreteState(initial)
        self.DeclarePeriodicDiscreteUpdateEvent(config.poll_period_s, 0.0, self._update)
        self.DeclareForcedDiscreteUpdateEvent(self._update)

        def scalar(index):
            return lambda c, o: o.SetAtIndex(0, self._values(c)[index])

        self.DeclareVectorOutputPort("link_status", 1, scalar(0), {self.xd_ticket()})
        self.DeclareVectorOutputPort(
            "telemetry_age", 1,
            lambda c, o: o.SetAtIndex(0, -1.0 if self._values(c)[1] < 0
                                      else c.get_time() - self._values(c)[1]),
            {self.xd_ticket(), self.time_ticket()})
        self.DeclareVectorOutputPort("unacknowledged", 1, scalar(3), {self.xd_ticket()})
        self.DeclareVectorOutputPort("onboard_guard_mode", 1, scalar(4), {self.xd_ticket()})
        self.DeclareVectorOutputPort("onboard_counts", 6,
                                     lambda c, o: o.SetFromVector(self._values(c)[6:12]),
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
        if count != values[2] and count > 0:
            msg = self._telemetry_input.Eval(context)
            values[1], values[2] = now, count
            counts = [msg.accepted_count, msg.rejected_invalid_count, msg.rejected_auth_count,
                      msg.dropped_duplicate_count, msg.dropped_stale_count,
                      msg.undecodable_count]
            flagged = msg.rejected_invalid_count + msg.rejected_auth_count + \
                msg.undecodable_count
            rejected_recently = flagged > values[5] or bool(msg.command_rejected)
            values[5] = flagged
            values[6:12] = counts
            values[4] = msg.guard_mode
            acked = msg.last_command_seq if msg.last_command_session_id == self._session_id \
                else -1
            values[3] = max(0.0, sent - acked)
        age = None if values[1] < 0 else now - values[1]
        values[0] = link_status(
            telemetry_age_s=age, unacknowledged=int(values[3]), guard_mode=int(values[4]),
            rejected_recently=rejected_recently, config=self._config)
        discrete_state.get_mutable_vector(self._state).SetFromVector(values)
