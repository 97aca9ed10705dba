"""Planar serial arms: the three joints of the air-bearing experiment.

In the paper's air-bearing experiment only three joints of the space arm
rotate, all about parallel vertical axes, so the arm moves in a horizontal
plane. This module models such an arm as a planar serial chain of revolute
joints and provides its forward kinematics (any number of joints) and the
analytic inverse kinematics of the three-joint (3R) case with a prescribed
end-effector orientation.

Conventions (used by every function here):

* The base frame has its origin on the first joint axis; x and y span the
  plane of motion; angles are counter-clockwise about +z, in radians.
* Joint ``i`` rotates link ``i`` relative to link ``i - 1`` (relative angles),
  and every joint angle is zero when the arm is stretched along +x.
* The end-effector point is the tip of the last link; its orientation is the
  absolute angle of the last link, i.e. the sum of all joint angles.

Everything here is a pure function of numpy arrays (no Drake), vectorised over
any number of leading dimensions.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

__all__ = [
    "AIR_BEARING_ARM",
    "AIR_BEARING_JOINT_LOWER_RAD",
    "AIR_BEARING_JOINT_NAMES",
    "AIR_BEARING_JOINT_UPPER_RAD",
    "AIR_BEARING_LINK_LENGTHS_M",
    "PlanarArm",
    "planar_3r_inverse_kinematics",
    "planar_3r_inverse_kinematics_point",
    "planar_end_effector_angle",
    "planar_forward_kinematics",
    "planar_pose_point",
]

# The paper's DH table for the arm is lost; these link lengths and limits are
# OUR values, chosen to give a ~0.9 m planar reach comparable to a laboratory
# air-bearing setup. They are not taken from the paper.
AIR_BEARING_LINK_LENGTHS_M: tuple[float, float, float] = (0.5, 0.4, 0.2)
"""Lengths of the shoulder, elbow and wrist links, m (our values, not the paper's)."""

AIR_BEARING_JOINT_NAMES: tuple[str, str, str] = ("shoulder", "elbow", "wrist")
"""Names of the three planar joints, base to tip."""

AIR_BEARING_JOINT_LOWER_RAD: tuple[float, float, float] = (math.radians(-170.0),) * 3
"""Lower joint limits, rad (-170 deg each; our values, not the paper's)."""

AIR_BEARING_JOINT_UPPER_RAD: tuple[float, float, float] = (math.radians(170.0),) * 3
"""Upper joint limits, rad (+170 deg each; our values, not the paper's)."""

# Relative slack on the 2R annulus test, so that targets placed exactly on the
# workspace boundary (e.g. the fully stretched pose) are not rejected because of
# rounding in the law of cosines. It is about 1e-12 of the reach, far below any
# physically meaningful distance.
_ANNULUS_RELATIVE_TOLERANCE = 1e-12


@dataclasses.dataclass(frozen=True)
class PlanarArm:
    """A planar serial arm of revolute joints with box joint limits.

    Attributes:
        link_lengths_m: Length of each link, base to tip, m; shape (num_joints,).
            Each must be positive and finite.
        joint_names: Name of each joint, base to tip; shape (num_joints,). Used
            in error messages and carried into trajectories. Must be unique.
        joint_lower_rad: Lower position limit of each joint, rad;
            shape (num_joints,).
        joint_upper_rad: Upper position limit of each joint, rad;
            shape (num_joints,). Each must be strictly above its lower limit.

    Sequences given for any field are stored as tuples (of float or str), so
    instances are hashable and immutable.

    Raises:
        ValueError: If the tuples have different lengths or are empty, a length
            is not positive and finite, a limit is not finite (infinite limits
            are allowed only as -inf lower / +inf upper), a lower limit is not
            below its upper limit, or joint names are empty or repeated. The
            message names the field, the offending value and the joint.
    """

    link_lengths_m: tuple[float, ...]
    joint_names: tuple[str, ...]
    joint_lower_rad: tuple[float, ...]
    joint_upper_rad: tuple[float, ...]

    def __post_init__(self) -> None:
        # Normalise to tuples so that lists or arrays given by callers cannot be
        # mutated behind the frozen dataclass.
        object.__setattr__(self, "link_lengths_m", tuple(float(v) for v in self.link_lengths_m))
        object.__setattr__(self, "joint_names", tuple(self.joint_names))
        object.__setattr__(self, "joint_lower_rad", tuple(float(v) for v in self.joint_lower_rad))
        object.__setattr__(self, "joint_upper_rad", tuple(float(v) for v in self.joint_upper_rad))

        num_joints = len(self.link_lengths_m)
        if num_joints == 0:
            raise ValueError("link_lengths_m = () must have at least one link")
        for field_name in ("joint_names", "joint_lower_rad", "joint_upper_rad"):
            value = getattr(self, field_name)
            if len(value) != num_joints:
                raise ValueError(
                    f"{field_name} = {value!r} has {len(value)} entries but "
                    f"link_lengths_m = {self.link_lengths_m!r} has {num_joints}"
                )
        for i, name in enumerate(self.joint_names):
            if not isinstance(name, str) or not name:
                raise ValueError(f"joint_names[{i}] = {name!r} must be a non-empty string")
            if name in self.joint_names[:i]:
                raise ValueError(f"joint_names[{i}] = {name!r} repeats an earlier joint name")
        for i, name in enumerate(self.joint_names):
            length = self.link_lengths_m[i]
            if not (math.isfinite(length) and length > 0.0):
                raise ValueError(
                    f"link_lengths_m[{i}] = {length!r} for joint {i} ({name!r}) "
                    "must be positive and finite"
                )
            lower = self.joint_lower_rad[i]
            upper = self.joint_upper_rad[i]
            if math.isnan(lower) or lower == math.inf:
                raise ValueError(
                    f"joint_lower_rad[{i}] = {lower!r} for joint {i} ({name!r}) "
                    "must be finite or -inf"
                )
            if math.isnan(upper) or upper == -math.inf:
                raise ValueError(
                    f"joint_upper_rad[{i}] = {upper!r} for joint {i} ({name!r}) "
                    "must be finite or +inf"
                )
            if not lower < upper:
                raise ValueError(
                    f"joint_lower_rad[{i}] = {lower!r} for joint {i} ({name!r}) must be below "
                    f"joint_upper_rad[{i}] = {upper!r}"
                )

    @property
    def num_joints(self) -> int:
        """Number of joints (= number of links)."""
        return len(self.link_lengths_m)

    @property
    def reach_m(self) -> float:
        """Maximum distance from the base to the end effector, m (sum of link lengths)."""
        return float(sum(self.link_lengths_m))


AIR_BEARING_ARM = PlanarArm(
    link_lengths_m=AIR_BEARING_LINK_LENGTHS_M,
    joint_names=AIR_BEARING_JOINT_NAMES,
    joint_lower_rad=AIR_BEARING_JOINT_LOWER_RAD,
    joint_upper_rad=AIR_BEARING_JOINT_UPPER_RAD,
)
"""The three-joint planar arm of the air-bearing experiment (our link lengths and limits)."""


def planar_forward_kinematics(q: np.ndarray, link_lengths_m: Sequence[float]) -> np.ndarray:
    """Position of the end effector of a planar serial arm.

    With absolute link angles theta_i = q_0 + ... + q_i,

        x = sum_i l_i cos(theta_i),   y = sum_i l_i sin(theta_i).

    Args:
        q: Joint angles, rad; shape (..., num_joints), any number of leading
            dimensions.
        link_lengths_m: Link lengths, base to tip, m; shape (num_joints,),
            num_joints >= 1.

    Returns:
        End-effector position in the base frame, m; shape (..., 2), last axis
        (x, y).

    Raises:
        ValueError: If ``link_lengths_m`` is not a non-empty 1-D sequence, or
            the last axis of ``q`` does not have one entry per link.
    """
    lengths = np.asarray(link_lengths_m, dtype=float)
    q = np.asarray(q, dtype=float)
    if lengths.ndim != 1 or lengths.size == 0:
        raise ValueError(
            f"link_lengths_m = {link_lengths_m!r} must be a non-empty 1-D sequence of lengths"
        )
    if q.ndim == 0 or q.shape[-1] != lengths.size:
        raise ValueError(
            f"q has shape {q.shape} but link_lengths_m has {lengths.size} links; "
            f"expected shape (..., {lengths.size})"
        )
    # theta_i = q_0 + ... + q_i (absolute angle of link i).
    theta = np.cumsum(q, axis=-1)
    x = np.sum(lengths * np.cos(theta), axis=-1)
    y = np.sum(lengths * np.sin(theta), axis=-1)
    return np.stack([x, y], axis=-1)


def planar_end_effector_angle(q: np.ndarray) -> np.ndarray:
    """Absolute orientation of the last link of a planar serial arm.

    Args:
        q: Joint angles, rad; shape (..., num_joints).

    Returns:
        Sum of the joint angles, rad; shape (...). Not wrapped: compare
        orientations modulo 2*pi.
    """
    return np.sum(np.asarray(q, dtype=float), axis=-1)


def _wrap_into_limits(q: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Pick, per joint, a 2*pi-equivalent angle that lies inside the limits.

    Args:
        q: Joint angles, rad; shape (..., num_joints).
        lower: Lower limits, rad (may be -inf); shape (num_joints,).
        upper: Upper limits, rad (may be +inf); shape (num_joints,).

    Returns:
        Angles equal to ``q`` modulo 2*pi, rad; shape (..., num_joints). In
        order of preference: ``q`` itself if inside [lower, upper], else its
        principal value in [-pi, pi) if inside, else the smallest
        representative at or above ``lower`` if inside, else the principal
        value (which then violates the limits).
    """

    def inside(angle: np.ndarray) -> np.ndarray:
        return (angle >= lower) & (angle <= upper)

    principal = np.mod(q + np.pi, 2.0 * np.pi) - np.pi
    finite_lower = np.where(np.isfinite(lower), lower, -np.pi)
    lowest_above_lower = finite_lower + np.mod(q - finite_lower, 2.0 * np.pi)
    wrapped = np.where(inside(lowest_above_lower), lowest_above_lower, principal)
    wrapped = np.where(inside(principal), principal, wrapped)
    return np.where(inside(q), q, wrapped)


def planar_3r_inverse_kinematics(
    xy: np.ndarray,
    phi_rad: np.ndarray | float,
    arm: PlanarArm,
    *,
    elbow: int = +1,
) -> tuple[np.ndarray, np.ndarray]:
    """Analytic inverse kinematics of a planar 3R arm with fixed end-effector angle.

    Shorthand: l1, l2, l3 = ``arm.link_lengths_m``; (x, y) = ``xy``;
    phi = ``phi_rad``; w = wrist point (tip of link 2); r = |w|.

        w = (x, y) - l3 [cos phi, sin phi]
        cos q2 = (r^2 - l1^2 - l2^2) / (2 l1 l2),   q2 = elbow * acos(cos q2)
        q1 = atan2(w_y, w_x) - atan2(l2 sin q2, l1 + l2 cos q2)
        q3 = phi - q1 - q2

    Each angle is then expressed by its 2*pi-equivalent inside the joint's
    limits when one exists (otherwise its principal value in [-pi, pi)).

    A target is *reachable* when the wrist point lies in the 2R annulus
    |l1 - l2| <= r <= l1 + l2 (with a relative slack of 1e-12 of l1 + l2 for
    rounding) AND all three angles lie within the arm's joint limits. Where it
    is reachable, ``planar_forward_kinematics(q)`` equals ``xy`` and
    ``planar_end_effector_angle(q)`` equals ``phi_rad`` modulo 2*pi, both to
    rounding.

    What is returned where the target is NOT reachable (always finite, never
    NaN, but never silently valid -- ``reachable`` is False):

    * wrist point outside the annulus: cos q2 is clamped to [-1, 1], giving the
      fully stretched (q2 = 0) or fully folded (|q2| = pi) arm whose wrist
      points along the ray from the base towards w; q3 still realises phi.
      Its forward kinematics is NOT ``xy``.
    * joint limit violated: the exact IK solution, outside the limits (it is
      not clamped).

    Args:
        xy: Target end-effector positions in the base frame, m; shape (..., 2).
        phi_rad: Target end-effector orientations (absolute angle of the last
            link), rad; scalar or shape broadcastable to ``xy.shape[:-1]``.
        arm: The arm; must have exactly three joints.
        elbow: +1 for the branch with q2 >= 0, -1 for q2 <= 0. The same branch
            is used for every target, so a continuous path that stays inside
            the annulus gives a continuous joint path (up to the 2*pi wrap of
            an angle, which cannot occur inside limits narrower than
            (-pi, pi]).

    Returns:
        A pair ``(q, reachable)``:
            q: Joint angles (shoulder, elbow, wrist), rad;
                shape (..., 3) where ... is the broadcast of ``xy.shape[:-1]``
                and ``phi_rad``'s shape. Finite everywhere.
            reachable: Boolean, shape (...); True where ``q`` reaches the target
                within the joint limits.

    Raises:
        ValueError: If ``arm`` does not have three joints, ``elbow`` is not +1
            or -1, ``xy`` does not have shape (..., 2), or ``xy`` / ``phi_rad``
            contain non-finite values.
    """
    if arm.num_joints != 3:
        raise ValueError(
            f"arm.num_joints = {arm.num_joints} (joint_names = {arm.joint_names!r}); "
            "planar_3r_inverse_kinematics needs exactly 3 joints"
        )
    if elbow not in (1, -1):
        raise ValueError(f"elbow = {elbow!r} must be +1 or -1")
    xy = np.asarray(xy, dtype=float)
    phi = np.asarray(phi_rad, dtype=float)
    if xy.ndim == 0 or xy.shape[-1] != 2:
        raise ValueError(f"xy has shape {xy.shape}; expected shape (..., 2)")
    if not np.all(np.isfinite(xy)):
        raise ValueError("xy contains non-finite values; every target must be finite")
    if not np.all(np.isfinite(phi)):
        raise ValueError(f"phi_rad = {phi_rad!r} contains non-finite values")

    # Shorthand for the link lengths (paper-free, textbook 2R + wrist notation).
    l1, l2, l3 = arm.link_lengths_m
    x = xy[..., 0]
    y = xy[..., 1]
    x, y, phi = np.broadcast_arrays(x, y, phi)

    # w = (x, y) - l3 [cos phi, sin phi]
    wx = x - l3 * np.cos(phi)
    wy = y - l3 * np.sin(phi)
    r_squared = wx * wx + wy * wy

    # cos q2 = (r^2 - l1^2 - l2^2) / (2 l1 l2)
    cos_q2 = (r_squared - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
    # Annulus test on r (not on cos q2) so the slack is a distance.
    r = np.sqrt(r_squared)
    slack_m = _ANNULUS_RELATIVE_TOLERANCE * (l1 + l2)
    in_annulus = (r <= (l1 + l2) + slack_m) & (r >= abs(l1 - l2) - slack_m)
    cos_q2 = np.clip(cos_q2, -1.0, 1.0)

    # q2 = elbow * acos(cos q2), via atan2 for accuracy near the stretched pose.
    sin_q2 = elbow * np.sqrt(np.maximum(0.0, 1.0 - cos_q2 * cos_q2))
    q2 = np.arctan2(sin_q2, cos_q2)
    # q1 = atan2(w_y, w_x) - atan2(l2 sin q2, l1 + l2 cos q2)
    q1 = np.arctan2(wy, wx) - np.arctan2(l2 * sin_q2, l1 + l2 * cos_q2)
    # q3 = phi - q1 - q2
    q3 = phi - q1 - q2

    q = np.stack([q1, q2, q3], axis=-1)
    lower = np.asarray(arm.joint_lower_rad)
    upper = np.asarray(arm.joint_upper_rad)
    q = _wrap_into_limits(q, lower, upper)
    within_limits = np.all((q >= lower) & (q <= upper), axis=-1)
    return q, in_annulus & within_limits


# -- one target at a time, in plain floats --------------------------------------------------
#
# The ground station's IK converts one pose per 10 ms. numpy's per-call overhead on 3-element
# arrays makes the vectorised functions above cost ~170 µs per pose; these scalar twins of
# the same formulas (same order of operations; tests compare them on random targets) cost a
# few µs.


def _wrap_angle_into_limits(angle: float, lower: float, upper: float) -> float:
    """:func:`_wrap_into_limits` for one angle (same preference order)."""
    if lower <= angle <= upper:
        return angle
    principal = (angle + math.pi) % (2.0 * math.pi) - math.pi
    if lower <= principal <= upper:
        return principal
    finite_lower = lower if math.isfinite(lower) else -math.pi
    lowest_above_lower = finite_lower + (angle - finite_lower) % (2.0 * math.pi)
    return lowest_above_lower if lower <= lowest_above_lower <= upper else principal


def planar_3r_inverse_kinematics_point(
    x_m: float, y_m: float, phi_rad: float, arm: PlanarArm, *, elbow: int = +1
) -> tuple[tuple[float, float, float], bool]:
    """:func:`planar_3r_inverse_kinematics` of one target, in plain floats.

    Same formulas, branch, wrapping into the limits and reachability test; for the 100 Hz
    ground-station IK, where numpy's overhead on three numbers dominates.

    Args:
        x_m, y_m: Target end-effector position in the base frame, m (finite).
        phi_rad: Target end-effector orientation, rad (finite).
        arm: The arm; must have exactly three joints.
        elbow: +1 (q2 >= 0) or -1 (q2 <= 0).

    Returns:
        ``((q1, q2, q3), reachable)`` as :func:`planar_3r_inverse_kinematics` returns them.

    Raises:
        ValueError: If ``arm`` does not have three joints, ``elbow`` is not +1 or -1, or a
            target value is not finite.
    """
    if arm.num_joints != 3:
        raise ValueError(
            f"arm.num_joints = {arm.num_joints} (joint_names = {arm.joint_names!r}); "
            "planar_3r_inverse_kinematics_point needs exactly 3 joints"
        )
    if elbow not in (1, -1):
        raise ValueError(f"elbow = {elbow!r} must be +1 or -1")
    x, y, phi = float(x_m), float(y_m), float(phi_rad)
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(phi)):
        raise ValueError(f"target (x_m, y_m, phi_rad) = {(x_m, y_m, phi_rad)!r} must be finite")
    l1, l2, l3 = arm.link_lengths_m
    # w = (x, y) - l3 [cos phi, sin phi]
    wx = x - l3 * math.cos(phi)
    wy = y - l3 * math.sin(phi)
    r_squared = wx * wx + wy * wy
    # cos q2 = (r^2 - l1^2 - l2^2) / (2 l1 l2)
    cos_q2 = (r_squared - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
    r = math.sqrt(r_squared)
    slack_m = _ANNULUS_RELATIVE_TOLERANCE * (l1 + l2)
    in_annulus = (l1 + l2) + slack_m >= r >= abs(l1 - l2) - slack_m
    cos_q2 = min(max(cos_q2, -1.0), 1.0)
    # q2 = elbow * acos(cos q2), via atan2.
    sin_q2 = elbow * math.sqrt(max(0.0, 1.0 - cos_q2 * cos_q2))
    q2 = math.atan2(sin_q2, cos_q2)
    # q1 = atan2(w_y, w_x) - atan2(l2 sin q2, l1 + l2 cos q2)
    q1 = math.atan2(wy, wx) - math.atan2(l2 * sin_q2, l1 + l2 * cos_q2)
    # q3 = phi - q1 - q2
    q3 = phi - q1 - q2
    lower, upper = arm.joint_lower_rad, arm.joint_upper_rad
    q = tuple(_wrap_angle_into_limits(angle, lower[i], upper[i])
              for i, angle in enumerate((q1, q2, q3)))
    within_limits = all(lower[i] <= q[i] <= upper[i] for i in range(3))
    return q, bool(in_annulus and within_limits)


def planar_pose_point(q_rad, link_lengths_m: Sequence[float]) -> tuple[float, float, float]:
    """(x, y, phi) of one joint vector, in plain floats: :func:`planar_forward_kinematics`
    and :func:`planar_end_effector_angle` (summed in the same order) for one configuration.

    Args:
        q_rad: Joint angles, rad; one per link.
        link_lengths_m: Link lengths, base to tip, m.
    """
    x = y = theta = 0.0
    for angle, length in zip(q_rad, link_lengths_m, strict=True):
        # theta_i = q_0 + ... + q_i
        theta += float(angle)
        x += length * math.cos(theta)
        y += length * math.sin(theta)
    return x, y, theta
