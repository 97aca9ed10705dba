"""Collision queries of the pre-simulator: signed distances between a rigid arm and its workspace.

The ground station's pre-simulator shows the newest inverse-kinematics target; before that
target is queued for the robot (docs/method.md §5.2) we ask how close the rigid arm at that
configuration comes to the workspace (obstacle boxes and bounding-box walls) and to itself.
:class:`ArmCollisionModel` answers that question for one joint vector at a time. It is plain
kinematics: a continuous (``time_step = 0``), never simulated MultibodyPlant with the rigid arm
model and the static workspace, connected to a SceneGraph inside a private two-system diagram
that owns one context. No LeafSystem of ours is involved; the periodic, latched flag for the
teleoperation chain is :class:`telesmooth.systems.collision_checker.CollisionChecker`.

Which pairs are checked: every arm link against every workspace box, and every pair of arm
bodies that the model does not filter (the model filters consecutive links and the arm's
``extra_filtered_pairs``; Drake also filters geometry that is welded together, so the fixed
base never "collides" with the fixed walls). ``extra_filtered_pairs`` given to the
constructor filters more pairs in this model only.

Distances come from ``QueryObject.ComputeSignedDistancePairwiseClosestPoints(max_distance=h)``
with a horizon h: pairs farther apart than h are not computed, which bounds the cost, and the
reported minimum is min(d_min, h). Negative distances are penetration depths.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np
from pydrake.geometry import CollisionFilterDeclaration, GeometrySet, Role
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.systems.framework import DiagramBuilder

from telesmooth.arms.description import ArmDescription
from telesmooth.arms.drake_models import add_arm, add_workspace
from telesmooth.arms.joint_vectors import check_joint_vector
from telesmooth.arms.workspace import Workspace

__all__ = ["ArmCollisionModel", "CollisionQuery", "DEFAULT_DISTANCE_HORIZON_M"]

DEFAULT_DISTANCE_HORIZON_M = 0.2
"""Default distance horizon h, m: pairs farther apart are reported as h."""


@dataclasses.dataclass(frozen=True)
class CollisionQuery:
    """The closest pair of one collision query.

    Attributes:
        min_distance_m: min(smallest signed distance over all checked pairs, horizon), m.
            Negative: the two bodies interpenetrate by that depth.
        body_a: Name of the arm body of the closest pair (``"base"``, ``"link1"``, ...; for
            an arm-arm pair the one nearer the base), or ``""`` when no pair is closer than
            the horizon.
        body_b: Name of the other body: a workspace box (e.g. ``"fixture"``,
            ``"wall_x_upper"``) or an arm link farther from the base; ``""`` when no pair is
            closer than the horizon.
    """

    min_distance_m: float
    body_a: str
    body_b: str

    def in_collision(self, margin_m: float = 0.0) -> bool:
        """True if the closest pair is nearer than ``margin_m``: min_distance_m < margin_m.

        Args:
            margin_m: Safety margin, m (finite). 0 means "touching or penetrating"; a margin
                at or above the model's horizon makes every configuration a collision.

        Raises:
            ValueError: If ``margin_m`` is not finite.
        """
        if not math.isfinite(margin_m):
            raise ValueError(f"margin_m = {margin_m!r} must be finite")
        return self.min_distance_m < margin_m


class ArmCollisionModel:
    """Signed-distance queries of a rigid arm in its workspace (kinematics only).

    Example::

        model = ArmCollisionModel(AIR_BEARING_ARM_3DOF, AIR_BEARING_WORKSPACE)
        result = model.query([0.0, 0.0, 0.0])
        result.min_distance_m            # 0.06 m: link3 to wall_x_upper
        result.in_collision(0.02)        # False

    The model owns one diagram context that every :meth:`query` overwrites (positions are set,
    then geometry is queried), so a model is cheap to query and must not be shared between
    threads. Queries do not depend on earlier queries.

    Args:
        arm: The arm; its committed rigid model (``arms/models/<name>.sdf``) is loaded.
        workspace: Obstacles and walls (the static part of the scene).
        distance_horizon_m: Horizon h, m (positive, finite): pairs farther apart than h are
            not computed, and the reported distance is at most h.
        extra_filtered_pairs: Additional (body, body) name pairs never checked in this model,
            e.g. ``(("link3", "link5"),)``; each name must be a body of the arm or a
            workspace box.

    Raises:
        ValueError: If the horizon is not positive and finite, a filtered pair names an
            unknown body, or the loaded model's joints do not match ``arm.joint_names``.
    """

    def __init__(
        self,
        arm: ArmDescription,
        workspace: Workspace,
        *,
        distance_horizon_m: float = DEFAULT_DISTANCE_HORIZON_M,
        extra_filtered_pairs: Sequence[tuple[str, str]] = (),
    ) -> None:
        if not isinstance(arm, ArmDescription):
            raise ValueError(f"arm = {arm!r} must be an ArmDescription")
        if not isinstance(workspace, Workspace):
            raise ValueError(f"workspace = {workspace!r} must be a Workspace")
        try:
            horizon = float(distance_horizon_m)
        except (TypeError, ValueError):
            raise ValueError(
                f"distance_horizon_m = {distance_horizon_m!r} must be a number of metres"
            ) from None
        if not (math.isfinite(horizon) and horizon > 0.0):
            raise ValueError(
                f"distance_horizon_m = {distance_horizon_m!r} must be positive and finite (m)"
            )
        self._arm = arm
        self._workspace = workspace
        self._horizon_m = horizon

        builder = DiagramBuilder()
        plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step=0.0)
        instance = add_arm(plant, arm, flexible=False)
        add_workspace(plant, workspace)
        plant.Finalize()
        # Map arm.joint_names order -> plant position index, so callers never depend on the
        # plant's internal ordering.
        self._position_index = np.empty(arm.num_joints, dtype=int)
        for i, name in enumerate(arm.joint_names):
            if not plant.HasJointNamed(name, instance):
                raise ValueError(
                    f"arm {arm.name!r}: joint {name!r} is missing from the loaded model "
                    f"{[plant.get_joint(j).name() for j in plant.GetJointIndices(instance)]!r}"
                )
            self._position_index[i] = plant.GetJointByName(name, instance).position_start()
        if plant.num_positions() != arm.num_joints:
            raise ValueError(
                f"arm {arm.name!r}: the loaded model has {plant.num_positions()} positions but "
                f"the description has {arm.num_joints} joints {arm.joint_names!r}"
            )

        self._apply_extra_filters(plant, scene_graph, extra_filtered_pairs)

        self._diagram = builder.Build()
        self._diagram.set_name(f"{arm.name}_collision_model")
        self._context = self._diagram.CreateDefaultContext()
        self._plant = plant
        self._plant_context = plant.GetMyMutableContextFromRoot(self._context)
        scene_graph_context = scene_graph.GetMyContextFromRoot(self._context)
        # The QueryObject is a live view of the context: evaluated once, it reflects the
        # positions set at query time (DRAKE_NOTES §4).
        self._query_object = scene_graph.get_query_output_port().Eval(scene_graph_context)
        inspector = self._query_object.inspector()
        self._body_name = {
            geometry_id: plant.GetBodyFromFrameId(inspector.GetFrameId(geometry_id)).name()
            for geometry_id in inspector.GetAllGeometryIds(Role.kProximity)
        }
        # Pairs are reported arm body first, base to tip, workspace boxes last.
        arm_bodies = (arm.base.name,) + tuple(link.name for link in arm.links)
        self._body_rank = {name: rank for rank, name in enumerate(arm_bodies)}
        self._candidate_pairs = tuple(sorted(
            self._ordered(self._body_name[a], self._body_name[b])
            for a, b in inspector.GetCollisionCandidates()
        ))
        self._q_full = np.zeros(plant.num_positions())

    def _ordered(self, name_a: str, name_b: str) -> tuple[str, str]:
        """(a, b) with the arm body nearer the base first and workspace boxes last."""
        last = len(self._body_rank)
        if self._body_rank.get(name_a, last) <= self._body_rank.get(name_b, last):
            return name_a, name_b
        return name_b, name_a

    @staticmethod
    def _apply_extra_filters(plant, scene_graph, pairs) -> None:
        """Excludes each (body, body) pair from collision in this model's SceneGraph."""
        manager = scene_graph.collision_filter_manager()
        for index, pair in enumerate(pairs):
            if isinstance(pair, str) or len(tuple(pair)) != 2:
                raise ValueError(
                    f"extra_filtered_pairs[{index}] = {pair!r} must be a pair of body names"
                )
            geometry_sets = []
            for name in pair:
                if not plant.HasBodyNamed(name):
                    raise ValueError(
                        f"extra_filtered_pairs[{index}] = {tuple(pair)!r}: body {name!r} is "
                        "neither an arm body nor a workspace box"
                    )
                geometry_sets.append(GeometrySet(
                    plant.GetCollisionGeometriesForBody(plant.GetBodyByName(name))
                ))
            manager.Apply(CollisionFilterDeclaration().ExcludeBetween(*geometry_sets))

    # -- properties -----------------------------------------------------------------------

    @property
    def arm(self) -> ArmDescription:
        return self._arm

    @property
    def workspace(self) -> Workspace:
        return self._workspace

    @property
    def distance_horizon_m(self) -> float:
        """The horizon h, m."""
        return self._horizon_m

    @property
    def num_joints(self) -> int:
        return self._arm.num_joints

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Order of the entries of ``q_rad`` in :meth:`query`."""
        return self._arm.joint_names

    @property
    def candidate_pairs(self) -> tuple[tuple[str, str], ...]:
        """The (body, body) name pairs that are checked, each ordered as in
        :class:`CollisionQuery` (arm body nearer the base first), sorted."""
        return self._candidate_pairs

    # -- queries --------------------------------------------------------------------------

    def validated_positions(self, q_rad) -> np.ndarray:
        """``q_rad`` as a float array of shape (num_joints,), or ValueError.

        Raises:
            ValueError: If ``q_rad`` does not have one entry per joint, or an entry is not
                finite (the message names the joint and the value).
        """
        return check_joint_vector("q_rad", q_rad, self.joint_names)

    def query(self, q_rad) -> CollisionQuery:
        """Closest pair and its signed distance at the joint angles ``q_rad``.

        Args:
            q_rad: Joint angles, rad; shape (num_joints,), ordered as :attr:`joint_names`.
                Joint limits are not checked (geometry is defined everywhere).

        Returns:
            The closest pair: distance min(d_min, h) in m, and the two body names (empty
            when no pair is within the horizon h).

        Raises:
            ValueError: If ``q_rad`` has the wrong size or a non-finite entry (the message
                names the joint and the value).
        """
        q = self.validated_positions(q_rad)
        self._q_full[self._position_index] = q
        self._plant.SetPositions(self._plant_context, self._q_full)
        pairs = self._query_object.ComputeSignedDistancePairwiseClosestPoints(
            max_distance=self._horizon_m
        )
        best = None
        for pair in pairs:
            if best is None or pair.distance < best.distance:
                best = pair
        if best is None or best.distance >= self._horizon_m:
            return CollisionQuery(self._horizon_m, "", "")
        body_a, body_b = self._ordered(self._body_name[best.id_A], self._body_name[best.id_B])
        return CollisionQuery(float(best.distance), body_a, body_b)
