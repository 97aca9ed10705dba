"""The ground-to-onboard link inside one simulation: delay, jitter, loss, duplication, reordering.

In the deployed chain (``chain: deployed``, the default) every uplink packet goes the way it
goes between the two processes: the ground's ``JointCommandSender`` forms (and signs) the
``lcmt_teleop_joint_command``, this
system encodes it and delivers the bytes according to a seeded
:class:`~telesmooth.link.faults.LinkFaultModel`, and the onboard ``JointCommandReceiver``
examines every delivered packet. The fate of packet k depends only on (seed, k)
(:meth:`LinkFaultModel.fate`), so the same configuration gives the same faults here and in
the ``telesmooth link-relay`` process between two real processes. A thin Drake system around
the pure step :func:`telesmooth.link.channel.channel_step`.
"""

from __future__ import annotations

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import EventStatus, LeafSystem

from telesmooth.link.channel import (
    ChannelState,
    channel_counts,
    channel_initial_state,
    channel_step,
)
from telesmooth.link.faults import LinkFaultConfig
from telesmooth.systems.lcm_safe_subscriber import RECENT_PACKETS
from telesmooth.systems.timing import check_period

__all__ = ["LINK_COUNTS", "LinkChannel"]

LINK_COUNTS = ("sent", "delivered", "lost", "duplicated", "held_back")
"""The ``link_counts`` output, in this order."""


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
      new packet when its (session_id, seq) (a type without a session: its seq) differs
      from the previous one's and seq ≥ 0
      (the sender's seq = −1 placeholder is not sent). It is sent at the first poll that
      sees it.
    - ``packets``: what arrived at the far end so far, as the
      :class:`~telesmooth.systems.lcm_safe_subscriber.LcmSafeSubscriber` ``packets`` output:
      a tuple of (arrival number from 1, bytes), the last ``RECENT_PACKETS`` of them.
    - ``link_counts``: (5,) packets sent, deliveries made, packets lost, duplicated and held
      back (:data:`LINK_COUNTS`).

    Every ``poll_period_s`` (from ``poll_offset_s``): take a new packet from the input
    (encode it and put it on a :class:`~telesmooth.link.faults.LinkQueue`, whose model
    decides its delivery times from (seed, packet index)), then deliver every copy whose time
    has come, in delivery-time order. Delivery times are therefore quantised to the poll
    grid. A receiver that polls every ``poll_period_s`` from offset 0 sees what this channel
    delivers at its next poll; polling at the receiver's period just before each of its
    polls (offset 0.9 period) hands it every packet as early as a faster channel would,
    with one event per receiver poll (the deployed chain, MakeTeleoperationDiagram).
    """

    def __init__(self, config: LinkFaultConfig = LinkFaultConfig(), *, lcm_type,
                 poll_period_s: float = 0.002, poll_offset_s: float = 0.0):
        super().__init__()
        if not isinstance(config, LinkFaultConfig):
            raise ValueError(f"config = {config!r} must be a LinkFaultConfig")
        check_period("LinkChannel.poll_period_s", poll_period_s)
        if not 0.0 <= poll_offset_s < poll_period_s:
            raise ValueError(f"LinkChannel.poll_offset_s = {poll_offset_s!r} must be >= 0 and "
                             f"below poll_period_s = {poll_period_s!r}")
        self._config = config
        self._message_input = self.DeclareAbstractInputPort(
            "lcm_message", AbstractValue.Make(lcm_type()))
        self._state = self.DeclareAbstractState(AbstractValue.Make(
            channel_initial_state(config)))
        self.DeclarePeriodicUnrestrictedUpdateEvent(poll_period_s, poll_offset_s, self._poll)
        self._packets_output = self.DeclareAbstractOutputPort(
            "packets", lambda: AbstractValue.Make(()),
            lambda c, o: o.set_value(self._link(c).delivered), {self.all_state_ticket()})
        self._counts_output = self.DeclareVectorOutputPort(
            "link_counts", len(LINK_COUNTS),
            lambda c, o: o.SetFromVector([self.counts(c)[name] for name in LINK_COUNTS]),
            {self.all_state_ticket()})

    @property
    def config(self) -> LinkFaultConfig:
        return self._config

    def get_lcm_message_input_port(self):
        return self._message_input

    def get_packets_output_port(self):
        return self._packets_output

    def get_link_counts_output_port(self):
        return self._counts_output

    def counts(self, context) -> dict:
        """{name: count} of :data:`LINK_COUNTS` in ``context``."""
        return channel_counts(self._link(context))

    def _link(self, context) -> ChannelState:
        return context.get_abstract_state(self._state).get_value()

    def _poll(self, context, state):
        after = channel_step(self._link(context), context.get_time(),
                             self._message_input.Eval(context), keep=RECENT_PACKETS)
        if after is None:
            return EventStatus.DidNothing()
        state.get_mutable_abstract_state(self._state).set_value(after)
        return EventStatus.Succeeded()
