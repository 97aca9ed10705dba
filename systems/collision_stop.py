"""The ground's collision stop: the pre-simulator's pose check and the planner it uses.

On a pre-simulator collision the FIFO either holds (the paper's policy, docs/method.md §5.2) or,
with ``on_collision = "stop"``, plays out a jerk-limited stop planned from the sent motion. The
planning is the pure core :func:`telesmooth.safety.stop.plan_stop` (see its module for how a
plan is made and when it falls back to the hold); this module adds what ties it to a
scenario: :class:`PreSimulatorPoseCheck` (the collision model and the joint limits as a pose
predicate), :func:`finite_smoother_limits` and :func:`MakeCollisionStopPlanner`, the ground's
:class:`~telesmooth.safety.stop.StopParams`.
"""

from __future__ import annotations

import numpy as np

from telesmooth.arms.joint_vectors import as_per_joint
from telesmooth.safety.stop import (
    STOP_OUTCOMES,
    STOPPABLE_ROUNDING_TOLERANCE,
    StopOutcome,
    StopParams,
    StopPlan,
    stop_params,
)

__all__ = [
    "STOP_OUTCOMES",
    "MakeCollisionStopPlanner",
    "PreSimulatorPoseCheck",
    "StopOutcome",
    "StopParams",
    "StopPlan",
    "finite_smoother_limits",
]


class PreSimulatorPoseCheck:
    """Whether the pre-simulator accepts a pose: within the joint limits and no collision.

    The same test as :class:`~telesmooth.systems.collision_checker.CollisionChecker` (smallest
    signed distance ≥ ``safety_margin_m``) plus the joint limits the onboard receiver enforces.
    Holds a collision model (a kinematics scratch context, fully overwritten per query, so
    the answer depends on the pose alone).

    Args:
        collision_model: An :class:`~telesmooth.arms.collision.ArmCollisionModel` (anything
            with ``query(q).in_collision(margin)``).
        safety_margin_m: The checker's margin, m.
        lower_rad, upper_rad: Joint limits, (J,) rad.
    """

    def __init__(self, collision_model, *, safety_margin_m: float, lower_rad, upper_rad):
        self._model = collision_model
        self._margin = float(safety_margin_m)
        self._lower = np.asarray(lower_rad, dtype=float)
        self._upper = np.asarray(upper_rad, dtype=float)

    def __call__(self, q) -> bool:
        q = np.asarray(q, dtype=float)
        if q.shape != self._lower.shape or not np.all(np.isfinite(q)):
            return False
        if np.any(q < self._lower) or np.any(q > self._upper):
            return False
        return not self._model.query(q).in_collision(self._margin)


def finite_smoother_limits(smoother_config, joint_names, *, purpose: str) -> dict:
    """{field: per-joint values} of the smoother's a_max and j_max, which must be finite.

    Raises:
        ValueError: naming the field, its value and ``purpose`` (what needs them finite).
    """
    names = tuple(joint_names)
    limits = {}
    for field in ("max_acceleration_rad_per_s2", "max_jerk_rad_per_s3"):
        values = as_per_joint(field, getattr(smoother_config, field), len(names), names,
                              allow_inf=True)
        if not np.all(np.isfinite(values)):
            raise ValueError(f"smoother.{field} = {getattr(smoother_config, field)!r} must be "
                             f"finite for {purpose}")
        limits[field] = values
    return limits


def MakeCollisionStopPlanner(*, period_s: float, smoother_config, arm, collision_model,
                             safety_margin_m: float, max_velocity=None) -> StopParams:
    """The stop parameters of the ground station: the smoother's limits, the pre-simulator's
    check, and the rounding tolerance ``STOPPABLE_ROUNDING_TOLERANCE``.

    Args:
        period_s: The uplink period, s.
        smoother_config: A ``ReducedQSmootherConfig`` (its a_max and j_max are the limits).
        arm: The ``ArmDescription`` (joint names and limits).
        collision_model: The pre-simulator's ``ArmCollisionModel`` (e.g.
            ``CollisionChecker.collision_model``).
        safety_margin_m: The checker's ``safety_margin_m``.
        max_velocity: Optional v_max, rad/s.

    Raises:
        ValueError: An infinite a_max or j_max (the stop needs finite limits), naming the field.
    """
    names = tuple(arm.joint_names)
    limits = finite_smoother_limits(smoother_config, names,
                                    purpose="fifo.on_collision = 'stop' (the stop brakes "
                                            "within these limits)")
    check = PreSimulatorPoseCheck(collision_model, safety_margin_m=safety_margin_m,
                                  lower_rad=arm.joint_lower_rad, upper_rad=arm.joint_upper_rad)
    return stop_params(
        dt_s=period_s, max_acceleration=limits["max_acceleration_rad_per_s2"],
        max_jerk=limits["max_jerk_rad_per_s3"], max_velocity=max_velocity,
        pose_is_safe=check, joint_names=names,
        # A sent stream the online-hard limiter kept inside the stoppable set can land a few
        # ulps outside it when its FD state is recomputed from the sent floats; that is not
        # a reason to fall back to the hold's velocity step (the onboard guard does the same).
        rounding_tolerance=STOPPABLE_ROUNDING_TOLERANCE)
