"""Validation of joint vectors and per-joint quantities: every error names the field, the value
and the joint.

Shared by the smoothers, the safety core and the systems (per-joint limits, trajectories,
positive scalars) and by every place that takes a configuration of an arm from a caller (the
inverse kinematics' initial target, the 6-DOF IK's seed, the collision model's query), so that
each says the same thing about a bad vector: the field, the value and, for a bad entry, the
joint. All checks raise ``ValueError`` (bad values) and never modify their inputs. Pure numpy:
the lowest layer, importable from every package.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

__all__ = [
    "as_per_joint",
    "check_joint_vector",
    "check_positive_int",
    "check_positive_scalar",
    "check_trajectory",
]


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


def _joint_label(index: int, joint_names: Sequence[str] | None) -> str:
    if joint_names is not None and index < len(joint_names):
        return f"joint {index} ({joint_names[index]!r})"
    return f"joint {index}"


def check_positive_scalar(field: str, value) -> float:
    """Returns ``float(value)`` if it is a finite number > 0, else raises ValueError."""
    if isinstance(value, (bool, str)):
        raise ValueError(f"{field} = {value!r} must be a number")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{field} = {value!r} must be a number") from None
    if not math.isfinite(number) or number <= 0.0:
        raise ValueError(f"{field} = {value!r} must be finite and > 0")
    return number


def check_positive_int(field: str, value, *, minimum: int = 1) -> int:
    """Returns ``int(value)`` if it is an integer ≥ ``minimum``, else raises ValueError."""
    if (isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating))
            or not float(value).is_integer() or int(value) < minimum):
        raise ValueError(f"{field} = {value!r} must be an integer >= {minimum}")
    return int(value)


def as_per_joint(
    field: str,
    value,
    num_joints: int,
    joint_names: Sequence[str] | None = None,
    *,
    allow_inf: bool = False,
) -> np.ndarray:
    """Broadcasts a per-joint positive quantity to shape ``(num_joints,)``.

    Args:
        field: name used in error messages (e.g. ``"max_acceleration_rad_per_s2"``).
        value: a scalar (all joints), a sequence of ``num_joints`` numbers, or a mapping
            from joint name to number that names every joint exactly once.
        num_joints: number of joints.
        joint_names: names used to resolve a mapping and to label errors.
        allow_inf: accept +inf (an inactive limit).

    Raises:
        ValueError: wrong length, unknown or missing joint names, non-finite or non-positive
            entries; the message names the field, the value and the joint.
    """
    if isinstance(value, Mapping):
        if joint_names is None:
            raise ValueError(f"{field}: per-joint values by name need the joint names")
        unknown = [name for name in value if name not in joint_names]
        if unknown:
            raise ValueError(
                f"{field}: unknown joint name(s) {unknown}; the joints are {list(joint_names)}"
            )
        missing = [name for name in joint_names if name not in value]
        if missing:
            raise ValueError(f"{field}: no value given for joint(s) {missing}")
        value = [value[name] for name in joint_names]
    try:
        array = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{field} = {value!r} must be a number or a list of numbers") from None
    if array.ndim == 0:
        array = np.full(num_joints, float(array))
    if array.shape != (num_joints,):
        raise ValueError(
            f"{field} has {array.size} value(s) {np.ravel(array).tolist()} but there are "
            f"{num_joints} joints; give one value for all joints or one per joint"
        )
    for index, entry in enumerate(array):
        bad = math.isnan(entry) or entry <= 0.0 or (math.isinf(entry) and not allow_inf)
        if bad:
            rule = "> 0" if allow_inf else "finite and > 0"
            raise ValueError(
                f"{field}[{index}] = {float(entry)!r} for {_joint_label(index, joint_names)} "
                f"must be {rule}"
            )
    return array


def check_trajectory(
    field: str, values, *, num_joints: int | None = None, joint_names=None, min_samples: int = 1
) -> np.ndarray:
    """Checks a trajectory array of shape ``(num_samples, num_joints)``.

    Raises:
        ValueError: wrong rank or joint count, too few samples, or a NaN/inf entry (the
            message gives the sample index, the joint and the value).
    """
    array = np.asarray(values, dtype=float)
    if array.ndim != 2:
        raise ValueError(
            f"{field} must have shape (num_samples, num_joints); got shape {array.shape}"
        )
    if num_joints is not None and array.shape[1] != num_joints:
        raise ValueError(
            f"{field} has {array.shape[1]} joint column(s) but {num_joints} were expected"
        )
    if array.shape[0] < min_samples:
        raise ValueError(
            f"{field} has {array.shape[0]} sample(s); at least {min_samples} are needed"
        )
    bad = ~np.isfinite(array)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise ValueError(
            f"{field}[{row}, {col}] = {float(array[row, col])!r} for "
            f"{_joint_label(int(col), joint_names)} at sample {row} is not finite"
            f" ({int(bad.sum())} non-finite value(s) in all)"
        )
    return array
