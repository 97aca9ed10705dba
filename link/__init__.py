"""The ground-to-robot link: fault injection and uplink authentication. Pure Python, no Drake.

* :mod:`telesmooth.link.faults`: a seeded model of an unreliable link (delay, jitter, loss,
  duplication, reordering, outages) and an in-flight queue built on it.
* :mod:`telesmooth.link.auth`: HMAC-SHA256 signing and verification of uplink commands, and
  key handling.
* :mod:`telesmooth.link.relay`: a real-time LCM relay process applying the fault model
  between two buses (``python -m telesmooth.link.relay``). Not imported here, so that
  importing the package does not import ``lcm``.
"""

from telesmooth.link.auth import (
    AUTH_CLASSES,
    AUTH_FORGED,
    AUTH_MALFORMED,
    AUTH_UNSIGNED,
    KEY_ENVIRONMENT_VARIABLE,
    MIN_KEY_BYTES,
    UplinkKeyError,
    generate_key_file,
    load_key,
    sign,
    verify,
    verify_classified,
)
from telesmooth.link.faults import (
    Delivery,
    LinkFaultConfig,
    LinkFaultModel,
    LinkQueue,
    PacketFate,
)

__all__ = [
    "AUTH_CLASSES",
    "AUTH_FORGED",
    "AUTH_MALFORMED",
    "AUTH_UNSIGNED",
    "Delivery",
    "KEY_ENVIRONMENT_VARIABLE",
    "LinkFaultConfig",
    "LinkFaultModel",
    "LinkQueue",
    "MIN_KEY_BYTES",
    "PacketFate",
    "UplinkKeyError",
    "generate_key_file",
    "load_key",
    "sign",
    "verify",
    "verify_classified",
]
