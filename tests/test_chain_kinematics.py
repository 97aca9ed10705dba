"""ChainPoint: forward kinematics of a point for many joint vectors, against Drake's own."""

from __future__ import annotations

import numpy as np
import pytest
from pydrake.math import RigidTransform
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import PrismaticJoint, RevoluteJoint, SpatialInertia

from telesmooth.arms.chain_kinematics import ChainPoint
from telesmooth.arms.description import AIR_BEARING_ARM_3DOF, SPACE_ARM_6DOF
from telesmooth.arms.drake_models import add_arm


@pytest.mark.parametrize("flexible", [True, False], ids=["flexible", "rigid"])
@pytest.mark.parametrize("arm", [AIR_BEARING_ARM_3DOF, SPACE_ARM_6DOF], ids=lambda a: a.name)
def test_the_tool_point_is_drakes(arm, flexible):
    plant = MultibodyPlant(0.0)
    instance = add_arm(plant, arm, flexible=flexible)
    plant.Finalize()
    context = plant.CreateDefaultContext()
    frame = plant.GetFrameByName(arm.tool_frame, instance)
    point = np.array([0.03, -0.02, 0.05])
    q = np.random.default_rng(1).uniform(-3.0, 3.0, (200, plant.num_positions()))
    ours = ChainPoint(plant, frame, point).positions(q)
    for row, p in zip(q, ours):
        plant.SetPositions(context, row)
        want = plant.CalcPointsPositions(context, frame, point.reshape(3, 1),
                                         plant.world_frame())[:, 0]
        np.testing.assert_allclose(p, want, rtol=0, atol=1e-14)


def _two_bodies(second_joint):
    plant = MultibodyPlant(0.0)
    inertia = SpatialInertia.SolidSphereWithMass(1.0, 0.1)
    a = plant.AddRigidBody("a", inertia)
    b = plant.AddRigidBody("b", inertia)
    plant.AddJoint(RevoluteJoint("hinge", plant.world_frame(), a.body_frame(), [0.3, 0.4, 0.0]
                                 / np.linalg.norm([0.3, 0.4, 0.0])))
    plant.AddJoint(second_joint(a, b))
    plant.Finalize()
    return plant, b


def test_a_tilted_axis_and_an_offset_joint_frame_are_drakes():
    plant, b = _two_bodies(lambda a, b: RevoluteJoint(
        "elbow", plant_frame(a, RigidTransform([0.5, 0.1, -0.2])), b.body_frame(),
        [0.0, 0.6, 0.8]))
    context = plant.CreateDefaultContext()
    q = np.random.default_rng(2).uniform(-3.0, 3.0, (50, 2))
    ours = ChainPoint(plant, b.body_frame(), [0.2, 0.0, 0.1]).positions(q)
    for row, p in zip(q, ours):
        plant.SetPositions(context, row)
        want = plant.CalcPointsPositions(context, b.body_frame(), np.array([[0.2], [0.0], [0.1]]),
                                         plant.world_frame())[:, 0]
        np.testing.assert_allclose(p, want, rtol=0, atol=1e-14)


def plant_frame(body, pose):
    """A frame fixed in ``body`` at ``pose`` (added to the body's plant)."""
    from pydrake.multibody.tree import FixedOffsetFrame

    return body.GetParentPlant().AddFrame(FixedOffsetFrame(f"{body.name()}_f", body.body_frame(),
                                                           pose))


def test_a_prismatic_joint_is_refused_with_its_name():
    plant, b = _two_bodies(lambda a, b: PrismaticJoint("slide", a.body_frame(), b.body_frame(),
                                                       [1.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match="joint 'slide' is a PrismaticJoint"):
        ChainPoint(plant, b.body_frame())
