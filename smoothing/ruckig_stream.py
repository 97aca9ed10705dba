"""Ruckig on a stream: the peer baseline for jerk-limited tracking of the operator's samples.

A user who already owns a jerk-limited trajectory generator would feed it the stream: each
uplink sample z_k becomes Ruckig's new target (at rest, or moving with the operator's finite-
difference velocity), Ruckig plans the time-optimal jerk-limited motion from its current state
(position, velocity, acceleration) and advances one period Δt, and the position it reaches is
sent. The packets are samples of one continuous trajectory whose velocity, acceleration and jerk
stay within the limits, so their finite differences do too (a k-th difference divided by Δtᵏ is
a B-spline average of the k-th derivative).

Ruckig is an optional dependency (``pip install telesmooth[bench]``, PyPI ``ruckig``); it is
imported only when this method runs.
"""

from __future__ import annotations

import re

import numpy as np

from telesmooth.arms.joint_vectors import as_per_joint, check_positive_scalar, check_trajectory
from telesmooth.user_input import quote

__all__ = ["RUCKIG_SYNCHRONIZATIONS", "RUCKIG_TARGETS", "UNLIMITED_VELOCITY", "ruckig_stream"]

RUCKIG_TARGETS = ("rest", "moving")
"""``rest``: each sample is a target at rest; ``moving``: with the operator's FD velocity."""

RUCKIG_SYNCHRONIZATIONS = ("none", "time")
"""``none``: each joint reaches its target as fast as it can (best tracking); ``time``: all
joints arrive together (Ruckig's default, straighter joint-space paths)."""

UNLIMITED_VELOCITY = 1e3
"""Ruckig needs a finite velocity limit; this stands for "none", rad/s."""


def _import_ruckig():
    try:
        import ruckig
    except ImportError as error:  # pragma: no cover - exercised only without the extra
        raise ImportError(
            "the 'ruckig' method needs the Ruckig package: pip install 'telesmooth[bench]' "
            "(or pip install ruckig)") from error
    return ruckig


def ruckig_stream(positions, dt_s: float, *, max_acceleration, max_jerk, max_velocity=None,
                  target: str = "rest", synchronization: str = "none", start=None,
                  joint_names=None) -> np.ndarray:
    """Sends each sample through Ruckig as its next target and returns what would be sent.

    Args:
        positions: The stream z_k, rad, (N, J).
        dt_s: The stream's period Δt (Ruckig's control cycle), s.
        max_acceleration, max_jerk: a_max, j_max per joint (scalar, sequence or mapping).
        max_velocity: v_max per joint; None = :data:`UNLIMITED_VELOCITY`.
        target: One of :data:`RUCKIG_TARGETS`.
        synchronization: One of :data:`RUCKIG_SYNCHRONIZATIONS`.
        start: The robot's pose at rest before the stream, rad (J,); default z_0.
        joint_names: Labels for error messages.

    Returns:
        States (N, J, 4): position, velocity, acceleration and jerk Ruckig reaches at t_k
        (sample k is the target of the update that ends at t_k).

    Raises:
        ValueError: Bad input (naming the field and joint); an error result from Ruckig.
    """
    z = check_trajectory("positions", positions, joint_names=joint_names, min_samples=1)
    num_samples, num_joints = z.shape
    dt_s = check_positive_scalar("dt_s", dt_s)
    if target not in RUCKIG_TARGETS:
        raise ValueError(f"target = {target!r} must be one of {RUCKIG_TARGETS}")
    if synchronization not in RUCKIG_SYNCHRONIZATIONS:
        raise ValueError(
            f"synchronization = {synchronization!r} must be one of {RUCKIG_SYNCHRONIZATIONS}")
    a_max = as_per_joint("max_acceleration", max_acceleration, num_joints, joint_names)
    j_max = as_per_joint("max_jerk", max_jerk, num_joints, joint_names)
    v_max = (np.full(num_joints, UNLIMITED_VELOCITY) if max_velocity is None else
             as_per_joint("max_velocity", max_velocity, num_joints, joint_names))
    q0 = z[0] if start is None else check_trajectory(
        "start", np.reshape(start, (1, -1)), num_joints=num_joints, joint_names=joint_names)[0]
    ruckig = _import_ruckig()
    generator = ruckig.Ruckig(num_joints, dt_s)
    request = ruckig.InputParameter(num_joints)
    result = ruckig.OutputParameter(num_joints)
    request.max_velocity = v_max.tolist()
    request.max_acceleration = a_max.tolist()
    request.max_jerk = j_max.tolist()
    if synchronization == "none":
        request.synchronization = ruckig.Synchronization.No
    request.current_position = q0.tolist()
    request.current_velocity = [0.0] * num_joints
    request.current_acceleration = [0.0] * num_joints
    # The operator's velocity at each sample (central differences; the ends one-sided).
    velocity = np.gradient(z, dt_s, axis=0) if num_samples > 1 else np.zeros_like(z)
    velocity = np.clip(velocity, -v_max, v_max)
    states = np.empty((num_samples, num_joints, 4))
    for k in range(num_samples):
        request.target_position = z[k].tolist()
        if target == "moving":
            request.target_velocity = velocity[k].tolist()
        try:
            status = generator.update(request, result)
        except Exception as error:  # noqa: BLE001 - see _refusal
            status = error
        if status not in (ruckig.Result.Working, ruckig.Result.Finished):
            joint = _refused_joint(ruckig, request, dt_s, status)
            raise ValueError(_refusal(k, dt_s, z[k], status, joint, joint_names))
        states[k, :, 0] = result.new_position
        states[k, :, 1] = result.new_velocity
        states[k, :, 2] = result.new_acceleration
        states[k, :, 3] = result.new_jerk
        result.pass_to_input(request)
    return states


