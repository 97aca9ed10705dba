"""Shared timing checks for the sampled systems (periods, delays in whole samples)."""

from __future__ import annotations

import math

__all__ = ["check_period", "delay_in_samples", "samples_per_period"]

_RATIO_TOLERANCE = 1e-9


def check_period(field: str, value) -> float:
    """A positive, finite period in seconds, or ValueError naming ``field`` and the value."""
    try:
        period = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{field} = {value!r} must be a number of seconds") from None
    if not (math.isfinite(period) and period > 0.0):
        raise ValueError(f"{field} = {value!r} must be positive and finite (seconds)")
    return period


def delay_in_samples(delay_s, period_s, *, delay_field="delay_s", period_field="period_s") -> int:
    """round(delay/period), rejecting delays that are not a whole number of periods."""
    period = check_period(period_field, period_s)
    try:
        delay = float(delay_s)
    except (TypeError, ValueError):
        raise ValueError(f"{delay_field} = {delay_s!r} must be a number of seconds") from None
    if not (math.isfinite(delay) and delay >= 0.0):
        raise ValueError(f"{delay_field} = {delay_s!r} must be non-negative and finite")
    ratio = delay / period
    samples = round(ratio)
    if abs(ratio - samples) > _RATIO_TOLERANCE * max(1.0, ratio):
        raise ValueError(
            f"{delay_field} = {delay!r} is not a whole number of {period_field} = {period!r} "
            f"periods ({delay_field}/{period_field} = {ratio!r})"
        )
    return int(samples)


def samples_per_period(slow_period_s, fast_period_s, *, slow_field, fast_field) -> int:
    """How many fast samples make one slow period; must be a whole number >= 1."""
    count = delay_in_samples(
        slow_period_s, fast_period_s, delay_field=slow_field, period_field=fast_field
    )
    if count < 1:
        raise ValueError(f"{slow_field} = {slow_period_s!r} must be at least {fast_field}")
    return count
