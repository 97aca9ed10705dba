"""LCM channel names and default URL, defined once for both processes."""

import ipaddress
import urllib.parse

TELEOP_HAPTIC_COMMAND = "TELEOP_HAPTIC_COMMAND"
"""Haptic device samples (lcmt_teleop_haptic_command), 100 Hz, device → ground."""

TELEOP_JOINT_COMMAND = "TELEOP_JOINT_COMMAND"
"""Smoothed joint commands (lcmt_teleop_joint_command), 4 Hz, ground → onboard."""

ONBOARD_JOINT_STATUS = "ONBOARD_JOINT_STATUS"
"""Robot telemetry (lcmt_onboard_joint_status), 100 Hz, onboard → ground."""

TELEOP_COLLISION_EVENT = "TELEOP_COLLISION_EVENT"
"""Pre-simulator collision and hold state (lcmt_teleop_collision_event), 4 Hz, ground → all."""

ALL_CHANNELS = (TELEOP_HAPTIC_COMMAND, TELEOP_JOINT_COMMAND, ONBOARD_JOINT_STATUS,
                TELEOP_COLLISION_EVENT)

DEFAULT_LCM_URL = "udpm://239.255.76.67:7667?ttl=0"
"""Multicast on this host only (ttl=0): never let teleoperation traffic leave the machine
unless you deliberately configure a routed URL for a two-machine set-up."""

LCM_URL_SCHEMES = ("udpm", "memq")
"""The LCM providers the processes use: UDP multicast between processes, ``memq://`` within
one (tests). Others (``file://`` writes a log file, ``tcpq://`` opens a TCP connection) are
refused."""


def check_lcm_url(field: str, url) -> str:
    """Returns ``url`` if it is a ``udpm://`` or ``memq://`` URL that LCM can open.

    Args:
        field: How messages name the URL, as the user wrote it (``"--lcm-url"``).
        url: The URL.

    Raises:
        ValueError: another scheme, or LCM cannot open it (a bad address or port); the message
            names ``field`` and the URL.
    """
    from telesmooth.user_input import quote

    scheme = url.split("://", 1)[0] if isinstance(url, str) and "://" in url else None
    if scheme not in LCM_URL_SCHEMES:
        raise ValueError(f"{field} = {quote(url)} must be an LCM URL udpm://GROUP:PORT?ttl=0 "
                         f"(or memq:// within one process), such as {DEFAULT_LCM_URL!r}")
    if scheme == "udpm":
        _check_udpm_address(field, url)
    import lcm

    try:
        lcm.LCM(url)
    except (RuntimeError, OSError) as error:
        raise ValueError(f"{field} = {quote(url)}: LCM cannot open it ({error})") from None
    return url


def _check_udpm_address(field: str, url: str) -> None:
    """The group of a udpm:// URL must be an IPv4 multicast address and its port a port
    (checked here: LCM would print its own line on stderr and fail without saying which)."""
    from telesmooth.user_input import quote

    parts = urllib.parse.urlsplit(url)
    try:
        group = ipaddress.IPv4Address(parts.hostname or "239.255.76.67")
        port = parts.port
    except ValueError as error:
        raise ValueError(f"{field} = {quote(url)}: {error}") from None
    if not group.is_multicast:
        raise ValueError(f"{field} = {quote(url)}: {group} is not a multicast group "
                         "(224.0.0.0 to 239.255.255.255)")
    if port is not None and not 0 < port < 65536:
        raise ValueError(f"{field} = {quote(url)}: port {port} is not in 1..65535")
