"""The ground station's inverse kinematics as a pure step: the clutch, the solve's verdict and
the holds.

At every update (100 Hz) the step reads the operator's pose command u and clutch value e:

* e not finite: the target holds, INVALID_INPUT (failed), the clutch counts as released;
* e <= 0.5: the target holds, DISENGAGED (not failed), the clutch released;
* u missing or not finite: the target holds, INVALID_INPUT (the clutch as it was);
* otherwise, if the clutch was released at the last update, it re-engages: the target first
  jumps to the anchor when ``anchor`` > 0.5 and ``q_anchor`` is finite and within the joint
  limits, and the clutch offset is re-indexed so that the command continues from the target's
  pose; the command is u moved by the offset. The command the last update solved (bit for bit,
  the clutch engaged both times) keeps its status and target without a new solve; any other
  command is solved from the held target and accepted only if the solve succeeds within the
  limits, the tolerances and the largest joint step, else the target holds and the status
  says why (:class:`IkStatus`).

The kinematics come as plain callables in :class:`IkParams` (forward kinematics, the clutch
offset and its application, and for the 6-DOF arm the numerical solve), so the step needs no
Drake; the planar arm's closed form is :mod:`telesmooth.arms.planar`'s.
:class:`~telesmooth.systems.inverse_kinematics.InverseKinematicsSystem` is the thin Drake
system around :func:`ik_step`; its callables run the rigid Drake plant of the 6-DOF arm.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from telesmooth.arms.planar import (
    PlanarArm,
    planar_3r_inverse_kinematics_point,
    planar_pose_point,
)

__all__ = ["IkInputs", "IkParams", "IkState", "IkStatus", "SOLVE_OUTCOMES", "ik_anchor",
           "ik_failed", "ik_initial_state", "ik_solve", "ik_step"]


class IkStatus(enum.IntEnum):
    """Outcome of the last update (the ``ik_status`` port of
    :class:`~telesmooth.systems.inverse_kinematics.InverseKinematicsSystem`)."""

    OK = 0
    """The command was converted; ``q_target`` is its joint target."""
    DISENGAGED = 1
    """The clutch is released: the target holds (not a failure)."""
    INVALID_INPUT = 2
    """A non-finite (or missing) pose command or clutch value: held, failed."""
    UNREACHABLE = 3
    """The commanded pose is outside the workspace (or, 6-DOF, at a singularity): held."""
    JOINT_LIMIT = 4
    """Reaching the commanded pose would violate a joint limit: held."""
    JOINT_STEP = 5
    """The target would jump by more than ``max_joint_step_rad`` in some joint: held."""
    SOLVER_ERROR = 6
    """The numerical solver raised: held."""


SOLVE_OUTCOMES = frozenset((IkStatus.OK, IkStatus.UNREACHABLE, IkStatus.JOINT_LIMIT,
                            IkStatus.JOINT_STEP, IkStatus.SOLVER_ERROR))
"""The statuses an IK solve of ``pose_commanded`` can end with (not DISENGAGED/INVALID)."""

_SOLVER_FAILURES = {"JOINT_LIMIT": IkStatus.JOINT_LIMIT, "JOINT_STEP": IkStatus.JOINT_STEP}
"""The 6-DOF solver's failure statuses (by name) that keep their reason; any other failure is
UNREACHABLE."""


@dataclasses.dataclass(frozen=True, eq=False)
class IkParams:
    """The arm, the acceptance bounds and the kinematics as callables.

    Attributes:
        lower_rad, upper_rad: The joint limits, rad, (n,).
        max_joint_step_rad: Largest accepted change of any joint between two targets, rad.
        position_tolerance_m, orientation_tolerance_rad: Largest accepted residuals.
        forward_kinematics: q (n,) → the tool's pose (m,).
        clutch_offset: (reference pose, device pose) → the offset mapping the device pose
            onto the reference pose.
        apply_clutch_offset: (device pose, offset) → the commanded pose.
        planar_arm: The planar 3R arm (closed-form IK on ``elbow``'s branch), or None for the
            6-DOF arm, solved by ``space_solve``.
        elbow: +1 or -1, the planar arm's elbow branch.
        space_solve: (pose, seed q) → a result with ``q_rad``, ``success`` and ``error``
            (``status`` with a ``name``, ``position_m``, ``orientation_rad``), as
            :func:`~telesmooth.arms.space_arm_ik.solve_space_arm_ik`; RuntimeError if the
            solver fails.
    """

    lower_rad: np.ndarray
    upper_rad: np.ndarray
    max_joint_step_rad: float
    position_tolerance_m: float
    orientation_tolerance_rad: float
    forward_kinematics: Callable
    clutch_offset: Callable
    apply_clutch_offset: Callable
    planar_arm: PlanarArm | None = None
    elbow: int = 1
    space_solve: Callable | None = None


class IkState(NamedTuple):
    """The IK stage between updates."""

    q: np.ndarray                # q_target (n,), rad: the last accepted target
    offset: np.ndarray           # the clutch offset (planar (3,); 6-DOF (7,): dp, R_off wxyz)
    engaged: bool                # the clutch at the last update
    status: IkStatus             # the last update's outcome
    pose_commanded: np.ndarray   # (m,) the last command solved


class IkInputs(NamedTuple):
    """One update's inputs; ``anchor`` and ``q_anchor`` are read only when the clutch was
    released at the last update (re-engagement), so they may be None otherwise."""

    pose: np.ndarray | None      # pose_desired (m,), None when not connected
    enable: float                # the clutch value (1.0 when not connected)
    anchor: float | None = None  # the anchor flag, None when not connected
    q_anchor: np.ndarray | None = None   # (n,) the anchor target, None when not connected


def ik_initial_state(q0, offset0, pose0) -> IkState:
    """Engaged with ``offset0`` at target ``q0`` (n,), status OK, ``pose0`` its pose."""
    return IkState(q=np.array(q0, dtype=float), offset=np.array(offset0, dtype=float),
                   engaged=True, status=IkStatus.OK, pose_commanded=np.array(pose0, dtype=float))


def ik_failed(status: IkStatus) -> bool:
    """The update rejected the command and held (any status but OK and DISENGAGED)."""
    return status not in (IkStatus.OK, IkStatus.DISENGAGED)


def ik_anchor(params: IkParams, anchor, q_anchor) -> np.ndarray | None:
    """The target to re-engage at, (n,) rad: ``q_anchor`` while ``anchor`` > 0.5, if both are
    given and ``q_anchor`` is finite and within the joint limits; else None."""
    if anchor is None or q_anchor is None or not anchor > 0.5:
        return None
    q = np.array(q_anchor, dtype=float)
    if not (np.all(np.isfinite(q)) and np.all(q >= params.lower_rad)
            and np.all(q <= params.upper_rad)):
        return None
    return q


def ik_solve(params: IkParams, pose_commanded, q_previous) -> tuple[np.ndarray, IkStatus]:
    """(q, status): the IK answer for ``pose_commanded`` seeded with ``q_previous``."""
    lower, upper = params.lower_rad, params.upper_rad
    if params.planar_arm is not None:
        # One pose in plain floats (the scalar twin of planar_3r_inverse_kinematics:
        # numpy's overhead on three numbers cost ~170 µs per call).
        x, y, phi = (float(v) for v in pose_commanded)
        angles, reachable = planar_3r_inverse_kinematics_point(
            x, y, phi, params.planar_arm, elbow=params.elbow)
        q = np.array(angles)
        within_limits = all(lower[i] <= angles[i] <= upper[i] for i in range(3))
        if not reachable:
            return q, IkStatus.UNREACHABLE if within_limits else IkStatus.JOINT_LIMIT
        # Belt and braces: the closed form is exact, so this residual is ~1e-16.
        x_q, y_q, phi_q = planar_pose_point(angles, params.planar_arm.link_lengths_m)
        position_m = math.hypot(x_q - x, y_q - y)
        orientation_rad = abs(math.remainder(phi_q - phi, 2.0 * math.pi))
    else:
        try:
            result = params.space_solve(pose_commanded, q_previous)
        except RuntimeError:
            return q_previous, IkStatus.SOLVER_ERROR
        if not result.success:
            return result.q_rad, _SOLVER_FAILURES.get(result.error.status.name,
                                                      IkStatus.UNREACHABLE)
        q = result.q_rad
        within_limits = bool(np.all((q >= lower) & (q <= upper)))
        # The solver already measured the pose error of this q against this target.
        position_m, orientation_rad = result.error.position_m, result.error.orientation_rad
    if not within_limits:
        return q, IkStatus.JOINT_LIMIT
    if not (position_m <= params.position_tolerance_m
            and orientation_rad <= params.orientation_tolerance_rad):
        return q, IkStatus.UNREACHABLE
    step = params.max_joint_step_rad
    if not all(abs(float(a) - float(b)) <= step for a, b in zip(q, q_previous)):
        return q, IkStatus.JOINT_STEP      # (a NaN fails the comparison too)
    return q, IkStatus.OK


def ik_step(params: IkParams, state: IkState, inputs: IkInputs) -> IkState:
    """The IK stage after one update (module docstring); ``state`` itself when nothing
    changes (the clutch released and held, or the same command as the last solve)."""
    enable, pose = inputs.enable, inputs.pose
    if not math.isfinite(enable):
        return _next(state, IkStatus.INVALID_INPUT, engaged=False)
    if enable <= 0.5:
        return _next(state, IkStatus.DISENGAGED, engaged=False)
    if pose is None or not all(map(math.isfinite, pose)):
        return _next(state, IkStatus.INVALID_INPUT, engaged=state.engaged)
    q, offset, q_new, pose_commanded = state.q, state.offset, None, None
    if not state.engaged:
        anchor = ik_anchor(params, inputs.anchor, inputs.q_anchor)
        if anchor is not None:
            # Re-anchored at the robot's commanded pose: the target continues from there
            # (it held elsewhere while the FIFO held the robot).
            q = q_new = anchor
        # Re-index: the command continues from the held target's pose.
        offset = params.clutch_offset(params.forward_kinematics(q), pose)
    command = params.apply_clutch_offset(pose, offset)
    if (state.engaged and state.status in SOLVE_OUTCOMES
            and np.array_equal(command, state.pose_commanded)):
        # The command the last update solved, from the target it held or set: the answer
        # would be the same, so it is not computed again (an operator who holds still
        # costs nothing).
        status = state.status
    elif all(map(math.isfinite, command)):
        pose_commanded = command
        solution, status = ik_solve(params, command, q)
        if status == IkStatus.OK and all(map(math.isfinite, solution)):
            q_new = solution
    else:  # cannot happen for finite inputs; hold rather than trust it
        status = IkStatus.INVALID_INPUT
    return _next(state, status, engaged=True, q=q_new,
                 offset=None if state.engaged else offset, pose_commanded=pose_commanded)


def _next(state: IkState, status: IkStatus, *, engaged: bool, q=None, offset=None,
          pose_commanded=None) -> IkState:
    """``state`` with the fields given (None: kept); ``state`` itself if none changes."""
    if (q is None and offset is None and pose_commanded is None and engaged == state.engaged
            and status == state.status):
        return state
    return IkState(q=state.q if q is None else np.array(q, dtype=float),
                   offset=state.offset if offset is None else np.array(offset, dtype=float),
                   engaged=engaged, status=status,
                   pose_commanded=(state.pose_commanded if pose_commanded is None
                                   else np.array(pose_commanded, dtype=float)))
