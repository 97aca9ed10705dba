"""Was a run of the flexible plant free of self-contact? A certificate from its recorded states.

The onboard plant (:class:`~telesmooth.systems.flexible_arm.FlexibleJointArm`) carries the
arm's collision geometry, so that links that meet push each other apart. Drake then asks the
geometry for contacts at every derivative evaluation of the continuous plant, whether or not
any pair is near: a quarter of a playback's integration time on the air-bearing arm. A
playback (``compare``, ``experiment``) therefore runs the plant without geometry and then
checks, from the states it recorded, that no pair of links that could touch came near each
other; when the check fails the run is discarded and simulated again with the geometry
(:func:`~telesmooth.diagrams.offline_playback.play_path`). When the geometry is in contact at
no state the integrator evaluates, its force is exactly zero and a run without it is the same
run. Those states are the recorded samples and the integrator's stages and trial steps, all
within one step (at most 10 ms) of a sample: the margin below covers them as it covers the
motion between samples.

The check. For each pair (A, B) of collision geometries the plant does not filter, the signed
distance d(q) depends on the joints between the two bodies only, and moving joint J by δ moves
the geometry on its far side by at most R_J·|δ|, where R_J bounds the distance from J's axis to
any point of that geometry (the sum of the fixed joint-to-joint distances along the chain, plus
the geometry's offset and bounding radius). Hence

    d(q') ≥ d(q) − Σ_J R_J·|q'_J − q_J|.

The exact distance is computed at every 25th recorded sample (an *anchor*) and every sample is
bounded from its nearest anchor; where a bound is not clear, from anchors every 5th sample, and
where it is still not clear, from the exact distance at the sample itself. Between
two samples (Δt apart) a joint moves at most Δt·2·max(|v| at either end) + 0.01 rad (an
engineering margin on the sampled speeds, not a proof: the samples are the integrator's dense
output at the tracker's 10 ms), which is subtracted too. The run is certified when every
bound exceeds :data:`CLEARANCE_M`. Arms whose paths include a joint that is not revolute, or
geometry other than spheres, capsules, cylinders, boxes and ellipsoids, are never certified
(their playbacks keep the geometry).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import threading

import numpy as np
from pydrake.geometry import Box, Capsule, Cylinder, Ellipsoid, Sphere
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.multibody.tree import RevoluteJoint
from pydrake.systems.framework import DiagramBuilder

from telesmooth.arms.chain_kinematics import joint_path
from telesmooth.arms.description import ArmDescription
from telesmooth.arms.drake_models import add_arm

__all__ = ["ANCHOR_STRIDE", "CLEARANCE_M", "EXCURSION_FLOOR_RAD", "SelfContactCertificate",
           "SelfContactCheck", "self_contact_certificate"]

CLEARANCE_M = 1e-3
"""A run is certified when every pair's lower bound on its distance exceeds this, m."""

ANCHOR_STRIDE = 25
"""Exact distances every this many recorded samples (0.25 s at the tracker's 10 ms)."""

EXCURSION_FLOOR_RAD = 0.01
"""Added to each joint's movement between two samples, rad (see the module's text)."""


@dataclasses.dataclass(frozen=True)
class SelfContactCheck:
    """The outcome of :meth:`SelfContactCertificate.check`.

    Attributes:
        certified: Every candidate pair stayed farther apart than :data:`CLEARANCE_M`
            throughout (the bound holds at every sample and between samples).
        min_clearance_m: The smallest lower bound over the run and the pairs, m (inf when
            the arm has no candidate pair).
        pair: The names of the geometries of that bound ("" when none).
        exact_queries: Samples at which the distances were computed exactly.
        reason: Why the arm cannot be certified at all ("" when it can).
    """

    certified: bool
    min_clearance_m: float
    pair: tuple[str, str]
    exact_queries: int
    reason: str = ""


@dataclasses.dataclass(frozen=True)
class _Pair:
    geometry_a: object
    geometry_b: object
    names: tuple[str, str]
    joints: np.ndarray          # indices into the arm's revolute joints
    radius_m: np.ndarray        # R_J of each of those joints


