"""Receiving one LCM channel from a ``udpm://`` bus so that every packet is accounted for.

The ``lcm`` package drops packets where nobody can count them: the kernel drops datagrams when
the socket's receive buffer is full, LCM drops a message when the subscription's queue is full
(``set_queue_capacity``) and a fragmented message when a fragment is missing. Measured: 40
signed commands published among 10⁴ garbage packets on the uplink channel, received through an
``lcm.LCM`` subscription (queue 256) pumped every 10 ms: 14 commands arrived, and 7707 of the
10 040 packets were never seen by the handler, nor counted anywhere.

:class:`UdpmReceiver` reads the multicast group with a socket of its own instead, so that the
kernel's receive buffer is the only queue, and accounts for every datagram that reaches it:

* the receive buffer is sized (``receive_buffer_bytes``, granted up to the system's
  ``net.core.rmem_max``; :attr:`UdpmReceiver.receive_buffer_bytes` is what was granted);
* each LCM message on the channel is delivered (``poll`` returns its payload), unless it is
  larger than ``max_message_bytes``, which is counted as ``oversized`` and never decoded nor
  reassembled beyond its first fragment;
* datagrams the kernel dropped (buffer full) are counted from the socket's own drop counter
  (``/proc/net/udp``, Linux), fragmented messages that never completed as ``incomplete``,
  datagrams that are not LCM packets as ``not_lcm``; messages on other channels are
  ``other_channel`` (not a loss: the bus is shared).

So every datagram that reached the host for this group and port is in exactly one of:
delivered, oversized, incomplete (its fragments), not_lcm, other_channel, kernel_dropped, or
still waiting in the socket (:meth:`UdpmReceiver.poll` takes at most ``limit`` a call).

The wire format is LCM's (``lcm_udpm.c``): a short message is ``magic "LC02", seqno (4 bytes),
channel, NUL, payload`` in one datagram; a long one is fragments ``magic "LC03", seqno,
message size, fragment offset (4 bytes each), fragment number, fragment count (2 bytes each)``,
the first fragment carrying ``channel, NUL`` before its data.
"""

from __future__ import annotations

import dataclasses
import ipaddress
import os
import socket
import struct
import time
import urllib.parse

__all__ = ["DEFAULT_MAX_MESSAGE_BYTES", "DEFAULT_RECEIVE_BUFFER_BYTES", "UdpmCounts",
           "UdpmReceiver"]

DEFAULT_RECEIVE_BUFFER_BYTES = 8 << 20
"""Receive buffer asked for, bytes; the kernel grants at most ``net.core.rmem_max`` (often
208 KiB by default; raise it with ``sysctl net.core.rmem_max=8388608``)."""

DEFAULT_MAX_MESSAGE_BYTES = 64 << 10
"""Largest message delivered, bytes: an uplink command of 6 joints is about 300 bytes, so this
leaves room for 200+ joints while bounding what a forged fragment header can make us hold."""

MAX_INCOMPLETE_MESSAGES = 8
"""Fragmented messages being reassembled at once; the oldest is dropped (and counted) first."""

_SHORT = struct.Struct(">II")            # magic, seqno
_LONG = struct.Struct(">IIIIHH")         # magic, seqno, size, offset, fragment no, count
_MAGIC_SHORT = 0x4C433032                # "LC02"
_MAGIC_LONG = 0x4C433033                 # "LC03"
_MAX_CHANNEL = 63                        # LCM_MAX_CHANNEL_NAME_LENGTH


