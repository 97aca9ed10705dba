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
a forged or oversized packet costs neither a decode nor memory beyond the bound.
"""

from __future__ import annotations

import dataclasses
import logging
import math

from pydrake.common.value import AbstractValue
from pydrake.systems.framework import EventStatus, LeafSystem

from telesmooth.lcm_types import decode_exact
from telesmooth.link.udpm_receiver import DEFAULT_MAX_MESSAGE_BYTES, UdpmReceiver

__all__ = ["DEFAULT_MAX_MESSAGE_BYTES", "DEFAULT_QUEUE_CAPACITY", "RECENT_PACKETS",
           "LcmSafeSubscriber", "Packets"]

_logger = logging.getLogger(__name__)

_FINGERPRINT_BYTES = 8
"""lcm-gen Python types start every encoded message with an 8-byte type fingerprint."""

# Layout of the discrete status state.
_MESSAGE_COUNT, _UNDECODABLE_COUNT, _NEWEST_UNDECODABLE, _DROPPED_COUNT = range(4)


class Packets(tuple):
    """Raw packets ``(number, bytes)`` as an abstract state or output value: a tuple that a
    Context's copy shares instead of copying. Drake clones abstract values at every update
    (pydrake with ``copy.deepcopy``); the packets are immutable, and a deep copy of a
    256-packet window at every step of the operator's process was a quarter of its CPU."""

    __slots__ = ()

    def __deepcopy__(self, memo):
        return self

    def __copy__(self):
        return self


@dataclasses.dataclass(frozen=True)
class _Received:
    """What has arrived on the channel so far (cumulative; replaced as a whole)."""

    message_count: int = 0          # packets that decoded
    undecodable_count: int = 0      # packets that did not
    newest_undecodable: bool = False
    message_bytes: bytes = b""      # the newest packet that decoded (b"": none yet)
    last_error: str = ""            # why the newest undecodable packet did not decode
    recent: Packets = Packets()     # the last RECENT_PACKETS raw packets, (index, bytes)


RECENT_PACKETS = 256
"""How many raw packets the ``packets`` output keeps (at 4 Hz, a minute of uplink; a
receiver polled every 10 ms sees each of them)."""

DEFAULT_QUEUE_CAPACITY = RECENT_PACKETS
"""Packets an ``lcm.LCM`` subscription queues between two pumps (one per simulator step):
a burst up to this size reaches the handler whole, and fits the ``packets`` window."""

_MAX_PUMPED_PER_STEP = RECENT_PACKETS
"""Most packets one step takes from an ``lcm.LCM``: a flood cannot stall the simulator, and
what one step takes fits the ``packets`` window (the rest waits for the next step)."""