class SelfContactCertificate:
    """The candidate pairs of the flexible plant of ``arm``, with their joint bounds R_J, and
    an exact distance oracle (a continuous MultibodyPlant + SceneGraph of the same model).

    Build it with :func:`self_contact_certificate` (one per arm and process)."""

    def __init__(self, arm: ArmDescription):
        builder = DiagramBuilder()
        plant, scene_graph = AddMultibodyPlantSceneGraph(builder, 0.0)
        add_arm(plant, arm, flexible=True)
        plant.Finalize()
        self._diagram = builder.Build()
        self._context = self._diagram.CreateDefaultContext()
        self._plant = plant
        self._plant_context = plant.GetMyMutableContextFromRoot(self._context)
        self._scene_graph = scene_graph
        self._sg_context = scene_graph.GetMyContextFromRoot(self._context)
        # One context, shared by the threads of a process (e.g. a Dask worker's).
        self._lock = threading.Lock()
        self.num_positions = plant.num_positions()
        self.num_velocities = plant.num_velocities()
        self._revolute = [joint for joint in map(plant.get_joint, plant.GetJointIndices())
                          if isinstance(joint, RevoluteJoint)]
        self._revolute_slot = {j.index(): slot for slot, j in enumerate(self._revolute)}
        self._position_index = np.array([j.position_start() for j in self._revolute], int)
        self._velocity_index = np.array([j.velocity_start() for j in self._revolute], int)
        query = scene_graph.get_query_output_port().Eval(self._sg_context)
        inspector = query.inspector()
        self.reason = ""
        pairs = []
        for geometry_a, geometry_b in inspector.GetCollisionCandidates():
            try:
                pairs.append(self._pair(inspector, geometry_a, geometry_b))
            except ValueError as error:
                self.reason = str(error)
                break
        self._pairs = tuple(pairs) if not self.reason else ()

    @property
    def refusal(self) -> SelfContactCheck | None:
        """The check of every run of an arm the certificate cannot bound (never certified,
        ``reason`` says why); None when it can bound it."""
        if not self.reason:
            return None
        return SelfContactCheck(False, -math.inf, ("", ""), 0, self.reason)

    def radii(self) -> dict:
        """{pair names: {joint name: R_J (m)}}: the bounds the check uses."""
        return {pair.names: {self._revolute[j].name(): float(r)
                             for j, r in zip(pair.joints, pair.radius_m)}
                for pair in self._pairs}

    def distances(self, positions) -> np.ndarray:
        """Exact signed distance of every candidate pair at the plant positions, m, (pairs,)."""
        with self._lock:
            self._plant.SetPositions(self._plant_context, np.asarray(positions, dtype=float))
            query = self._scene_graph.get_query_output_port().Eval(self._sg_context)
            return np.array([query.ComputeSignedDistancePairClosestPoints(
                pair.geometry_a, pair.geometry_b).distance for pair in self._pairs])

    def check(self, positions, velocities, period_s: float) -> SelfContactCheck:
        """Certifies a run from its plant states sampled every ``period_s`` (see the module).

        Args:
            positions: The plant's positions at the samples, (T, num_positions).
            velocities: Its velocities at the same samples, (T, num_velocities).
            period_s: The time between samples, s (> 0); the run may go on up to one period
                after the last sample.
        """
        if self.reason:
            return self.refusal
        if not self._pairs:
            return SelfContactCheck(True, math.inf, ("", ""), 0)
        q = np.asarray(positions, dtype=float)
        v = np.asarray(velocities, dtype=float)
        if q.ndim != 2 or q.shape[1] != self.num_positions or q.shape[0] < 1 \
                or v.shape != (q.shape[0], self.num_velocities):
            raise ValueError(f"positions {q.shape} and velocities {v.shape} must be "
                             f"(T, {self.num_positions}) and (T, {self.num_velocities})")
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
            raise ValueError("positions and velocities must be finite")
        angles = q[:, self._position_index]
        speed = np.abs(v[:, self._velocity_index])
        # Movement from each sample to anywhere before the next one (or the run's end).
        peak = np.maximum(speed, np.vstack([speed[1:], speed[-1:]]))
        excursion = period_s * 2.0 * peak + EXCURSION_FLOOR_RAD
        count = angles.shape[0]
        exact = {}

        def bounds(samples, anchors):
            """Lower bounds (len(samples), pairs) from each sample's anchor's exact distance."""
            for k in np.unique(anchors):
                if int(k) not in exact:
                    exact[int(k)] = self.distances(q[k])
            result = np.array([exact[int(k)] for k in anchors])
            for p, pair in enumerate(self._pairs):
                moved = np.abs(angles[samples][:, pair.joints] - angles[anchors][:, pair.joints])
                result[:, p] -= (moved + excursion[samples][:, pair.joints]) @ pair.radius_m
            return result

        # Anchors every ANCHOR_STRIDE samples, then every 5 around the samples whose bound is
        # not clear, then those samples themselves.
        samples = np.arange(count)
        bound = np.full((count, len(self._pairs)), -math.inf)
        for stride in (ANCHOR_STRIDE, 5, 1):
            anchors = np.minimum(np.rint(samples / stride).astype(int) * stride, count - 1)
            # Each bound is valid: keep the better one.
            bound[samples] = np.maximum(bound[samples], bounds(samples, anchors))
            samples = np.flatnonzero(np.any(bound <= CLEARANCE_M, axis=1))
            if samples.size == 0:
                break
        k, p = np.unravel_index(int(np.argmin(bound)), bound.shape)
        least = float(bound[k, p])
        return SelfContactCheck(least > CLEARANCE_M, least, self._pairs[p].names, len(exact))

    # -- construction ----------------------------------------------------------------------

    def _pair(self, inspector, geometry_a, geometry_b) -> _Pair:
        plant = self._plant
        body_a = plant.GetBodyFromFrameId(inspector.GetFrameId(geometry_a))
        body_b = plant.GetBodyFromFrameId(inspector.GetFrameId(geometry_b))
        chain_a = joint_path(plant, body_a)
        chain_b = joint_path(plant, body_b)
        shared = {j.index() for j in chain_a} & {j.index() for j in chain_b}
        indices, radii = [], []
        for chain, geometry in ((chain_a, geometry_a), (chain_b, geometry_b)):
            # chain: the joints from the base down to the geometry's body.
            own = [j for j in chain if j.index() not in shared]
            offset = np.asarray(inspector.GetPoseInFrame(geometry).translation())
            reach = np.linalg.norm(offset - _child_origin(own[-1])) + _bounding_radius(
                inspector.GetShape(geometry), inspector.GetName(geometry)) if own else 0.0
            # From the deepest joint up: R_J = the joint-to-joint lengths below J + reach.
            for position in range(len(own) - 1, -1, -1):
                joint = own[position]
                if not isinstance(joint, RevoluteJoint):
                    raise ValueError(f"joint {joint.name()!r} between collision geometries is "
                                     f"a {type(joint).__name__}, not revolute")
                indices.append(self._revolute_slot[joint.index()])
                radii.append(reach)
                if position > 0:
                    above = own[position - 1]
                    reach += np.linalg.norm(_parent_origin(joint) - _child_origin(above))
        return _Pair(geometry_a, geometry_b,
                     (inspector.GetName(geometry_a), inspector.GetName(geometry_b)),
                     np.array(indices, int), np.array(radii, float))


