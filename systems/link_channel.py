"""The ground-to-onboard link inside one simulation: delay, jitter, loss, duplication, reordering.

In-process runs normally wire the uplink's held command straight into the robot. With
``link.simulate`` the packet goes the way it goes between the two processes instead: the
ground's ``JointCommandSender`` forms (and signs) the ``lcmt_teleop_joint_command``, this
system encodes it and delivers the bytes according to a seeded
:class:`~telesmooth.link.faults.LinkFaultModel`, and the onboard ``JointCommandReceiver``
examines every delivered packet. The fate of packet k depends only on (seed, k)
(:meth:`LinkFaultModel.fate`), so the same configuration gives the same faults here and in
the ``telesmooth link-relay`` process between two real processes.
"""

from __future__ import annotations

import dataclasses

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import EventStatus, LeafSystem

from telesmooth.link.faults import LinkFaultConfig, LinkFaultModel
from telesmooth.systems.lcm_safe_subscriber import RECENT_PACKETS
from telesmooth.systems.timing import check_period

__all__ = ["LINK_COUNTS", "LinkChannel"]

LINK_COUNTS = ("sent", "delivered", "lost", "duplicated", "held_back")
"""The ``link_counts`` output, in this order."""


@dataclasses.dataclass(frozen=True)
class _LinkState:
    """Everything in flight (replaced as a whole; lives in an abstract state)."""

    last_key: tuple | None = None     # (session_id, seq) of the last packet taken from input
    sent: int = 0                     # packets taken from the input (packet index = sent − 1)
    in_flight: tuple = ()             # (delivery time, packet index, copy, bytes), sorted
    delivered: tuple = ()             # the last RECENT_PACKETS deliveries, (number, bytes)
    counts: tuple = (0, 0, 0, 0, 0)   # LINK_COUNTS


class LinkChannel(LeafSystem):
    r"""A simulated unreliable link for one LCM message stream.

    .. pydrake_system::

        name: LinkChannel
        input_ports:
        - lcm_message
        output_ports:
        - packets
        - link_counts

    - ``lcm_message``: the sender's current message (abstract, ``lcm_type``). A message is a
      new packet when its (session_id, seq) differs from the previous one's and seq ≥ 0
      (the sender's seq = −1 placeholder is not sent). It is sent at the first poll that
      sees it.
    - ``packets``: what arrived at the far end so far, as the
      :class:`~telesmooth.systems.lcm_safe_subscriber.LcmSafeSubscriber` ``packets`` output:
      a tuple of (arrival number from 1, bytes), the last ``RECENT_PACKETS`` of them.
    - ``link_counts``: (5,) packets sent, deliveries made, packets lost, duplicated and held
      back (:data:`LINK_COUNTS`).

    Every ``poll_period_s``: take a new packet from the input (encode it; its delivery times
    are ``LinkFaultModel.fate(index, now)``), then deliver every copy whose time has come, in
    delivery-time order. Delivery times are therefore quantised to the poll period.
    """

    def __init__(self, config: LinkFaultConfig = LinkFaultConfig(), *, lcm_type,
                 poll_period_s: float = 0.002):
        super().__init__()
        if not isinstance(config, LinkFaultConfig):
            raise ValueError(f"config = {config!r} must be a LinkFaultConfig")
        check_period("LinkChannel.poll_period_s", poll_period_s)
        self._model = LinkFaultModel(config)
        self._message_input = self.DeclareAbstractInputPort(
            "lcm_message", AbstractValue.Make(lcm_type()))
        self._state = self.DeclareAbstractState(AbstractValue.Make(_LinkState()))
        self.DeclarePeriodicUnrestrictedUpdateEvent(poll_period_s, 0.0, self._poll)
        self._packets_output = self.DeclareAbstractOutputPort(
            "packets", lambda: AbstractValue.Make(()),
            lambda c, o: o.set_value(self._link(c).delivered), {self.all_state_ticket()})
        self._counts_output = self.DeclareVectorOutputPort(
            "link_counts", len(LINK_COUNTS),
            lambda c, o: o.SetFromVector(self._link(c).counts), {self.all_state_ticket()})

    @property
    def config(self) -> LinkFaultConfig:
        return self._model.config

    def get_lcm_message_input_port(self):
        return self._message_input

    def get_packets_output_port(self):
        return self._packets_output

    def get_link_counts_output_port(self):
        return self._counts_output

    def counts(self, context) -> dict:
        """{name: count} of :data:`LINK_COUNTS` in ``context``."""
        return dict(zip(LINK_COUNTS, self._link(context).counts))

    def _link(self, context) -> _LinkState:
        return context.get_abstract_state(self._state).get_value()

    def _poll(self, context, state):
        link = self._link(context)
        now = context.get_time()
        sent, in_flight, counts = link.sent, list(link.in_flight), list(link.counts)
        last_key = link.last_key
        msg = self._message_input.Eval(context)
        key = (int(msg.session_id), int(msg.seq))
        if msg.seq >= 0 and key != last_key:
            last_key = key
            fate = self._model.fate(sent, now)
            payload = msg.encode()
            in_flight.extend((t, sent, copy, payload)
                             for copy, t in enumerate(fate.delivery_times_s))
            in_flight.sort(key=lambda item: item[:3])
            counts[0] += 1
            counts[2] += int(fate.lost)
            counts[3] += int(fate.duplicated)
            counts[4] += int(fate.held_back)
            sent += 1
        due = [item for item in in_flight if item[0] <= now]
        if not due and (sent, last_key) == (link.sent, link.last_key):
            return EventStatus.DidNothing()
        delivered = link.delivered
        number = delivered[-1][0] if delivered else 0
        new = tuple((number + k + 1, item[3]) for k, item in enumerate(due))
        counts[1] += len(due)
        state.get_mutable_abstract_state(self._state).set_value(_LinkState(
            last_key=last_key, sent=sent, in_flight=tuple(in_flight[len(due):]),
            delivered=(delivered + new)[-RECENT_PACKETS:], counts=tuple(counts)))
        return EventStatus.Succeeded()
