"""The ground's sent packets, replayed on a copy of the onboard chain (the predicted robot).

The ground's predicted robot (:class:`~telesmooth.systems.robot_predictor.RobotPredictor`) runs
a copy of the onboard command path and plant, driven by the commands the ground has already
sent. :class:`PacketReplay` is the copy's link: its ``packets`` output is what a
:class:`~telesmooth.systems.link_channel.LinkChannel` with a constant delay, polled just
before each receiver poll, would have delivered by now, computed from the send times alone
(no event of its own, so the copy's integrator is not stopped by one). The packets come
from a :class:`PacketLog`, which only grows and only with packets sent at or after every
packet already in it, so that a replay never sees its past change: a time the copy has
simulated keeps the packets it had.
"""

from __future__ import annotations

import bisect
import math

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from telesmooth.systems.lcm_safe_subscriber import RECENT_PACKETS
from telesmooth.systems.timing import check_period

__all__ = ["PacketLog", "PacketReplay"]


class PacketLog:
    """Packets by send time, appended in order (shared by the replays that read it)."""

    def __init__(self):
        self._times: list[float] = []
        self._payloads: list[bytes] = []
        self._seq = -1

    def __len__(self) -> int:
        return len(self._times)

    def append(self, send_time_s: float, message) -> None:
        """Adds ``message`` (an LCM message) sent at ``send_time_s`` (s, not before the last
        one's), encoded."""
        if self._times and send_time_s < self._times[-1]:
            raise ValueError(f"send_time_s = {send_time_s!r} is before the last packet's "
                             f"{self._times[-1]!r}: the log only grows forward")
        self._times.append(float(send_time_s))
        self._payloads.append(message.encode())
        self._seq = int(message.seq)

    def last_seq(self) -> int:
        """The newest packet's seq, or −1."""
        return self._seq

    def sent_by(self, time_s: float) -> int:
        """How many packets were sent at or before ``time_s``."""
        return bisect.bisect_right(self._times, time_s + 1e-12)

    def send_time(self, index: int) -> float:
        return self._times[index]

    def last_send_time(self) -> float:
        """The newest packet's send time, or −inf."""
        return self._times[-1] if self._times else -math.inf

    def payload(self, index: int) -> bytes:
        return self._payloads[index]


class PacketReplay(LeafSystem):
    r"""What a constant-delay link delivers of a :class:`PacketLog`, by the current time.

    .. pydrake_system::

        name: PacketReplay
        output_ports:
        - packets

    - ``packets``: as a ``LinkChannel``'s: (arrival number from 1, encoded packet), the last
      ``RECENT_PACKETS`` of them, in arrival order. Packet i, sent at s_i, is taken by the
      first channel poll at or after s_i (polls at ``poll_period_s``·j + ``poll_offset_s``)
      and delivered by the first poll at or after that one + ``delay_s``; it is in the
      output from then on. Depends on the time only (and on the log, which grows only into
      the future of every replay that reads it).
    """

    def __init__(self, log: PacketLog, *, delay_s: float = 0.0, poll_period_s: float = 0.01,
                 poll_offset_s: float = 0.009):
        super().__init__()
        check_period("PacketReplay.poll_period_s", poll_period_s)
        if not (math.isfinite(delay_s) and delay_s >= 0.0):
            raise ValueError(f"PacketReplay.delay_s = {delay_s!r} must be >= 0")
        self._log = log
        self._delay = float(delay_s)
        self._poll = float(poll_period_s)
        self._offset = float(poll_offset_s)
        self._output = self.DeclareAbstractOutputPort(
            "packets", lambda: AbstractValue.Make(()), self._calc, {self.time_ticket()})

    def get_packets_output_port(self):
        return self._output

    def _next_poll(self, time_s: float) -> float:
        j = math.ceil((time_s - self._offset) / self._poll - 1e-9)
        return j * self._poll + self._offset

    def delivery_time(self, send_time_s: float) -> float:
        """When a packet sent at ``send_time_s`` is delivered, s."""
        return self._next_poll(self._next_poll(send_time_s) + self._delay)

    def _calc(self, context, output):
        now = context.get_time()
        # Deliveries are in send order (one constant delay): count those due by now.
        sent = self._log.sent_by(now)
        delivered = sent
        while delivered > 0 and self.delivery_time(self._log.send_time(delivered - 1)) \
                > now + 1e-9:
            delivered -= 1
        first = max(0, delivered - RECENT_PACKETS)
        output.set_value(tuple((index + 1, self._log.payload(index))
                               for index in range(first, delivered)))
