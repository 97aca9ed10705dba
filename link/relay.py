"""A real-time LCM relay that puts a faulty link between two processes.

For multi-process fault-injection tests the ground process publishes on LCM bus A and the
onboard process listens on bus B; the relay forwards the uplink channels A → B through a
:class:`~telesmooth.link.faults.LinkQueue` (delay, jitter, loss, duplication, reordering,
outages) and the downlink channels (telemetry) B → A, unchanged or with their own faults::

    ground ──A── relay ──B── onboard         python -m telesmooth.link.relay \\
                                                 --in-url udpm://239.255.76.67:7901?ttl=0 \\
                                                 --out-url udpm://239.255.76.67:7951?ttl=0 \\
                                                 --link '{delay_s: 0.3, loss_probability: 0.1}'

Packet ``k`` of a direction is the ``k``-th message (from 0) the relay receives on any of
that direction's channels, its send time the wall time since the relay started, s (a
monotonic clock); so its fate is exactly what ``LinkFaultModel(config).fate(k, t)`` predicts
(outage windows are in seconds since the relay started). Pure Python; no Drake.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import select
import signal
import sys
import threading
import time
import urllib.parse
import warnings
from collections.abc import Sequence
from pathlib import Path

import lcm

from telesmooth.lcm_types.channels import (
    LCM_URL_SCHEMES,
    ONBOARD_JOINT_STATUS,
    TELEOP_JOINT_COMMAND,
)
from telesmooth.link.faults import LinkFaultConfig, LinkQueue
from telesmooth.user_input import quote

__all__ = ["POLL_PERIOD_S", "check_relay_urls", "main", "parse_link_option", "run_relay"]

POLL_PERIOD_S = 0.005
"""Longest wait for incoming messages between checks for due packets, s."""

PROGRESS_PERIOD_S = 1.0
"""Shortest interval between progress lines on stderr, s."""

_DEFAULT_UDPM_GROUP = "239.255.76.67"
_DEFAULT_UDPM_PORT = 7667


def _bus_identity(url: str) -> tuple:
    """What makes two URLs the same bus (udpm: group and port; the query does not count)."""
    parts = urllib.parse.urlsplit(url)
    if parts.scheme == "udpm":
        host = parts.hostname or _DEFAULT_UDPM_GROUP
        try:
            port = parts.port or _DEFAULT_UDPM_PORT
        except ValueError:   # a non-numeric port: leave it to LCM to reject
            port = parts.netloc
        return ("udpm", host, port)
    return (parts.scheme, parts.netloc, parts.path)


def check_relay_urls(uplink_in_url: str, uplink_out_url: str) -> None:
    """Checks the two LCM URLs of a relay.

    Warns (``UserWarning``) when a ``udpm://`` URL does not say ``ttl=0``: only then is the
    multicast traffic guaranteed to stay on this host.

    Raises:
        ValueError: a URL is empty or not a string, or both name the same bus (the relay
            would receive its own output); the message names the fields and values.
    """
    for field, url in (("uplink_in_url", uplink_in_url), ("uplink_out_url", uplink_out_url)):
        if (not isinstance(url, str) or "://" not in url
                or url.split("://", 1)[0] not in LCM_URL_SCHEMES):
            raise ValueError(f"{field} = {quote(url)} must be an LCM URL such as "
                             f"'udpm://{_DEFAULT_UDPM_GROUP}:7901?ttl=0' (or memq://)")
    if _bus_identity(uplink_in_url) == _bus_identity(uplink_out_url):
        raise ValueError(f"uplink_in_url = {uplink_in_url!r} and uplink_out_url = "
                         f"{uplink_out_url!r} are the same LCM bus: the relay would receive "
                         "its own output; use two different buses (e.g. two udpm ports)")
    for field, url in (("uplink_in_url", uplink_in_url), ("uplink_out_url", uplink_out_url)):
        parts = urllib.parse.urlsplit(url)
        if parts.scheme == "udpm":
            ttl = urllib.parse.parse_qs(parts.query).get("ttl")
            if ttl != ["0"]:
                warnings.warn(f"{field} = {url!r} does not say ttl=0: multicast traffic may "
                              "leave this host", UserWarning, stacklevel=2)


def _check_channels(field: str, channels) -> tuple[str, ...]:
    if isinstance(channels, str) or not all(isinstance(c, str) and c for c in channels):
        raise ValueError(f"{field} = {channels!r} must be a sequence of channel names")
    return tuple(channels)


def _open_bus(field: str, url: str):
    try:
        return lcm.LCM(url)
    except (RuntimeError, OSError) as error:
        raise ValueError(f"{field} = {url!r}: LCM cannot open it ({error})") from None


class _Direction:
    """One direction of the relay: its queue, counters, and the bus it publishes on."""

    def __init__(self, name, channels, config, fault_config, lcm_out, clock):
        self.name = name
        self.channels = channels
        self.config = fault_config          # None: forwarded unchanged
        self.queue = LinkQueue(config)
        self.lcm_out = lcm_out
        self.clock = clock
        self.received = 0
        self.forwarded = 0

    def on_message(self, channel: str, data: bytes) -> None:
        # Publishing from inside a handler is avoided: queue now, publish in the main loop.
        self.queue.send(self.received, self.clock(), (channel, bytes(data)))
        self.received += 1

    def publish_due(self, now_s: float) -> None:
        for channel, data in self.queue.due(now_s):
            self.lcm_out.publish(channel, data)
            self.forwarded += 1

    def report(self) -> dict:
        counts = self.queue.counts()
        return {
            "channels": list(self.channels),
            "config": None if self.config is None else self.config.to_mapping(),
            "received": self.received,
            "forwarded": self.forwarded,
            "lost": counts["lost"],
            "duplicated": counts["duplicated"],
            "reordered": counts["reordered"],
            "in_flight": self.queue.pending(),
        }

    def summary(self) -> str:
        r = self.report()
        return (f"{self.name} {r['received']} received, {r['forwarded']} forwarded, "
                f"{r['lost']} lost, {r['duplicated']} duplicated, {r['reordered']} reordered, "
                f"{r['in_flight']} in flight")


def _write_report(report: dict, report_path) -> None:
    from telesmooth.atomic_files import write_text

    write_text(Path(report_path), json.dumps(report, indent=2) + "\n")


def run_relay(
    *,
    uplink_in_url: str,
    uplink_out_url: str,
    config: LinkFaultConfig,
    duration_s: float,
    uplink_channels: Sequence[str] = (TELEOP_JOINT_COMMAND,),
    downlink_channels: Sequence[str] = (ONBOARD_JOINT_STATUS,),
    downlink_config: LinkFaultConfig | None = None,
    report_path: str | os.PathLike | None = None,
    progress: bool = True,
) -> dict:
    """Relays LCM traffic between two buses in real time, applying link faults.

    Messages on ``uplink_channels`` received on ``uplink_in_url`` (bus A) are scheduled
    through a :class:`LinkQueue` with ``config`` and published on ``uplink_out_url`` (bus B)
    when due; messages on ``downlink_channels`` received on B are forwarded to A, with
    ``downlink_config`` faults if given, else unchanged. Packets still in flight at the end
    are dropped (counted as ``in_flight``). SIGINT and SIGTERM end the relay early (when it
    runs in the main thread) and the report is still written.

    Args:
        uplink_in_url: LCM URL of bus A, where the ground process publishes.
        uplink_out_url: LCM URL of bus B, where the onboard process listens; must be a
            different bus.
        config: Faults of the uplink (A → B).
        duration_s: How long to relay, s (> 0; ``inf`` = until a signal).
        uplink_channels: Channels relayed A → B.
        downlink_channels: Channels relayed B → A; disjoint from ``uplink_channels``.
        downlink_config: Faults of the downlink, or None for a perfect downlink.
        report_path: If given, the report is written there as JSON.
        progress: Print a ready line and at most one progress line per second to stderr.

    Returns:
        The report: ``uplink_in_url``, ``uplink_out_url``, ``elapsed_s``, ``stopped_by``
        (``"duration"``, ``"SIGINT"`` or ``"SIGTERM"``), and per direction (``"uplink"``,
        ``"downlink"``) ``channels``, ``config``, ``received``, ``forwarded`` (copies
        published, duplicates included), ``lost``, ``duplicated``, ``reordered`` (held back)
        and ``in_flight``.

    Raises:
        ValueError: invalid arguments (the field and value named), or a URL LCM cannot open.
    """
    check_relay_urls(uplink_in_url, uplink_out_url)
    for field, value in (("config", config), ("downlink_config", downlink_config)):
        if not isinstance(value, LinkFaultConfig) and not (field == "downlink_config"
                                                           and value is None):
            raise ValueError(f"{field} = {value!r} must be a LinkFaultConfig")
    if (isinstance(duration_s, bool) or not isinstance(duration_s, (int, float))
            or math.isnan(duration_s) or duration_s <= 0):
        raise ValueError(f"duration_s = {duration_s!r} must be > 0 s (inf: until a signal)")
    uplink_channels = _check_channels("uplink_channels", uplink_channels)
    downlink_channels = _check_channels("downlink_channels", downlink_channels)
    shared = sorted(set(uplink_channels) & set(downlink_channels))
    if shared:
        raise ValueError(f"uplink_channels and downlink_channels share {shared}: a channel is "
                         "relayed in one direction only")

    bus_a = _open_bus("uplink_in_url", uplink_in_url)
    bus_b = _open_bus("uplink_out_url", uplink_out_url)
    start = time.monotonic()

    def clock() -> float:
        return time.monotonic() - start

    uplink = _Direction("uplink", uplink_channels, config, config, bus_b, clock)
    downlink = _Direction("downlink", downlink_channels, downlink_config or LinkFaultConfig(),
                          downlink_config, bus_a, clock)
    subscriptions = ([(bus_a, bus_a.subscribe(c, uplink.on_message)) for c in uplink_channels]
                     + [(bus_b, bus_b.subscribe(c, downlink.on_message))
                        for c in downlink_channels])

    stopped_by: list[str] = []

    def on_signal(signum, frame):
        stopped_by.append(signal.Signals(signum).name)

    previous_handlers = {}
    if threading.current_thread() is threading.main_thread():
        for signum in (signal.SIGINT, signal.SIGTERM):
            previous_handlers[signum] = signal.signal(signum, on_signal)

    def make_report() -> dict:
        return {
            "uplink_in_url": uplink_in_url,
            "uplink_out_url": uplink_out_url,
            "elapsed_s": clock(),
            "stopped_by": stopped_by[0] if stopped_by else "duration",
            "uplink": uplink.report(),
            "downlink": downlink.report(),
        }

    if progress:
        print(f"link-relay: ready; {list(uplink_channels)} {uplink_in_url} -> "
              f"{uplink_out_url}, {list(downlink_channels)} back; uplink faults "
              f"{config.to_mapping() if config.enabled else 'none'}; downlink faults "
              f"{downlink_config.to_mapping() if downlink_config else 'none'}",
              file=sys.stderr, flush=True)
    buses = (bus_a, bus_b)
    last_progress = 0.0
    try:
        while not stopped_by:
            now = clock()
            if now >= duration_s:
                break
            uplink.publish_due(now)
            downlink.publish_due(now)
            # Wait for input, but wake up in time for the next due packet.
            timeout = min(POLL_PERIOD_S, duration_s - now)
            for direction in (uplink, downlink):
                next_time = direction.queue.next_delivery_time()
                if next_time is not None:
                    timeout = min(timeout, next_time - now)
            readable, _, _ = select.select(buses, [], [], max(timeout, 0.0))
            for bus in readable:
                while bus.handle_timeout(0) > 0:
                    pass
            if progress and clock() - last_progress >= PROGRESS_PERIOD_S:
                last_progress = clock()
                print(f"link-relay {last_progress:.1f} s: {uplink.summary()}; "
                      f"{downlink.summary()}", file=sys.stderr, flush=True)
    finally:
        for signum, handler in previous_handlers.items():
            signal.signal(signum, handler)
        for bus, subscription in subscriptions:
            bus.unsubscribe(subscription)
        report = make_report()
        if report_path is not None:
            _write_report(report, report_path)
    if progress:
        print(f"link-relay: stopped by {report['stopped_by']} after {report['elapsed_s']:.1f} "
              f"s: {uplink.summary()}; {downlink.summary()}", file=sys.stderr, flush=True)
    return report


def parse_link_option(option: str, text: str | None) -> LinkFaultConfig | None:
    """Parses a YAML (or JSON) mapping such as ``"{delay_s: 0.3, seed: 4}"``.

    Args:
        option: The option's name for error messages (``"--link"``).
        text: The mapping, or None (returns None).

    Raises:
        ValueError: not YAML, not a mapping, unknown keys or bad values (option and field
            named).
    """
    if text is None:
        return None
    from telesmooth.typed_yaml import load_yaml_text
    # Bounded plain data (size, nesting, aliases), string keys each given once.
    data = load_yaml_text(text, source=option)
    try:
        return LinkFaultConfig.from_mapping(data)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{option}: {error}") from None


def build_parser() -> argparse.ArgumentParser:
    """The options of ``telesmooth link-relay``."""
    parser = argparse.ArgumentParser(
        prog="telesmooth link-relay",
        description="Relay LCM traffic between two buses, applying link faults to the uplink.")
    parser.add_argument("--in-url", required=True,
                        help="LCM URL of bus A, where the ground process publishes")
    parser.add_argument("--out-url", required=True,
                        help="LCM URL of bus B, where the onboard process listens")
    parser.add_argument("--duration", type=float, default=math.inf,
                        help="seconds to relay (default: until SIGINT/SIGTERM)")
    parser.add_argument("--link", default="{}",
                        help="uplink faults, a YAML/JSON mapping of LinkFaultConfig fields, "
                             "e.g. '{delay_s: 0.3, loss_probability: 0.1, seed: 1}'")
    parser.add_argument("--downlink", default=None,
                        help="downlink faults, same format (default: forwarded unchanged)")
    parser.add_argument("--uplink-channel", action="append", default=None,
                        help=f"uplink channel (repeatable; default {TELEOP_JOINT_COMMAND})")
    parser.add_argument("--downlink-channel", action="append", default=None,
                        help=f"downlink channel (repeatable; default {ONBOARD_JOINT_STATUS})")
    parser.add_argument("--report", default=None, help="write the counts here as JSON")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Command line of the relay (``telesmooth link-relay``, ``python -m telesmooth.link.relay``).

    Returns:
        0 after a completed run. Bad arguments exit with status 2 and a message naming the
        option and field.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    if math.isnan(args.duration) or args.duration <= 0:
        parser.error(f"--duration = {args.duration!r} must be > 0 s")
    from telesmooth.atomic_files import Outputs

    with Outputs() as outputs:
        report = None if args.report is None else outputs.file("--report", args.report)
        return _relay(parser, args, report)


def _exit_with_error(parser, error: Exception) -> None:
    """One line naming the option (not the function's argument), exit status 2: a bad value
    is not a usage error, so no usage block."""
    message = str(error).replace("uplink_in_url", "--in-url").replace("uplink_out_url",
                                                                     "--out-url")
    parser.exit(2, f"{parser.prog}: error: {message}\n")


def _relay(parser, args, report_path) -> int:
    try:
        config = parse_link_option("--link", args.link) or LinkFaultConfig()
        downlink_config = parse_link_option("--downlink", args.downlink)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")   # run_relay warns again, once
            check_relay_urls(args.in_url, args.out_url)
    except ValueError as error:
        _exit_with_error(parser, error)
    try:
        run_relay(uplink_in_url=args.in_url, uplink_out_url=args.out_url, config=config,
                  duration_s=args.duration,
                  uplink_channels=tuple(args.uplink_channel or (TELEOP_JOINT_COMMAND,)),
                  downlink_channels=tuple(args.downlink_channel or (ONBOARD_JOINT_STATUS,)),
                  downlink_config=downlink_config, report_path=report_path,
                  progress=not args.quiet)
    except ValueError as error:   # channels, or a URL LCM cannot open
        _exit_with_error(parser, error)
    return 0


if __name__ == "__main__":
    sys.exit(main())
