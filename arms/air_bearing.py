"""The air-bearing configuration of the 6-DOF arm: planar commands lifted into its x-z plane.

With shoulder_yaw, wrist_yaw and wrist_roll locked at zero, the three pitch joints of
:data:`~telesmooth.arms.description.SPACE_ARM_6DOF` move the arm in the vertical x-z plane
through the shoulder, with the planar arm's link lengths (0.5, 0.4, 0.2 m). A planar pose
(x, y, φ) (metres in the plane, φ the tool angle) maps to the 6-DOF tool pose

    p = p_shoulder + (x, 0, y),   roll-pitch-yaw = (0, −φ, 0)

(the pitch axes point along −y, so a positive planar angle is a negative pitch), and planar
joints (q1, q2, q3) map to (0, q1, q2, q3, 0, 0). Pure numpy.
"""

from __future__ import annotations

import numpy as np

from telesmooth.arms.description import SPACE_ARM_6DOF

__all__ = [
    "SHOULDER_IN_BASE_M",
    "planar_joints_to_space_arm",
    "planar_pose_to_space_arm",
    "space_arm_pose_to_planar",
]

SHOULDER_IN_BASE_M = SPACE_ARM_6DOF.link_origins_m()[1]
"""The shoulder-pitch axis point of the 6-DOF arm in its base frame, m."""


def planar_pose_to_space_arm(pose) -> np.ndarray:
    """(…, 3) planar poses (x_m, y_m, phi_rad) → (…, 6) 6-DOF tool poses (x, y, z, r, p, y)."""
    pose = np.asarray(pose, dtype=float)
    if pose.shape[-1] != 3:
        raise ValueError(f"planar pose has shape {pose.shape}; expected (..., 3) = (x, y, phi)")
    lifted = np.zeros(pose.shape[:-1] + (6,))
    lifted[..., 0] = SHOULDER_IN_BASE_M[0] + pose[..., 0]
    lifted[..., 1] = SHOULDER_IN_BASE_M[1]
    lifted[..., 2] = SHOULDER_IN_BASE_M[2] + pose[..., 1]
    lifted[..., 4] = -pose[..., 2]
    return lifted


def planar_joints_to_space_arm(q) -> np.ndarray:
    """(…, 3) planar joint angles → (…, 6) 6-DOF joint angles with yaw and roll locked at 0."""
    q = np.asarray(q, dtype=float)
    if q.shape[-1] != 3:
        raise ValueError(f"planar joints have shape {q.shape}; expected (..., 3)")
    lifted = np.zeros(q.shape[:-1] + (6,))
    lifted[..., 1:4] = q
    return lifted


def space_arm_pose_to_planar(pose) -> np.ndarray:
    """Inverse of :func:`planar_pose_to_space_arm` for poses in the plane: (…, 6) → (…, 3).

    The y, roll and yaw components are ignored (they are 0 in the air-bearing plane).
    """
    pose = np.asarray(pose, dtype=float)
    if pose.shape[-1] != 6:
        raise ValueError(f"6-DOF pose has shape {pose.shape}; expected (..., 6)")
    return np.stack([pose[..., 0] - SHOULDER_IN_BASE_M[0], pose[..., 2] - SHOULDER_IN_BASE_M[2],
                     -pose[..., 4]], axis=-1)
