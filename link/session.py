"""Freshness of uplink commands: the onboard run's epoch and the ground's session counter.

The HMAC (:mod:`telesmooth.link.auth`) proves a command came from a key holder; it does not
prove the command is *fresh*. Two numbers in every command, both covered by the tag, do:

* ``onboard_epoch``: a random number (:data:`EPOCH_BITS` bits, never 0) that the onboard
  process draws at start and announces in its telemetry (``lcmt_onboard_joint_status``). It
  accepts only commands that carry it. A packet captured before an onboard restart carries
  the old epoch and is refused ("session"), however new its session or seq.
* ``session_id``: a counter in the high 32 bits and a random number of the ground run
  (:func:`new_ground_nonce`) in the low 32. A ground run takes the counter after the one of
  the last session the robot accepted in this epoch (from the same telemetry:
  ``last_command_session_id``), so a restarted ground is accepted from its first packet.

The onboard rule for an authentic packet (session s, seq q) against the last accepted
(s₀, q₀) of this epoch (none yet: s₀ = 0, q₀ = −1), :func:`classify_session`:

* s = s₀ and q > q₀: accepted (the current session); q = q₀: duplicate; q < q₀: stale;
* counter(s) = counter(s₀) + 1: accepted (the next ground session; any seq);
* counter(s) ≤ counter(s₀), s ≠ s₀: stale (an earlier session, or a withheld one that lost
  the race for this counter);
* counter(s) > counter(s₀) + 1: refused ("session"): a session that skips ahead cannot lock
  the real ground out, whoever signed it.

In-process simulation uses epoch 0 and session 0 on both sides (no telemetry, no key).
Session ids stay below 2⁵³ (counter < 2²¹) and epochs below 2⁵², so both are exact in the
float64 vectors of a Drake Context.
"""

from __future__ import annotations

import secrets

__all__ = [
    "EPOCH_BITS",
    "NONCE_BITS",
    "classify_session",
    "new_epoch",
    "new_ground_nonce",
    "next_session",
    "session_counter",
    "session_id",
]

EPOCH_BITS = 52
"""Bits of an onboard epoch (exact in a float64)."""

NONCE_BITS = 32
"""Bits of a ground run's random part of its session id."""

_MAX_COUNTER = 2**21 - 1


def new_epoch() -> int:
    """A fresh random onboard epoch in [1, 2^52)."""
    while True:
        epoch = secrets.randbits(EPOCH_BITS)
        if epoch:
            return epoch


def new_ground_nonce() -> int:
    """A fresh random ground-run number in [0, 2^32)."""
    return secrets.randbits(NONCE_BITS)


def session_id(counter: int, nonce: int) -> int:
    """The session id of ``counter`` and ``nonce``.

    Raises:
        ValueError: a counter outside [0, 2^21) or a nonce outside [0, 2^32).
    """
    if not 0 <= counter <= _MAX_COUNTER:
        raise ValueError(f"session counter = {counter!r} must be in [0, {_MAX_COUNTER}]")
    if not 0 <= nonce < 2**NONCE_BITS:
        raise ValueError(f"session nonce = {nonce!r} must be in [0, 2^{NONCE_BITS})")
    return (int(counter) << NONCE_BITS) | int(nonce)


def session_counter(session: int) -> int:
    """The counter of a session id."""
    return int(session) >> NONCE_BITS


def next_session(last_accepted_session: int, nonce: int) -> int:
    """The session a ground run with ``nonce`` uses after the robot's last accepted session
    ``last_accepted_session`` (0 before any): the next counter."""
    return session_id(min(session_counter(last_accepted_session) + 1, _MAX_COUNTER), nonce)


def classify_session(session: int, seq: int, last_accepted) -> tuple[str, str]:
    """("accepted" | "duplicate" | "stale" | "session", reason) of an authentic packet of this
    epoch (the module docstring's rule); ``last_accepted`` = (session, seq) of the last
    accepted command in this epoch, or None before the first."""
    last_session, last_seq = (0, -1) if last_accepted is None else (
        int(last_accepted[0]), int(last_accepted[1]))
    session, seq = int(session), int(seq)
    if session == last_session:
        if seq > last_seq:
            return "accepted", ""
        if seq == last_seq:
            return "duplicate", (f"(session_id, seq) = {(session, seq)} was already accepted "
                                 "(a duplicate or a replay)")
        return "stale", (f"seq = {seq} of session {session} is older than the last accepted "
                         f"{last_seq} (late, reordered or replayed)")
    counter, last_counter = session_counter(session), session_counter(last_session)
    if counter == last_counter + 1:
        return "accepted", ""
    if counter <= last_counter:
        return "stale", (f"session_id = {session} (counter {counter}) is not the robot's "
                         f"current session {last_session} (counter {last_counter}): an "
                         "earlier ground run, late or replayed")
    return "session", (f"session_id = {session} (counter {counter}) skips ahead of the robot's "
                       f"session counter {last_counter}: only {last_counter + 1} may start")
