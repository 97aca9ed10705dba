"""Ground-side link status from the onboard telemetry (``lcmt_onboard_joint_status``).

The ground process cannot see the link itself; it sees what the robot reports: the last
command the robot accepted (session and seq), the onboard link guard's mode, and how many
packets the robot rejected or dropped, by class. :class:`LinkMonitor` turns that into one
status an operator can read, and the ground process prints it whenever it changes: a thin
Drake system around the pure step :func:`telesmooth.link.monitor.monitor_step`, whose
:class:`~telesmooth.link.monitor.MonitorState` lives in the Context as one vector.
"""

from __future__ import annotations

import dataclasses

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from telesmooth.lcm_types import lcmt_onboard_joint_status
from telesmooth.link.monitor import (
    LINK_STATUSES,
    ONBOARD_COUNTS,
    LinkStatus,
    MonitorInputs,
    MonitorParams,
    MonitorState,
    link_status,
    monitor_initial_state,
    monitor_step,
)
from telesmooth.systems.codec_state import CodecState
from telesmooth.systems.timing import check_period

__all__ = ["LINK_STATUSES", "LinkMonitor", "LinkMonitorConfig", "LinkStatus", "ONBOARD_COUNTS",
           "link_status"]

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

    def params(self, session_nonce: int | None = None) -> MonitorParams:
        """The parameters of :func:`~telesmooth.link.monitor.monitor_step`."""
        return MonitorParams(telemetry_timeout_s=self.telemetry_timeout_s,
                             max_unacknowledged=self.max_unacknowledged,
                             session_nonce=session_nonce)


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
        self._params = config.params(session_nonce)
        self._telemetry_input = self.DeclareAbstractInputPort(
            "telemetry", AbstractValue.Make(lcmt_onboard_joint_status()))
        self._count_input = self.DeclareVectorInputPort("telemetry_count", 1)
        self._sequence_input = self.DeclareVectorInputPort("sequence_number", 1)
        initial = monitor_initial_state(session_id=session_id, onboard_epoch=onboard_epoch)
        self._state = CodecState(self, initial)
        self.DeclarePeriodicDiscreteUpdateEvent(config.poll_period_s, 0.0, self._update)
        self.DeclareForcedDiscreteUpdateEvent(self._update)

        state_output = self._state.output
        arrival = self._state.codec.field_slice("arrival").start
        state_output("link_status", "status")
        self.DeclareVectorOutputPort(
            "telemetry_age", 1,
            lambda c, o: o.SetAtIndex(0, -1.0 if self._state.vector(c)[arrival] < 0
                                      else c.get_time() - self._state.vector(c)[arrival]),
            {self.xd_ticket(), self.time_ticket()})
        state_output("unacknowledged", "unacknowledged")
        state_output("onboard_guard_mode", "guard_mode")
        state_output("onboard_counts", "counts")
        state_output("onboard_epoch", "epoch")
        state_output("session_id", "session")
        state_output("stream_distance", "stream_distance")
        state_output("robot_session", "robot_session")

    @property
    def params(self) -> MonitorParams:
        """The immutable parameters of :func:`~telesmooth.link.monitor.monitor_step`."""
        return self._params

    def monitor_state(self, context) -> MonitorState:
        """The monitor's state in ``context`` (between polls)."""
        return self._state.get(context)

    def _update(self, context, discrete_state):
        count = self._count_input.Eval(context)[0] if self._count_input.HasValue(context) \
            else 0.0
        sent = self._sequence_input.Eval(context)[0] if self._sequence_input.HasValue(
            context) else -1.0
        message = (self._telemetry_input.Eval(context)
                   if self._telemetry_input.HasValue(context) else None)
        state = monitor_step(self._params, self.monitor_state(context),
                             MonitorInputs(now=context.get_time(), count=count, sent=sent,
                                           message=message))
        self._state.store(discrete_state, state)