@dataclasses.dataclass(frozen=True)
class UdpmCounts:
    """Where the datagrams that reached the socket went (cumulative).

    Attributes:
        delivered: messages on the channel handed to the caller.
        oversized: messages on the channel larger than ``max_message_bytes`` (not delivered).
        incomplete: fragmented messages that never completed (a fragment lost or evicted).
        not_lcm: datagrams that are not LCM packets (bad magic, too short, bad channel).
        other_channel: messages on other channels (ignored; not a loss).
        kernel_dropped: datagrams the kernel dropped because the receive buffer was full
            (None where the system does not tell, i.e. outside Linux).
    """

    delivered: int = 0
    oversized: int = 0
    incomplete: int = 0
    not_lcm: int = 0
    other_channel: int = 0
    kernel_dropped: int | None = 0

    @property
    def lost(self) -> int:
        """Packets that were meant for someone and never delivered: kernel drops, incomplete
        and oversized messages (garbage that is not LCM is counted apart)."""
        return (self.kernel_dropped or 0) + self.incomplete + self.oversized


class UdpmReceiver:
    """One channel of an LCM ``udpm://`` bus, read with a non-blocking socket of our own.

    Args:
        url: ``udpm://GROUP:PORT?ttl=0`` (the group must be a multicast address).
        channel: The LCM channel delivered.
        receive_buffer_bytes: SO_RCVBUF asked for.
        max_message_bytes: Largest message delivered (see :data:`DEFAULT_MAX_MESSAGE_BYTES`).

    Raises:
        ValueError: a URL that is not udpm://, a group that is not multicast, a bad port, or
            a socket that cannot be opened (the message names the URL).
    """

    def __init__(self, url: str, channel: str, *,
                 receive_buffer_bytes: int = DEFAULT_RECEIVE_BUFFER_BYTES,
                 max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES):
        parts = urllib.parse.urlsplit(url)
        if parts.scheme != "udpm":
            raise ValueError(f"url = {url!r} must be a udpm:// LCM URL")
        try:
            group = ipaddress.IPv4Address(parts.hostname or "239.255.76.67")
            port = parts.port or 7667
        except ValueError as error:
            raise ValueError(f"url = {url!r}: {error}") from None
        if not group.is_multicast:
            raise ValueError(f"url = {url!r}: {group} is not a multicast group")
        if not isinstance(channel, str) or not channel or len(channel) > _MAX_CHANNEL:
            raise ValueError(f"channel = {channel!r} must be an LCM channel name")
        for name, value in (("receive_buffer_bytes", receive_buffer_bytes),
                            ("max_message_bytes", max_message_bytes)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} = {value!r} must be a positive integer")
        self.url = url
        self.channel = channel
        self.max_message_bytes = max_message_bytes
        self._channel_bytes = channel.encode("utf-8")
        try:
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, receive_buffer_bytes)
            sock.bind((str(group), port))
            membership = struct.pack("4s4s", group.packed, socket.inet_aton("0.0.0.0"))
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, membership)
            sock.setblocking(False)
        except OSError as error:
            raise ValueError(f"url = {url!r}: cannot receive on it ({error.strerror})") from None
        self._socket = sock
        # Linux doubles the value asked for (bookkeeping overhead) and caps it at rmem_max.
        self.receive_buffer_bytes = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        self._inode = os.fstat(sock.fileno()).st_ino
        self._fragments: dict = {}       # (sender, seqno) -> [size, remaining, data, started]
        self._counts = UdpmCounts()
        self._kernel_checked_at = -1.0

    # --- receiving ---

    def poll(self, limit: int = 256) -> list[bytes]:
        """The payloads of the messages on the channel received since the last call, oldest
        first, at most ``limit`` datagrams read (the rest wait in the socket). Never blocks."""
        payloads = []
        for _ in range(limit):
            try:
                datagram, sender = self._socket.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                break
            payload = self._classify(datagram, sender)
            if payload is not None:
                payloads.append(payload)
        return payloads

    def counts(self, *, refresh_s: float = 0.05) -> UdpmCounts:
        """What has happened to the datagrams so far (the kernel's drop counter is read at
        most every ``refresh_s`` seconds)."""
        now = time.monotonic()
        if now - self._kernel_checked_at >= refresh_s:
            self._kernel_checked_at = now
            self._bump(kernel_dropped=_kernel_drops(self._inode))
        return self._counts

    def close(self) -> None:
        self._socket.close()

    def fileno(self) -> int:
        return self._socket.fileno()

    # --- the LCM wire format ---

    def _bump(self, **changes) -> None:
        counts = self._counts
        values = {}
        for name, change in changes.items():
            if name == "kernel_dropped":
                values[name] = change        # an absolute reading (or None)
            else:
                values[name] = getattr(counts, name) + change
        self._counts = dataclasses.replace(counts, **values)

    def _classify(self, datagram: bytes, sender) -> bytes | None:
        if len(datagram) < _SHORT.size:
            self._bump(not_lcm=1)
            return None
        magic, seqno = _SHORT.unpack_from(datagram)
        if magic == _MAGIC_SHORT:
            end = datagram.find(b"\0", _SHORT.size, _SHORT.size + _MAX_CHANNEL + 1)
            if end < 0:
                self._bump(not_lcm=1)
                return None
            if datagram[_SHORT.size:end] != self._channel_bytes:
                self._bump(other_channel=1)
                return None
            payload = datagram[end + 1:]
            if len(payload) > self.max_message_bytes:
                self._bump(oversized=1)
                return None
            self._bump(delivered=1)
            return payload
        if magic == _MAGIC_LONG and len(datagram) >= _LONG.size:
            return self._fragment(datagram, sender)
        self._bump(not_lcm=1)
        return None

    def _fragment(self, datagram: bytes, sender) -> bytes | None:
        _, seqno, size, offset, number, count = _LONG.unpack_from(datagram)
        data = datagram[_LONG.size:]
        key = (sender, seqno)
        if number == 0:
            end = data.find(b"\0", 0, _MAX_CHANNEL + 1)
            if end < 0 or count == 0:
                self._bump(not_lcm=1)
                return None
            if data[:end] != self._channel_bytes:
                self._bump(other_channel=1)
                self._fragments[key] = None      # its other fragments are not ours either
                self._evict()
                return None
            if size > self.max_message_bytes:
                self._bump(oversized=1)
                self._fragments[key] = None      # counted once, its fragments ignored
                self._evict()
                return None
            data = data[end + 1:]
        entry = self._fragments.get(key, False)
        if entry is None:                        # a message already counted (other/oversized)
            self._forget_when_done(key, number, count)
            return None
        if entry is False:
            if size > self.max_message_bytes:   # fragment 0 lost, and too big anyway
                self._fragments[key] = None
                self._bump(oversized=1)
                self._evict()
                return None
            entry = [size, count, bytearray(size), time.monotonic(), None]
            self._fragments[key] = entry
            self._evict()
        if entry[0] != size or offset + len(data) > size:
            self._bump(not_lcm=1)
            return None
        entry[2][offset:offset + len(data)] = data
        entry[1] -= 1
        if number == 0:
            entry[4] = True                      # the channel is ours
        if entry[1] > 0:
            return None
        del self._fragments[key]
        if entry[4] is None:                     # fragment 0 never came: channel unknown
            self._bump(incomplete=1)
            return None
        self._bump(delivered=1)
        return bytes(entry[2])

    def _forget_when_done(self, key, number: int, count: int) -> None:
        if number == count - 1:
            self._fragments.pop(key, None)

    def _evict(self) -> None:
        """Keeps at most MAX_INCOMPLETE_MESSAGES in reassembly; the oldest is a loss."""
        while len(self._fragments) > MAX_INCOMPLETE_MESSAGES:
            key = next(iter(self._fragments))
            entry = self._fragments.pop(key)
            if entry is not None:
                self._bump(incomplete=1)


def _kernel_drops(inode: int) -> int | None:
    """The drop counter of the UDP socket ``inode`` (``/proc/net/udp``'s last column), or None
    where it cannot be read."""
    try:
        with open("/proc/net/udp", encoding="ascii") as table:
            next(table)
            for line in table:
                fields = line.split()
                if len(fields) >= 13 and fields[9] == str(inode):
                    return int(fields[12])
    except (OSError, ValueError, StopIteration):
        return None
    return None