_RUCKIG_DOF = re.compile(r"dof:\s*(\d+)")


def _refused_joint(ruckig, request, dt_s: float, error) -> int | None:
    """The joint Ruckig could not plan: the "dof" its error names, else the first joint that
    fails alone (each planned as a one-joint problem from the same state), else the joint
    whose motion alone lasts longest (e.g. -101, a too long motion, is raised for the joints
    together when each alone plans), else None."""
    match = _RUCKIG_DOF.search(str(error))
    if match is not None:
        return int(match.group(1))
    durations = []
    for joint in range(request.degrees_of_freedom):
        alone = ruckig.InputParameter(1)
        for name in ("current_position", "current_velocity", "current_acceleration",
                     "target_position", "target_velocity", "target_acceleration",
                     "max_velocity", "max_acceleration", "max_jerk"):
            setattr(alone, name, [getattr(request, name)[joint]])
        output = ruckig.OutputParameter(1)
        try:
            status = ruckig.Ruckig(1, dt_s).update(alone, output)
        except Exception:  # noqa: BLE001 - a failure is the answer
            return joint
        if status not in (ruckig.Result.Working, ruckig.Result.Finished):
            return joint
        durations.append(output.trajectory.duration)
    return int(np.argmax(durations)) if durations else None


def _refusal(k: int, dt_s: float, target, error, index, joint_names) -> str:
    """The message for Ruckig refusing sample ``k`` (for joint ``index`` if known).

    Ruckig refuses by raising ``RuckigError`` (its text names the step and the "dof", our
    joint), by returning an error result, or, for a result its Python enum lacks (e.g.
    ErrorTrajectoryDuration = -101: the motion would last longer than Ruckig allows), by
    raising ``ValueError("-101 is not a valid Result")``."""
    text = str(error)
    joint = ""
    if index is not None and index < len(target):
        name = joint_names[index] if joint_names is not None and index < len(joint_names) \
            else None
        joint = f" for joint {index}" + (f" ({name!r})" if name is not None else "")
        target = target[index]
    if "-101" in text:
        reason = "the motion would last longer than Ruckig allows (a step far too large "\
                 "for the limits)"
    elif isinstance(error, Exception):
        reason = "Ruckig found no motion within the limits (limits too small or values too " \
                 "large for its numerics)"
    else:
        reason = f"Ruckig returned {error}"
    shown = quote(np.round(target, 6).tolist())
    return f"ruckig: sample {k} (t = {k * dt_s:g} s), target {shown}{joint}: {reason}"
