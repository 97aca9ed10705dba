"""Numbers in reports (a ratio to a limit never hides a violation in its rounding) and the
command line's progress lines."""

from __future__ import annotations

import math
import sys

from telesmooth.smoothing.metrics import VIOLATION_RTOL

__all__ = ["limit_ratio", "log"]


def log(message: str) -> None:
    """A progress or status line on stderr, flushed at once (stdout is for results)."""
    print(message, file=sys.stderr, flush=True)


def limit_ratio(value, digits: int = 2) -> str:
    """A max/limit ratio for a table: ``digits`` decimals, but a value over the limit (beyond
    the round-off tolerance :data:`~telesmooth.smoothing.metrics.VIOLATION_RTOL`) gets as many
    decimals as it takes to show it above 1 (1.0021, not 1.00) and a ``!``.

    >>> limit_ratio(0.999), limit_ratio(1.0000001), limit_ratio(1.0021), limit_ratio(2.456)
    ('1.00', '1.00', '1.0021!', '2.46!')
    """
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    value = float(value)
    if value <= 1.0 + VIOLATION_RTOL:
        return f"{value:.{digits}f}"
    places = digits
    while float(f"{value:.{places}f}") <= 1.0 and places < 12:
        places += 1
    text = f"{value:.{places}f}"
    # One more significant place than it took to leave 1.00…, so the excess reads clearly.
    if places > digits:
        text = f"{value:.{places + 1}f}"
    return text + "!"
