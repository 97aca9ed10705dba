"""Forward kinematics of one point of a serial arm for many joint vectors at once.

The laser tracker samples the tool point of the plant every 10 ms; a playback takes its
samples afterwards, thousands at a time
(:meth:`~telesmooth.systems.laser_tracker.LaserTracker.Record`).
Through Drake's bindings each sample costs a ``SetPositions`` and a ``CalcPointsPositions``
(about 8 µs); :class:`ChainPoint` reads the same chain of fixed frame poses and joint
rotations out of the finalized plant once and composes them with numpy over all samples (the
arms' chains: welds and revolute joints from the world down to the point's body).

Against Drake's own kinematics it agrees to rounding (tested to 1e-14 m; the tracker's
periodic event, one sample at a time, keeps Drake's).
"""

from __future__ import annotations

import numpy as np
from pydrake.math import RigidTransform, RotationMatrix
from pydrake.multibody.tree import RevoluteJoint, WeldJoint

__all__ = ["ChainPoint", "joint_path"]


class ChainPoint:
    """p_W of a point fixed in a frame of a plant, as a function of the plant's positions.

    Args:
        plant: A finalized MultibodyPlant.
        frame: The frame the point is fixed in.
        point: The point in ``frame``, m, (3,); its origin by default.

    Raises:
        ValueError: If a joint between the world and the frame's body is neither revolute
            nor a weld (or the body has no joint to the world): naming it.
    """

    def __init__(self, plant, frame, point=(0.0, 0.0, 0.0)):
        chain = joint_path(plant, frame.body())
        for joint in chain:
            if not isinstance(joint, (RevoluteJoint, WeldJoint)):
                raise ValueError(f"joint {joint.name()!r} is a {type(joint).__name__}: only "
                                 "revolute joints and welds are supported")
        # X_WT = C_0 · Rz(q_1) · C_1 · Rz(q_2) ··· Rz(q_m) · C_m · p_T: each revolute joint
        # turned about z of a frame A whose z is its axis (X_FM(θ) = A·Rz(θ)·Aᵀ), and every
        # fixed pose between two revolute joints folded into one constant C_i.
        constant = RigidTransform()
        self._joints, self._constants = [], []
        for joint in chain:
            constant = constant.multiply(joint.frame_on_parent().GetFixedPoseInBodyFrame())
            if isinstance(joint, WeldJoint):
                constant = constant.multiply(joint.X_FM())
            else:
                axis_frame = RigidTransform(_frame_with_z(joint.revolute_axis()), np.zeros(3))
                self._constants.append(_arrays(constant.multiply(axis_frame)))
                self._joints.append(joint.position_start())
                constant = axis_frame.inverse()
            constant = constant.multiply(joint.frame_on_child().GetFixedPoseInBodyFrame()
                                         .inverse())
        tool = constant.multiply(frame.GetFixedPoseInBodyFrame())
        self._last = np.asarray(tool.multiply(np.asarray(point, dtype=float)),
                                dtype=float).reshape(3)

    def positions(self, q) -> np.ndarray:
        """p_W of the point for each row of plant positions ``q`` (T, nq), m, (T, 3)."""
        q = np.asarray(q, dtype=float)
        count = q.shape[0]
        rotation = np.broadcast_to(np.eye(3), (count, 3, 3))
        translation = np.zeros((count, 3))
        for (R_C, p_C), index in zip(self._constants, self._joints):
            translation = translation + rotation @ p_C
            rotation = rotation @ R_C
            # · Rz(θ): columns x, y turn, z stays.
            c, s = np.cos(q[:, index])[:, None], np.sin(q[:, index])[:, None]
            x, y = rotation[:, :, 0], rotation[:, :, 1]
            rotation = np.stack([c * x + s * y, c * y - s * x, rotation[:, :, 2]], axis=-1)
        return translation + rotation @ self._last


def joint_path(plant, body) -> list:
    """The joints from the world down to ``body`` of a finalized plant, the world's first.

    Raises:
        ValueError: If the path does not reach the world (naming the body where it stops).
    """
    by_child = {}
    for index in plant.GetJointIndices():
        joint = plant.get_joint(index)
        by_child[joint.child_body().index()] = joint
    path = []
    while body.index() != plant.world_body().index():
        joint = by_child.get(body.index())
        if joint is None:
            raise ValueError(f"body {body.name()!r} has no joint to the world")
        path.append(joint)
        body = joint.parent_body()
    return path[::-1]


def _frame_with_z(axis) -> RotationMatrix:
    """A rotation whose z column is the unit ``axis``."""
    z = np.asarray(axis, dtype=float)
    z = z / np.linalg.norm(z)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return RotationMatrix(np.column_stack([x, np.cross(z, x), z]))


def _arrays(pose):
    return (np.asarray(pose.rotation().matrix(), dtype=float),
            np.asarray(pose.translation(), dtype=float).reshape(3))
