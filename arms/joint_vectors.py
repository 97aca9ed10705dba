"""Validation of a joint-position vector: one angle per joint, finite, optionally within limits.

Shared by every place that takes a configuration of an arm from a caller (the inverse
kinematics' initial target, the 6-DOF IK's seed, the collision model's query), so that each
says the same thing about a bad vector: the field, the value and, for a bad entry, the joint.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = ["check_joint_vector"]


def check_joint_vector(field: str, value, joint_names: Sequence[str], *, lower=None,
                       upper=None) -> np.ndarray:
    """``value`` as a float array of shape (n,), one angle per joint of ``joint_names``.

    Args:
        field: The argument's name in messages (e.g. ``"q_rad"``).
        value: The joint angles, rad, ordered as ``joint_names``.
        joint_names: The joints, (n,).
        lower, upper: Joint limits, rad, (n,) each, or both None (limits not checked).

    Returns:
        A new float array of shape (n,).

    Raises:
        ValueError: If ``value`` is not numeric or does not have one entry per joint (the
            message gives the field, the value and the joints), or an entry is not finite or,
            with limits, outside them (the message gives the field, the index, the joint and
            the entry).
    """
    names = tuple(joint_names)
    n = len(names)
    if (lower is None) != (upper is None):
        raise ValueError("check_joint_vector: give both lower and upper limits, or neither")
    try:
        q = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(
            f"{field} = {value!r} must be {n} joint angles in rad, ordered {names!r}"
        ) from None
    if q.shape != (n,):
        raise ValueError(
            f"{field} = {value!r} has shape {q.shape}; expected ({n},) for the joints {names!r}"
        )
    for i, entry in enumerate(q):
        if lower is None:
            if not math.isfinite(entry):
                raise ValueError(
                    f"{field}[{i}] (joint {names[i]!r}) = {float(entry)!r} must be finite"
                )
        elif not (math.isfinite(entry) and lower[i] <= entry <= upper[i]):
            raise ValueError(
                f"{field}[{i}] (joint {names[i]!r}) = {float(entry)!r} must be finite and "
                f"within [{float(lower[i])!r}, {float(upper[i])!r}] rad"
            )
    return q