def _child_origin(joint) -> np.ndarray:
    """Where the joint's axis point sits in its child body's frame."""
    return np.asarray(joint.frame_on_child().GetFixedPoseInBodyFrame().translation())


def _parent_origin(joint) -> np.ndarray:
    """Where the joint's axis point sits in its parent body's frame."""
    return np.asarray(joint.frame_on_parent().GetFixedPoseInBodyFrame().translation())


def _bounding_radius(shape, name: str) -> float:
    """The largest distance from the geometry's origin to a point of it, m."""
    if isinstance(shape, Sphere):
        return shape.radius()
    if isinstance(shape, Capsule):
        return shape.length() / 2.0 + shape.radius()
    if isinstance(shape, Cylinder):
        return math.hypot(shape.length() / 2.0, shape.radius())
    if isinstance(shape, Box):
        return 0.5 * math.sqrt(shape.width() ** 2 + shape.depth() ** 2 + shape.height() ** 2)
    if isinstance(shape, Ellipsoid):
        return max(shape.a(), shape.b(), shape.c())
    raise ValueError(f"collision geometry {name!r} is a {type(shape).__name__}, whose extent "
                     "the certificate does not bound")


@functools.lru_cache(maxsize=8)
def self_contact_certificate(arm: ArmDescription) -> SelfContactCertificate:
    """The certificate of ``arm``'s flexible plant, built once per arm and process."""
    return SelfContactCertificate(arm)
