"""Validation of joint vectors and per-joint quantities: every error names the field, the value
and the joint.

Shared by the smoothers, the safety core and the systems (per-joint limits, trajectories,
positive scalars) and by every place that takes a configuration of an arm from a caller (the
inverse kinematics' initial target, the 6-DOF IK's seed, the collision model's query), so that
each says the same thing about a bad vector: the field, the value and, for a bad entry, the
joint. All checks raise ``ValueError`` (bad values) and never modify their inputs. Pure numpy
(and the top-level ``user_input``'s quoting): the lowest layer, importable from every package.

A joint vector's messages, from :func:`check_joint_vector` and :func:`check_finite_per_joint`
(every system's initial pose and limits, every smoother's start pose, ...), are one line each,
the field as the caller wrote it, then the value cut short or the bad entry and its joint::

    q_start = [0.0] has shape (1,); expected (2,), one per joint of ('shoulder', 'elbow')
    q_start[1] = nan for joint 1 ('elbow') must be finite
    q_start[1] = 3.2 for joint 1 ('elbow') must be finite and within [-2.9, 2.9] rad
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from telesmooth.user_input import quote

__all__ = [
    "as_per_joint",
    "check_finite_per_joint",
    "check_joint_limits",
    "check_joint_vector",
    "check_positive_int",
    "check_positive_scalar",
    "check_trajectory",
]


def check_finite_per_joint(field: str, value, num_joints: int,
                           joint_names: Sequence[str] | None = None) -> np.ndarray:
    """``value`` as a float array of shape (num_joints,) whose entries are all finite.

    The count-and-finite check of a joint vector: one number per joint, none NaN or ±inf. It
    is :func:`check_joint_vector` without the limits and without needing the joints' names
    (a system that knows only its joint count), for any per-joint quantity (a pose, a
    measurement, the joint limits themselves). The messages are those of
    :func:`check_joint_vector`.

    Args:
        field: The argument's name as the caller wrote it (e.g. ``"initial_position_rad"``).
        value: The vector, (num_joints,).
        num_joints: n.
        joint_names: The joints' names, (n,), for the messages; None if unknown (the joint
            is then named by its index only).

    Returns:
        A new float array of shape (num_joints,).

    Raises:
        ValueError: in one line: if ``value`` is not numeric or does not have one entry per
            joint, the field, the value (cut short) and the joints; if an entry is not
            finite, the field, the index, the joint and the entry.
    """
    q = _joint_array(field, value, num_joints, joint_names)
    if not np.isfinite(q).all():
        i = int(np.flatnonzero(~np.isfinite(q))[0])
        raise ValueError(
            f"{field}[{i}] = {float(q[i])!r} for {_joint_label(i, joint_names)} must be finite"
        )
    return q


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
            the entry); see :func:`check_finite_per_joint`.
    """
    names = tuple(joint_names)
    if (lower is None) != (upper is None):
        raise ValueError("check_joint_vector: give both lower and upper limits, or neither")
    if lower is None:
        return check_finite_per_joint(field, value, len(names), names)
    q = _joint_array(field, value, len(names), names)
    for i, entry in enumerate(q):
        if not (math.isfinite(entry) and lower[i] <= entry <= upper[i]):
            raise ValueError(
                f"{field}[{i}] = {float(entry)!r} for {_joint_label(i, names)} must be finite "
                f"and within [{float(lower[i])!r}, {float(upper[i])!r}] rad"
            )
    return q


def check_joint_limits(lower_rad, upper_rad, joint_names: Sequence[str]
                       ) -> tuple[np.ndarray, np.ndarray]:
    """``lower_rad`` and ``upper_rad`` as finite joint vectors (:func:`check_joint_vector`)
    with lower < upper on every joint; the messages name the fields ``lower_rad`` and
    ``upper_rad``, the joint and both values.

    Returns:
        (lower, upper), new float arrays of shape (n,).
    """
    names = tuple(joint_names)
    lower = check_joint_vector("lower_rad", lower_rad, names)
    upper = check_joint_vector("upper_rad", upper_rad, names)
    for i in range(len(names)):
        if not lower[i] < upper[i]:
            raise ValueError(
                f"lower_rad[{i}] = {float(lower[i])!r} for {_joint_label(i, names)} must be "
                f"< upper_rad[{i}] = {float(upper[i])!r}")
    return lower, upper


def _joint_array(field: str, value, num_joints: int,
                 joint_names: Sequence[str] | None) -> np.ndarray:
    """``value`` as a new float array of shape (num_joints,) (entries not checked)."""
    try:
        q = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(
            f"{field} = {_quote_vector(value)} must be {num_joints} numbers, "
            f"{_one_per_joint(joint_names)}"
        ) from None
    if q.shape != (num_joints,):
        raise ValueError(
            f"{field} = {_quote_vector(value)} has shape {q.shape}; expected ({num_joints},), "
            f"{_one_per_joint(joint_names)}"
        )
    return q


def _quote_vector(value) -> str:
    """The value as the caller wrote it, on one line and cut short (an array as a list)."""
    return quote(value.tolist() if isinstance(value, np.ndarray) else value)


def _one_per_joint(joint_names: Sequence[str] | None) -> str:
    return "one per joint" if joint_names is None else f"one per joint of {tuple(joint_names)!r}"


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
