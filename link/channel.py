"""The ground-to-onboard link inside one simulation, as a pure step: what is in flight and what
has arrived.

At every poll (:class:`~telesmooth.systems.link_channel.LinkChannel` is the thin Drake system
around :func:`channel_step`): the sender's current message is a new packet when its
(session_id, seq) (a type without a session: its seq) differs from the previous one's and
seq ≥ 0 (the sender's seq = −1 placeholder is not sent); a new packet is encoded and put on the
:class:`~telesmooth.link.faults.LinkQueue`, whose seeded model decides when its copies arrive;
then every copy whose time has come is delivered, in delivery-time order, numbered from 1.
"""

from __future__ import annotations

import copy
import dataclasses

from telesmooth.link.faults import LinkFaultConfig, LinkQueue

__all__ = ["ChannelState", "channel_counts", "channel_initial_state", "channel_step"]


@dataclasses.dataclass(frozen=True)
class ChannelState:
    """Everything in flight (replaced as a whole by each step)."""

    last_key: tuple | None = None     # (session_id, seq) of the last packet taken from input
    queue: LinkQueue | None = None    # in flight; copied before any change
    delivered: tuple = ()             # the last deliveries kept, (number, bytes)
    delivered_count: int = 0

    def __deepcopy__(self, memo):
        # Immutable (the queue is copied before any change, channel_step), so a copy may
        # share it: Drake clones abstract state values at every update, and a deep copy of
        # the packets in flight made the deployed chain's link cost 60 % of a run.
        return self


def channel_initial_state(config: LinkFaultConfig) -> ChannelState:
    """Nothing sent, nothing in flight."""
    return ChannelState(queue=LinkQueue(config))


def channel_step(state: ChannelState, now: float, message, *,
                 keep: int) -> ChannelState | None:
    """The link after a poll at ``now`` that reads the sender's ``message`` (an LCM message
    with ``seq``, and ``session_id`` if its type has one), keeping the last ``keep``
    deliveries; None when the poll changes nothing (no new packet, nothing due)."""
    # Telemetry has no session: its seq alone numbers it.
    key = (int(getattr(message, "session_id", 0)), int(message.seq))
    new_packet = message.seq >= 0 and key != state.last_key
    next_time = state.queue.next_delivery_time()
    if not new_packet and (next_time is None or next_time > now):
        return None
    # The state's queue is never mutated: change a copy, return the copy.
    queue = copy.deepcopy(state.queue)
    if new_packet:
        queue.send(queue.counts()["sent"], now, message.encode())
    due = queue.due(now)
    number = state.delivered[-1][0] if state.delivered else 0
    new = tuple((number + k + 1, payload) for k, payload in enumerate(due))
    return ChannelState(last_key=key if new_packet else state.last_key, queue=queue,
                        delivered=(state.delivered + new)[-keep:],
                        delivered_count=state.delivered_count + len(due))


def channel_counts(state: ChannelState) -> dict:
    """{sent, delivered, lost, duplicated, held_back}: the link's counts so far."""
    model = state.queue.counts()
    return {"sent": model["sent"], "delivered": state.delivered_count,
            "lost": model["lost"], "duplicated": model["duplicated"],
            "held_back": model["reordered"]}