class _Inbox:
    """The LCM handler's side: classifies each packet and keeps a :class:`_Received`.

    Like ``LcmSubscriberSystem``'s receive buffer this lives outside the Context (the handler
    runs inside ``HandleSubscriptions``, not in an event); the system copies it into its state
    at the next simulator step. It is a separate object so that the subscription, which lives
    as long as the ``DrakeLcm``, does not keep the system alive.
    """

    def __init__(self, channel: str, lcm_type,
                 max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES):
        self._channel = channel
        self._lcm_type = lcm_type
        self._max_message_bytes = max_message_bytes
        self._fingerprint = lcm_type._get_packed_fingerprint()
        # One attribute, replaced atomically, so a reader never sees half an update.
        self.received = _Received()

    def handle(self, data: bytes) -> None:
        """The LCM handler. It is called from C (``lcm_handle``), so it must never raise."""
        previous = self.received
        packet = previous.message_count + previous.undecodable_count + 1
        if len(data) > self._max_message_bytes:
            # Refused unread: neither decoded nor kept (the window holds an empty stand-in).
            recent = Packets((previous.recent + ((packet, b""),))[-RECENT_PACKETS:])
            problem = (f"{len(data)} bytes, more than the {self._max_message_bytes}-byte bound "
                       "of a message (not decoded)")
        else:
            recent = Packets((previous.recent + ((packet, bytes(data)),))[-RECENT_PACKETS:])
            try:
                problem = self._why_undecodable(bytes(data))
            except Exception as error:  # noqa: BLE001 - nothing may escape into the C callback
                problem = f"{type(error).__name__}: {error}"
        if problem is None:
            self.received = dataclasses.replace(
                previous, message_count=previous.message_count + 1, newest_undecodable=False,
                message_bytes=bytes(data), recent=recent)
        else:
            self.received = dataclasses.replace(
                previous, undecodable_count=previous.undecodable_count + 1,
                newest_undecodable=True, recent=recent,
                last_error=(f"{self._channel}: packet {packet} ({len(data)} bytes) is not a "
                            f"valid {self._lcm_type.__name__}: {problem}"))

    def _why_undecodable(self, data: bytes) -> str | None:
        """None if ``data`` decodes as the channel's type, else the reason (for people)."""
        try:
            decode_exact(self._lcm_type, data)
        # lcm-gen decoders raise ValueError (wrong fingerprint) and struct.error (short or
        # malformed body), but a damaged string may also give UnicodeDecodeError, an absurd
        # array length MemoryError, ...: any failure means "not a message of this type".
        except Exception as error:  # noqa: BLE001
            head = data[:_FINGERPRINT_BYTES]
            if len(data) < _FINGERPRINT_BYTES:
                return (f"shorter than the {_FINGERPRINT_BYTES}-byte type fingerprint "
                        f"(starts {head!r})")
            if head != self._fingerprint:
                return (f"type fingerprint {head.hex()} is not {self._fingerprint.hex()} "
                        "(another message type on this channel, or garbage)")
            return f"the body does not decode ({type(error).__name__}: {error})"
        return None


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
    unrestricted update copies what has arrived into the state, so outputs change at the
    first step after a packet arrives, at the same simulation time, as with
    ``LcmSubscriberSystem``. If several packets arrive between two steps only the newest
    decodable one is on ``lcm_message`` (all are counted, and all are on ``packets``). State:
    the raw bytes of the newest good packet (the output port decodes them), the error text,
    and [message_count, undecodable_count, message_undecodable, dropped_count].
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
        self._inbox = _Inbox(channel, lcm_type, max_message_bytes)
        self._pumped_lcm = None
        self._receiver = None
        self._pump_errors: set[str] = set()
        if isinstance(lcm, UdpmReceiver):
            if lcm.channel != channel:
                raise ValueError(f"lcm = UdpmReceiver of channel {lcm.channel!r}; this "
                                 f"subscriber's channel is {channel!r}")
            self._receiver = lcm
        elif hasattr(lcm, "handle_timeout") and hasattr(lcm, "subscribe"):   # lcm.LCM
            inbox = self._inbox
            subscription = lcm.subscribe(channel, lambda _channel, data: inbox.handle(data))
            subscription.set_queue_capacity(queue_capacity)
            self._pumped_lcm = lcm
        elif hasattr(lcm, "Subscribe"):                                     # DrakeLcm
            lcm.Subscribe(channel, self._inbox.handle)
        else:
            raise ValueError(f"lcm = {lcm!r} must be a pydrake DrakeLcm or an lcm.LCM")
        self._bytes_state = self.DeclareAbstractState(AbstractValue.Make(b""))
        self._error_state = self.DeclareAbstractState(AbstractValue.Make(""))
        self._packets_state = self.DeclareAbstractState(AbstractValue.Make(Packets()))
        # [message_count, undecodable_count, message_undecodable, dropped_count (NaN: the
        # transport does not tell)].
        self._status_state = self.DeclareDiscreteState(
            [0.0, 0.0, 0.0, 0.0 if self._receiver is not None else math.nan])
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
        self._message_count_output = self.DeclareVectorOutputPort(
            "message_count", 1,
            lambda c, o: o.SetAtIndex(0, self._status(c)[_MESSAGE_COUNT]))
        self._undecodable_count_output = self.DeclareVectorOutputPort(
            "undecodable_count", 1,
            lambda c, o: o.SetAtIndex(0, self._status(c)[_UNDECODABLE_COUNT]))
        self._undecodable_output = self.DeclareVectorOutputPort(
            "message_undecodable", 1,
            lambda c, o: o.SetAtIndex(0, self._status(c)[_NEWEST_UNDECODABLE]))
        self._error_output = self.DeclareStateOutputPort("last_decode_error", self._error_state)
        self._packets_output = self.DeclareStateOutputPort("packets", self._packets_state)
        self._dropped_output = self.DeclareVectorOutputPort(
            "dropped_count", 1, lambda c, o: o.SetAtIndex(0, self._status(c)[_DROPPED_COUNT]))

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

    def _status(self, context):
        return context.get_discrete_state(self._status_state).get_value()

    def _calc_lcm_message(self, context, output):
        data = context.get_abstract_state(self._bytes_state).get_value()
        # These bytes decoded once in the handler, so decoding them again cannot fail.
        output.set_value(self._lcm_type.decode(data) if data else self._lcm_type())

    @property
    def pumps_its_own_lcm(self) -> bool:
        """Whether this system pumps its ``lcm.LCM`` or ``UdpmReceiver`` itself (each step)."""
        return self._pumped_lcm is not None or self._receiver is not None

    def _pump(self) -> None:
        """Hands the packets queued on the ``lcm.LCM`` to the inbox (at most
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
        elif self._receiver is not None:
            for payload in self._receiver.poll(_MAX_PUMPED_PER_STEP):
                self._inbox.handle(payload)
            lost = self._receiver.counts()
            dropped = float(lost.lost) if lost.kernel_dropped is not None else math.nan
        received = self._inbox.received
        status = self._status(context)
        counts = (received.message_count, received.undecodable_count)
        same_drops = (status[_DROPPED_COUNT] == dropped
                      or (math.isnan(dropped) and math.isnan(status[_DROPPED_COUNT])))
        if counts == (status[_MESSAGE_COUNT], status[_UNDECODABLE_COUNT]) and same_drops:
            return EventStatus.DidNothing()
        state.get_mutable_abstract_state(self._bytes_state).set_value(received.message_bytes)
        state.get_mutable_abstract_state(self._error_state).set_value(received.last_error)
        state.get_mutable_abstract_state(self._packets_state).set_value(received.recent)
        state.get_mutable_discrete_state(self._status_state).SetFromVector(
            [received.message_count, received.undecodable_count,
             float(received.newest_undecodable), dropped])
        return EventStatus.Succeeded()
