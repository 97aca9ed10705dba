"""An LCM subscriber that bad bytes cannot kill: the live inputs of both processes.

Drake's ``LcmSubscriberSystem`` decodes inside ``DrakeLcm.HandleSubscriptions``, which the
``LcmInterfaceSystem`` calls while the simulator advances; one packet that does not decode
(garbage, a truncated datagram, another message type on the channel) makes
``Simulator.AdvanceTo`` raise, and the process dies. :class:`LcmSafeSubscriber` subscribes to
the raw bytes instead, decodes them itself, and turns every failure into data: the last good
message holds, and counters, a flag and the error text say what was thrown away. The receivers
(:class:`~telesmooth.systems.joint_command_receiver.JointCommandReceiver`,
:class:`~telesmooth.systems.haptic_command_receiver.HapticCommandReceiver`) take the flag as a
rejected message, so the robot keeps holding its last accepted command.

It is a thin Drake system around the pure step :func:`telesmooth.link.inbox.inbox_step`, which
examines the packets and keeps the window and the counts. The system itself does the I/O: its
LCM handler (called whenever the LCM is pumped, outside any event) or its receiver's poll only
collects the raw payloads, and its update hands them to the step and stores what it returns.
As with Drake's ``LcmSubscriberSystem``, the counts and the window live in the Context and
the payloads wait outside it: the first Context to update takes them, so drive one Simulator
per subscriber at a time (a second Context on the same system starts from nothing and sees
only what arrives after it is made).

It subscribes through Drake's ``DrakeLcm`` (pumped by the diagram's ``LcmInterfaceSystem``),
through an ``lcm.LCM`` of the ``lcm`` Python package, or through a
:class:`~telesmooth.link.udpm_receiver.UdpmReceiver`; the system pumps the last two itself at
every simulator step. Where every packet counts (the onboard uplink) use the receiver: a
``DrakeLcm`` subscription queues one message, so of a burst of packets that arrive between
two pumps only part reaches the handler (measured over udpm: 2 of 3 packets sent back to
back, 1 of 40), and nothing counts the rest; an ``lcm.LCM`` subscription queues
``queue_capacity`` of them and drops the rest uncounted too (measured: 40 commands among 10⁴
garbage packets, 14 arrived, 7707 packets vanished); the receiver's socket is the only queue,
sized, and it counts what the kernel drops (output ``dropped_count``).

Every packet larger than ``max_message_bytes`` is refused unread (counted as undecodable), so
a forged or oversized packet costs no decode, and is kept only until the step that counts
it.
"""

from __future__ import annotations

import logging
import math

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import EventStatus, LeafSystem

from telesmooth.link.inbox import (
    RECENT_PACKETS,
    InboxState,
    Packets,
    inbox_initial_state,
    inbox_params,
    inbox_step,
    nothing_new,
)
from telesmooth.link.udpm_receiver import DEFAULT_MAX_MESSAGE_BYTES, UdpmReceiver
from telesmooth.systems.codec_state import CodecState

__all__ = ["DEFAULT_MAX_MESSAGE_BYTES", "DEFAULT_QUEUE_CAPACITY", "RECENT_PACKETS",
           "LcmSafeSubscriber", "Packets"]

_logger = logging.getLogger(__name__)

DEFAULT_QUEUE_CAPACITY = RECENT_PACKETS
"""Packets an ``lcm.LCM`` subscription queues between two pumps (one per simulator step):
a burst up to this size reaches the handler whole, and fits the ``packets`` window."""

_MAX_PUMPED_PER_STEP = RECENT_PACKETS
"""Most packets one step takes from an ``lcm.LCM``: a flood cannot stall the simulator, and
what one step takes fits the ``packets`` window (the rest waits for the next step)."""


class _Arrivals:
    """The LCM handler's side: the raw payloads that arrived since the last step, in order.

    Like ``LcmSubscriberSystem``'s receive buffer this lives outside the Context (the handler
    runs inside ``HandleSubscriptions``, not in an event); the system's next update takes
    them. It is a separate object so that the subscription, which lives as long as the
    ``DrakeLcm``, does not keep the system alive.
    """

    def __init__(self):
        self._payloads: list = []

    def handle(self, data: bytes) -> None:
        """The LCM handler. It is called from C (``lcm_handle``), so it must never raise."""
        self._payloads.append(data)

    def take(self) -> list:
        """The payloads since the last call, oldest first."""
        payloads, self._payloads = self._payloads, []
        return payloads


