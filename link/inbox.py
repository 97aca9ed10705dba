"""What has arrived on one LCM channel, as a pure step: the packet window and its counts.

:func:`inbox_step` ``(params, state, payloads, dropped) -> state`` examines the raw packets
taken from the channel since the previous step, oldest first, and never raises: a packet larger
than ``max_message_bytes`` is refused unread (counted as undecodable, kept in the window as
``b""``); any other packet is decodable when the channel type's exact decoder accepts it, and
otherwise counted as undecodable with the reason (shorter than the type fingerprint, another
fingerprint, a body that does not decode). Packets are numbered from 1 in arrival order; the
window keeps the last ``window`` of them, decodable or not; the newest decodable packet's bytes
are kept, and the newest undecodable one's error text. ``dropped`` is what the transport says
it lost before the packets reached the step (NaN where it does not tell); the step keeps the
value given. With no payload and the same ``dropped`` it returns the state it was given.

:class:`~telesmooth.systems.lcm_safe_subscriber.LcmSafeSubscriber` is the thin Drake system
around it: its LCM handler (or its receiver's poll) only collects the payloads, and its
per-step update hands them to the step. The counts (:class:`InboxCounts`) are numbers and live
in one Context vector; the bytes, the error text and the window cannot, and live in Drake
abstract states.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Sequence
from typing import NamedTuple

from telesmooth.lcm_types import decode_exact
from telesmooth.link.udpm_receiver import DEFAULT_MAX_MESSAGE_BYTES

__all__ = ["FINGERPRINT_BYTES", "InboxCounts", "InboxParams", "InboxState", "Packets",
           "RECENT_PACKETS", "inbox_initial_state", "inbox_params", "inbox_step",
           "nothing_new", "why_undecodable"]

FINGERPRINT_BYTES = 8
"""lcm-gen Python types start every encoded message with an 8-byte type fingerprint."""

RECENT_PACKETS = 256
"""How many raw packets the window keeps (at 4 Hz, a minute of uplink; a receiver polled every
10 ms sees each of them)."""


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
class InboxParams:
    """The channel and what a packet on it must be.

    Attributes:
        channel: The LCM channel name (in the error text).
        type_name: The channel's message type name (in the error text).
        decode: Decodes a packet exactly, raising on anything that is not a message of the
            type (``functools.partial(decode_exact, lcm_type)``).
        fingerprint: The type's packed 8-byte fingerprint.
        max_message_bytes: Packets larger than this are refused unread.
        window: How many packets the window keeps.
    """

    channel: str
    type_name: str
    decode: Callable[[bytes], object]
    fingerprint: bytes
    max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES
    window: int = RECENT_PACKETS


def inbox_params(channel: str, lcm_type, max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
                 window: int = RECENT_PACKETS) -> InboxParams:
    """The parameters for ``channel`` carrying the lcm-gen type ``lcm_type``."""
    return InboxParams(channel=channel, type_name=lcm_type.__name__,
                       decode=functools.partial(decode_exact, lcm_type),
                       fingerprint=lcm_type._get_packed_fingerprint(),
                       max_message_bytes=max_message_bytes, window=window)


class InboxCounts(NamedTuple):
    """The counts (one Context vector, in this order)."""

    message_count: int = 0          # packets that decoded
    undecodable_count: int = 0      # packets that did not
    newest_undecodable: bool = False
    dropped_count: float = math.nan  # lost before the step, as the transport says; NaN: untold


class InboxState(NamedTuple):
    """What has arrived on the channel so far (cumulative)."""

    counts: InboxCounts
    message_bytes: bytes = b""      # the newest packet that decoded (b"": none yet)
    last_error: str = ""            # why the newest undecodable packet did not decode
    recent: Packets = Packets()     # the last ``window`` raw packets, (number, bytes)


def inbox_initial_state(*, dropped_count: float = math.nan) -> InboxState:
    """Nothing arrived; ``dropped_count`` 0.0 for a transport that counts its losses."""
    return InboxState(InboxCounts(dropped_count=dropped_count))


def why_undecodable(params: InboxParams, data: bytes) -> str | None:
    """None if ``data`` decodes as the channel's type, else the reason (for people)."""
    try:
        params.decode(data)
    # lcm-gen decoders raise ValueError (wrong fingerprint) and struct.error (short or
    # malformed body), but a damaged string may also give UnicodeDecodeError, an absurd
    # array length MemoryError, ...: any failure means "not a message of this type".
    except Exception as error:  # noqa: BLE001
        head = data[:FINGERPRINT_BYTES]
        if len(data) < FINGERPRINT_BYTES:
            return (f"shorter than the {FINGERPRINT_BYTES}-byte type fingerprint "
                    f"(starts {head!r})")
        if head != params.fingerprint:
            return (f"type fingerprint {head.hex()} is not {params.fingerprint.hex()} "
                    "(another message type on this channel, or garbage)")
        return f"the body does not decode ({type(error).__name__}: {error})"
    return None


def _take(params: InboxParams, state: InboxState, data: bytes) -> InboxState:
    """The state after one more packet."""
    counts = state.counts
    packet = counts.message_count + counts.undecodable_count + 1
    if len(data) > params.max_message_bytes:
        # Refused unread: neither decoded nor kept (the window holds an empty stand-in).
        recent = Packets((state.recent + ((packet, b""),))[-params.window:])
        problem = (f"{len(data)} bytes, more than the {params.max_message_bytes}-byte bound "
                   "of a message (not decoded)")
    else:
        recent = Packets((state.recent + ((packet, bytes(data)),))[-params.window:])
        try:
            problem = why_undecodable(params, bytes(data))
        except Exception as error:  # noqa: BLE001 - no packet may stop the simulator
            problem = f"{type(error).__name__}: {error}"
    if problem is None:
        return state._replace(
            counts=counts._replace(message_count=counts.message_count + 1,
                                   newest_undecodable=False),
            message_bytes=bytes(data), recent=recent)
    return state._replace(
        counts=counts._replace(undecodable_count=counts.undecodable_count + 1,
                               newest_undecodable=True),
        recent=recent,
        last_error=(f"{params.channel}: packet {packet} ({len(data)} bytes) is not a "
                    f"valid {params.type_name}: {problem}"))


def nothing_new(dropped_before: float, payloads: Sequence[bytes], dropped: float) -> bool:
    """Whether a step with ``payloads`` and the transport's ``dropped`` count changes nothing
    after a state whose dropped count is ``dropped_before``: no payload and the same count
    (NaN equal to NaN). A system may ask this before it reads the rest of its state."""
    same_drops = dropped_before == dropped or (math.isnan(dropped) and math.isnan(dropped_before))
    return not payloads and same_drops


def inbox_step(params: InboxParams, state: InboxState, payloads: Sequence[bytes],
               dropped: float) -> InboxState:
    """The state after ``payloads`` (oldest first) and the transport's ``dropped`` count.

    Returns ``state`` itself when there is no payload and ``dropped`` equals the state's
    (NaN equal to NaN): nothing changed.
    """
    if nothing_new(state.counts.dropped_count, payloads, dropped):
        return state
    for data in payloads:
        state = _take(params, state, data)
    return state._replace(counts=state.counts._replace(dropped_count=dropped))
