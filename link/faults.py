"""A seeded model of an unreliable one-way link: delay, jitter, loss, duplication, reordering.

The 4 Hz uplink of a space robot crosses a relay chain whose faults the teleoperation chain
must survive. :class:`LinkFaultModel` decides the fate of every packet from the pair
``(config.seed, packet_index)`` alone, so the in-process simulation (a Drake system built on
:class:`LinkQueue`) and the real-time relay between two processes
(:mod:`telesmooth.link.relay`) give packet ``k`` exactly the same fate, whatever order they
ask in and however many packets they ask about.

Fate of packet ``k`` sent at ``t_send`` (times in seconds on the sender's clock):

* lost if ``t_send`` lies in an outage window ``[start, end)``, or with probability
  ``loss_probability``; a lost packet has no copy at all;
* else held back by ``reorder_delay_s`` with probability ``reorder_probability``
  (``hold = reorder_delay_s`` or ``0``), so that later packets overtake it;
* first copy delivered at ``t_send + delay_s + hold + jitter_s · u₁``;
* with probability ``duplicate_probability`` a second copy, travelling on its own, delivered
  at ``t_send + delay_s + hold + duplicate_spacing_s + jitter_s · u₂``;

with ``u₁, u₂`` uniform in ``[0, 1)``. Jitter larger than the sending period lets packets
overtake each other (reordering) without any hold.
"""

from __future__ import annotations

import dataclasses
import heapq
import math
import numbers
from collections.abc import Mapping
from typing import Any, NamedTuple

import numpy as np

__all__ = [
    "Delivery",
    "LinkFaultConfig",
    "LinkFaultModel",
    "LinkQueue",
    "PacketFate",
]