class LcmSafeSubscriber(LeafSystem):
    r"""Subscribes to one LCM channel; outputs the last message that decoded, never raises.

    .. pydrake_system::

        name: LcmSafeSubscriber
        output_ports:
        - lcm_message
        - message_count
        - undecodable_count
        - message_undecodable
        - last_decode_error
        - packets
        - dropped_count

    - ``lcm_message``: the newest packet that decoded as ``lcm_type`` (abstract, an
      ``lcm_type`` instance, as ``LcmSubscriberSystem``'s output); a default-constructed
      message before any has.
    - ``message_count``: number of packets that decoded, (1,).
    - ``undecodable_count``: number of packets that did not (garbage, truncated, wrong type
      fingerprint, malformed body), (1,).
    - ``message_undecodable``: 1 if the newest packet did not decode, else 0, (1,); connect
      it to a receiver's input of the same name to count it as a rejected message.
    - ``last_decode_error``: why the newest undecodable packet did not decode (abstract str:
      channel, packet number, size, reason); ``""`` before any.
    - ``packets``: the last :data:`RECENT_PACKETS` raw packets, decodable or not, as a tuple
      of (packet number from 1, bytes), oldest first (abstract); for receivers that must
      examine every packet (duplicates, replays, forgeries), not only the newest.
    - ``dropped_count``: with a ``UdpmReceiver``, packets lost before this system could see
      them, (1,): dropped by the kernel (receive buffer full; the whole socket, all
      channels), oversized before reassembly, fragmented and never completed
      (:attr:`~telesmooth.link.udpm_receiver.UdpmCounts.lost`); NaN with a ``DrakeLcm`` or
      an ``lcm.LCM``, which do not tell.

    With a ``DrakeLcm``, packets arrive whenever someone pumps it (an ``LcmInterfaceSystem``
    in the diagram does so as the simulator advances, and then schedules a step at the
    current time); with an ``lcm.LCM``, this system pumps it (without waiting) at the start
    of every simulator step, so a packet is seen at the first step after it arrives (the
    diagram must step often enough: the onboard receiver polls every 10 ms). A per-step
    unrestricted update hands what has arrived to the step, so outputs change at the
    first step after a packet arrives, at the same simulation time, as with
    ``LcmSubscriberSystem``. If several packets arrive between two steps only the newest
    decodable one is on ``lcm_message`` (all are counted, and all are on ``packets``). State:
    :func:`~telesmooth.link.inbox.inbox_step`'s :class:`~telesmooth.link.inbox.InboxState`:
    its counts [message_count, undecodable_count, message_undecodable, dropped_count] as one
    vector (:class:`~telesmooth.systems.codec_state.CodecState`), and, as three abstract
    states since no float vector holds them, the raw bytes of the newest good packet (the
    output port decodes them), the error text and the window.
    """

    def __init__(self, *, channel: str, lcm_type, lcm,
                 queue_capacity: int = DEFAULT_QUEUE_CAPACITY,
                 max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
                 pump_period_s: float | None = None):
        """Subscribes to ``channel`` on ``lcm``.

        Args:
            channel: The LCM channel name.
            lcm_type: An lcm-gen Python message class (``decode``, ``_get_packed_fingerprint``).
            lcm: A ``DrakeLcm`` (it must outlive the simulation, and be pumped by an
                ``LcmInterfaceSystem``), an ``lcm.LCM`` of the ``lcm`` package, or a
                :class:`~telesmooth.link.udpm_receiver.UdpmReceiver` for ``channel`` (both
                pumped by this system at every step; they must outlive the simulation).
            queue_capacity: For an ``lcm.LCM``: packets its subscription queues between two
                steps (an integer >= 1). Ignored for a ``DrakeLcm`` (its queue holds one) and
                a ``UdpmReceiver`` (the socket's buffer is the queue).
            max_message_bytes: Packets larger than this are refused unread (an integer
                >= 1).
            pump_period_s: If given, take packets in (and update the outputs) every
                ``pump_period_s`` from t = 0 instead of at every simulator step. Give the
                period of the receiver that reads ``packets`` (polling at the same instants):
                it then sees each batch exactly once, whereas per-step pumping can take
                several batches between two polls, and the oldest leave the window of
                :data:`RECENT_PACKETS` unexamined.

        Raises:
            ValueError: naming the argument and the value.
        """
        super().__init__()
        if not isinstance(channel, str) or not channel:
            raise ValueError(f"channel = {channel!r} must be a non-empty string")
        for attribute in ("decode", "_get_packed_fingerprint"):
            if not hasattr(lcm_type, attribute):
                raise ValueError(f"lcm_type = {lcm_type!r} is not an lcm-gen message type "
                                 f"(it has no {attribute!r})")
        for name, value in (("queue_capacity", queue_capacity),
                            ("max_message_bytes", max_message_bytes)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} = {value!r} must be an integer >= 1")
        self._lcm_type = lcm_type
        self._params = inbox_params(channel, lcm_type, max_message_bytes)
        self._arrivals = _Arrivals()
        self._pumped_lcm = None
        self._receiver = None
        self._pump_errors: set[str] = set()
        if isinstance(lcm, UdpmReceiver):
            if lcm.channel != channel:
                raise ValueError(f"lcm = UdpmReceiver of channel {lcm.channel!r}; this "
                                 f"subscriber's channel is {channel!r}")
            self._receiver = lcm
        elif hasattr(lcm, "handle_timeout") and hasattr(lcm, "subscribe"):   # lcm.LCM
            arrivals = self._arrivals
            subscription = lcm.subscribe(channel, lambda _channel, data: arrivals.handle(data))
            subscription.set_queue_capacity(queue_capacity)
            self._pumped_lcm = lcm
        elif hasattr(lcm, "Subscribe"):                                     # DrakeLcm
            lcm.Subscribe(channel, self._arrivals.handle)
        else:
            raise ValueError(f"lcm = {lcm!r} must be a pydrake DrakeLcm or an lcm.LCM")
        initial = inbox_initial_state(
            dropped_count=0.0 if self._receiver is not None else math.nan)
        # The step's InboxCounts as one vector; its bytes, error text and window (which no
        # float vector holds) as three abstract states, in InboxState's field order.
        self._counts = CodecState(self, initial.counts)
        self._dropped_slice = self._counts.codec.field_slice("dropped_count")
        self._bytes_state, self._error_state, self._packets_state = (
            self.DeclareAbstractState(AbstractValue.Make(value)) for value in initial[1:])
        if pump_period_s is None:
            self.DeclarePerStepUnrestrictedUpdateEvent(self._update_received)
        else:
            if not (isinstance(pump_period_s, (int, float)) and math.isfinite(pump_period_s)
                    and pump_period_s > 0):
                raise ValueError(f"pump_period_s = {pump_period_s!r} must be a positive time")
            self.DeclarePeriodicUnrestrictedUpdateEvent(float(pump_period_s), 0.0,
                                                         self._update_received)
        self._message_output = self.DeclareAbstractOutputPort(
            "lcm_message", lambda: AbstractValue.Make(lcm_type()), self._calc_lcm_message)
        self._message_count_output = self._counts.output("message_count", "message_count")
        self._undecodable_count_output = self._counts.output("undecodable_count",
                                                             "undecodable_count")
        self._undecodable_output = self._counts.output("message_undecodable",
                                                       "newest_undecodable")
        self._error_output = self.DeclareStateOutputPort("last_decode_error", self._error_state)
        self._packets_output = self.DeclareStateOutputPort("packets", self._packets_state)
        self._dropped_output = self._counts.output("dropped_count", "dropped_count")

    def get_lcm_message_output_port(self):
        return self._message_output

    def get_message_count_output_port(self):
        return self._message_count_output

    def get_undecodable_count_output_port(self):
        return self._undecodable_count_output

    def get_message_undecodable_output_port(self):
        return self._undecodable_output

    def get_last_decode_error_output_port(self):
        return self._error_output

    def get_packets_output_port(self):
        return self._packets_output

    def get_dropped_count_output_port(self):
        return self._dropped_output

    def inbox_state(self, context) -> InboxState:
        """The state of :func:`~telesmooth.link.inbox.inbox_step` in ``context``."""
        return InboxState(self._counts.get(context), *(
            context.get_abstract_state(index).get_value()
            for index in (self._bytes_state, self._error_state, self._packets_state)))

    def _calc_lcm_message(self, context, output):
        data = context.get_abstract_state(self._bytes_state).get_value()
        # These bytes decoded once in the handler, so decoding them again cannot fail.
        output.set_value(self._lcm_type.decode(data) if data else self._lcm_type())

    @property
    def pumps_its_own_lcm(self) -> bool:
        """Whether this system pumps its ``lcm.LCM`` or ``UdpmReceiver`` itself (each step)."""
        return self._pumped_lcm is not None or self._receiver is not None

    def _pump(self) -> None:
        """Hands the packets queued on the ``lcm.LCM`` to the handler (at most
        ``_MAX_PUMPED_PER_STEP``), without waiting."""
        try:
            for _ in range(_MAX_PUMPED_PER_STEP):
                if self._pumped_lcm.handle_timeout(0) <= 0:
                    break
        except OSError as error:
            # A broken socket must not kill the running diagram: the receiver then sees
            # silence (the onboard guard ramps the robot down). Logged once per kind.
            text = f"{type(error).__name__}: {error}"
            if text not in self._pump_errors:
                self._pump_errors.add(text)
                _logger.error("LCM receive on this channel failed (%s); no packets arrive "
                              "while it fails", text)

    def _update_received(self, context, state):
        dropped = math.nan
        if self._pumped_lcm is not None:
            self._pump()
        payloads = self._arrivals.take()
        if self._receiver is not None:
            payloads += self._receiver.poll(_MAX_PUMPED_PER_STEP)
            lost = self._receiver.counts()
            dropped = float(lost.lost) if lost.kernel_dropped is not None else math.nan
        dropped_before = self._counts.vector(context)[self._dropped_slice][0]
        if nothing_new(dropped_before, payloads, dropped):
            return EventStatus.DidNothing()    # most steps: nothing to unpack
        after = inbox_step(self._params, self.inbox_state(context), payloads, dropped)
        self._counts.store(state, after.counts)
        for index, value in zip((self._bytes_state, self._error_state, self._packets_state),
                                after[1:]):
            state.get_mutable_abstract_state(index).set_value(value)
        return EventStatus.Succeeded()