def _check_real(field: str, value) -> float:
    """Returns ``float(value)`` for a real number (bools and strings rejected)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise ValueError(f"{field} = {value!r} must be a number")
    return float(value)


def _check_nonnegative(field: str, value) -> float:
    number = _check_real(field, value)
    if not math.isfinite(number) or number < 0.0:
        raise ValueError(f"{field} = {value!r} must be finite and >= 0")
    return number


def _check_probability(field: str, value) -> float:
    number = _check_real(field, value)
    if not 0.0 <= number <= 1.0:   # also rejects NaN
        raise ValueError(f"{field} = {value!r} must be a probability in [0, 1]")
    return number


def _check_outages(value) -> tuple[tuple[float, float], ...]:
    if isinstance(value, (str, bytes, Mapping)) or not hasattr(value, "__iter__"):
        raise ValueError(f"outages = {value!r} must be a list of [start_s, end_s) windows")
    windows = []
    for index, window in enumerate(value):
        field = f"outages[{index}]"
        if isinstance(window, (str, bytes, Mapping)) or not hasattr(window, "__len__") \
                or len(window) != 2:
            raise ValueError(f"{field} = {window!r} must be a pair [start_s, end_s]")
        start = _check_real(f"{field} start", window[0])
        end = _check_real(f"{field} end", window[1])
        if not math.isfinite(start):
            raise ValueError(f"{field} = {window!r}: start {start!r} s must be finite")
        if math.isnan(end) or end <= start:
            raise ValueError(f"{field} = {window!r}: end must be > start (an end of inf "
                             "means the link never comes back)")
        windows.append((start, end))
    return tuple(windows)


@dataclasses.dataclass(frozen=True)
class LinkFaultConfig:
    """Faults of one direction of the link. The defaults are a perfect link.

    Attributes:
        delay_s: Constant one-way delay, s (≥ 0; may be several seconds).
        jitter_s: Extra delay per packet, uniform in ``[0, jitter_s]``, s. Jitter above the
            sending period reorders packets.
        loss_probability: Probability that a packet is lost, in ``[0, 1]``.
        duplicate_probability: Probability that a (not lost) packet is delivered twice.
        duplicate_spacing_s: The duplicate travels ``duplicate_spacing_s`` behind the first
            copy, plus its own jitter, s.
        reorder_probability: Probability that a (not lost) packet is held back by
            ``reorder_delay_s`` so that later packets overtake it.
        reorder_delay_s: Hold of a reordered packet, s.
        outages: Send-time windows ``(start_s, end_s)``, half-open ``[start, end)``, in which
            every packet is lost (a link drop); ``end_s`` may be ``inf``.
        seed: Seed (integer ≥ 0) of the per-packet random draws.
    """

    delay_s: float = 0.0
    jitter_s: float = 0.0
    loss_probability: float = 0.0
    duplicate_probability: float = 0.0
    duplicate_spacing_s: float = 0.01
    reorder_probability: float = 0.0
    reorder_delay_s: float = 0.3
    outages: tuple[tuple[float, float], ...] = ()
    seed: int = 0

    def __post_init__(self):
        # Normalise (ints → floats, lists → tuples) so that equal configs compare equal.
        for field in ("delay_s", "jitter_s", "duplicate_spacing_s", "reorder_delay_s"):
            object.__setattr__(self, field, _check_nonnegative(field, getattr(self, field)))
        for field in ("loss_probability", "duplicate_probability", "reorder_probability"):
            object.__setattr__(self, field, _check_probability(field, getattr(self, field)))
        object.__setattr__(self, "outages", _check_outages(self.outages))
        if (isinstance(self.seed, bool) or not isinstance(self.seed, numbers.Integral)
                or self.seed < 0):
            raise ValueError(f"seed = {self.seed!r} must be an integer >= 0")
        object.__setattr__(self, "seed", int(self.seed))

    @property
    def enabled(self) -> bool:
        """True if this link differs from a perfect, instantaneous one."""
        return (self.delay_s > 0.0 or self.jitter_s > 0.0 or self.loss_probability > 0.0
                or self.duplicate_probability > 0.0
                or (self.reorder_probability > 0.0 and self.reorder_delay_s > 0.0)
                or bool(self.outages))

    def describe(self) -> str:
        """The faults in words, for a report (``"a perfect link"`` when none)."""
        parts = []
        if self.delay_s > 0.0:
            parts.append(f"delay {self.delay_s:g} s")
        if self.jitter_s > 0.0:
            parts.append(f"jitter up to {self.jitter_s:g} s")
        if self.loss_probability > 0.0:
            parts.append(f"loss {100 * self.loss_probability:g} %")
        if self.duplicate_probability > 0.0:
            parts.append(f"duplicates {100 * self.duplicate_probability:g} %")
        if self.reorder_probability > 0.0 and self.reorder_delay_s > 0.0:
            parts.append(f"{100 * self.reorder_probability:g} % held back "
                         f"{self.reorder_delay_s:g} s")
        for start, end in self.outages:
            parts.append(f"outage {start:g}–{end:g} s")
        if not parts:
            return "a perfect link"
        return ", ".join(parts) + f"; seed {self.seed}"

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any] | None) -> LinkFaultConfig:
        """Builds a config from a YAML/JSON-like mapping (``None`` = the defaults).

        Outage windows may be given as lists (``outages: [[2.0, 3.5]]``).

        Raises:
            ValueError: ``data`` is not a mapping, has unknown keys (named, with the known
                ones) or invalid values (the field and value named).
        """
        if data is None:
            data = {}
        if not isinstance(data, Mapping):
            raise ValueError(f"link fault config = {data!r} must be a mapping of field: value")
        known = [field.name for field in dataclasses.fields(cls)]
        unknown = sorted(str(key) for key in data if key not in known)
        if unknown:
            raise ValueError(f"link fault config: unknown key(s) {unknown}; "
                             f"the known keys are {known}")
        return cls(**data)

    def to_mapping(self) -> dict[str, Any]:
        """The fields as a JSON-ready dict (outages as lists); inverse of from_mapping."""
        data = dataclasses.asdict(self)
        data["outages"] = [list(window) for window in self.outages]
        return data


class PacketFate(NamedTuple):
    """What the link does to one packet.

    Attributes:
        delivery_times_s: Delivery times of its copies, s, sorted; empty if lost, two
            entries if duplicated.
        lost: True if the packet is lost (in an outage or by ``loss_probability``).
        in_outage: True if it was sent during an outage window.
        duplicated: True if a second copy is delivered.
        held_back: True if it is held back by ``reorder_delay_s`` (``reorder_probability``).
    """

    delivery_times_s: tuple[float, ...]
    lost: bool
    in_outage: bool
    duplicated: bool
    held_back: bool


class LinkFaultModel:
    """The seeded fate of each packet on a link with the faults of a :class:`LinkFaultConfig`.

    :meth:`fate` is a pure function of ``(config, packet_index, send_time_s)``: the random
    draws of packet ``k`` come from ``numpy.random.default_rng([config.seed, k])``, always the
    same five draws in the same order whatever the config, so changing one probability does
    not reshuffle the other fates. :meth:`deliveries` is the same plus counters.
    """

    def __init__(self, config: LinkFaultConfig):
        if not isinstance(config, LinkFaultConfig):
            raise TypeError(f"config = {config!r} must be a LinkFaultConfig")
        self._config = config
        self._counts = {"sent": 0, "lost": 0, "duplicated": 0, "reordered": 0}

    @property
    def config(self) -> LinkFaultConfig:
        """The faults of this link."""
        return self._config

    def fate(self, packet_index: int, send_time_s: float) -> PacketFate:
        """The fate of packet ``packet_index`` sent at ``send_time_s`` (s); no counting.

        Args:
            packet_index: Number of the packet on this link, from 0 (an integer ≥ 0).
            send_time_s: Send time, s, on the clock of ``config.outages``.

        Raises:
            ValueError: negative or non-integer ``packet_index``, non-finite ``send_time_s``.
        """
        if (isinstance(packet_index, bool) or not isinstance(packet_index, numbers.Integral)
                or packet_index < 0):
            raise ValueError(f"packet_index = {packet_index!r} must be an integer >= 0")
        send_time = _check_real("send_time_s", send_time_s)
        if not math.isfinite(send_time):
            raise ValueError(f"send_time_s = {send_time_s!r} must be finite")
        config = self._config
        # Fixed draw order: loss, duplicate, reorder, jitter of copy 1, jitter of copy 2.
        u_loss, u_duplicate, u_reorder, u_jitter_1, u_jitter_2 = np.random.default_rng(
            [config.seed, int(packet_index)]).random(5)
        in_outage = any(start <= send_time < end for start, end in config.outages)
        if in_outage or u_loss < config.loss_probability:
            return PacketFate((), True, in_outage, False, False)
        held_back = bool(u_reorder < config.reorder_probability)
        duplicated = bool(u_duplicate < config.duplicate_probability)
        base = send_time + config.delay_s + (config.reorder_delay_s if held_back else 0.0)
        times = [base + config.jitter_s * float(u_jitter_1)]
        if duplicated:
            times.append(base + config.duplicate_spacing_s + config.jitter_s * float(u_jitter_2))
        return PacketFate(tuple(sorted(times)), False, False, duplicated, held_back)

    def deliveries(self, packet_index: int, send_time_s: float) -> tuple[float, ...]:
        """Delivery times, s, sorted, of packet ``packet_index`` sent at ``send_time_s`` (s).

        Empty if the packet is lost, two times if it is duplicated. Updates :meth:`counts`
        (each call counts as one packet sent). See :meth:`fate` for the arguments.
        """
        fate = self.fate(packet_index, send_time_s)
        self._counts["sent"] += 1
        self._counts["lost"] += fate.lost
        self._counts["duplicated"] += fate.duplicated
        self._counts["reordered"] += fate.held_back
        return fate.delivery_times_s

    def counts(self) -> dict[str, int]:
        """Counters over the :meth:`deliveries` calls so far.

        Keys: ``sent``, ``lost``, ``duplicated`` (packets delivered twice), ``reordered``
        (packets held back by ``reorder_delay_s``; overtaking caused by jitter alone is not
        counted here).
        """
        return dict(self._counts)


class Delivery(NamedTuple):
    """One copy of a packet leaving a :class:`LinkQueue`.

    Attributes:
        delivery_time_s: When it is delivered, s.
        packet_index: Number of the packet on the link.
        copy: 0 for the earlier copy, 1 for the later one (only if duplicated).
        payload: What was sent.
    """

    delivery_time_s: float
    packet_index: int
    copy: int
    payload: bytes


class LinkQueue:
    """Packets in flight on a faulty link: send now, collect when due.

    Packets leave in delivery-time order; ties are broken by packet index, then copy number.
    Pure Python (``heapq``); the payload is opaque (normally the LCM encoding). A queue is
    plain data: ``copy.deepcopy`` gives an independent queue (e.g. for Drake abstract state).

    Args:
        link: The faults, a :class:`LinkFaultConfig` or a :class:`LinkFaultModel` (whose
            counters the queue then updates).
    """

    def __init__(self, link: LinkFaultConfig | LinkFaultModel):
        self._model = link if isinstance(link, LinkFaultModel) else LinkFaultModel(link)
        self._heap: list[tuple[float, int, int, int, Any]] = []
        self._sent = 0   # a unique tie-breaker, so that payloads are never compared

    @property
    def model(self) -> LinkFaultModel:
        """The fault model deciding the fates (and holding the counters)."""
        return self._model

    def send(self, packet_index: int, send_time_s: float, payload: bytes) -> tuple[float, ...]:
        """Puts packet ``packet_index``, sent at ``send_time_s`` (s), on the link.

        Returns:
            Its delivery times, s (empty if lost).
        """
        times = self._model.deliveries(packet_index, send_time_s)
        for copy, time_s in enumerate(times):
            heapq.heappush(self._heap, (time_s, int(packet_index), copy, self._sent, payload))
        self._sent += 1
        return times

    def due_deliveries(self, now_s: float) -> list[Delivery]:
        """Pops every copy with delivery time ≤ ``now_s`` (s), in delivery order."""
        out = []
        while self._heap and self._heap[0][0] <= now_s:
            time_s, index, copy, _, payload = heapq.heappop(self._heap)
            out.append(Delivery(time_s, index, copy, payload))
        return out

    def due(self, now_s: float) -> list[bytes]:
        """Pops the payloads of every copy with delivery time ≤ ``now_s`` (s), in order."""
        return [delivery.payload for delivery in self.due_deliveries(now_s)]

    def next_delivery_time(self) -> float | None:
        """The earliest delivery time in flight, s, or None if nothing is in flight."""
        return self._heap[0][0] if self._heap else None

    def pending(self) -> int:
        """Number of copies in flight."""
        return len(self._heap)

    def counts(self) -> dict[str, int]:
        """The counters of the fault model (see :meth:`LinkFaultModel.counts`)."""
        return self._model.counts()
