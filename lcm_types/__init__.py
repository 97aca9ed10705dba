"""LCM message types of the ground/onboard split.

The ``*.lcm`` files here are the definitions; ``telesmooth_lcmt/`` is the Python code
generated from them by the ``lcm-gen`` shipped with the ``lcm`` package. Regenerate after
changing a definition with ``python -m telesmooth.lcm_types.generate`` (a test checks the
committed code matches). Import the types from here:

    from telesmooth.lcm_types import lcmt_teleop_joint_command
"""

from telesmooth.lcm_types.telesmooth_lcmt import (
    lcmt_onboard_joint_status,
    lcmt_teleop_collision_event,
    lcmt_teleop_haptic_command,
    lcmt_teleop_joint_command,
)

__all__ = [
    "lcmt_onboard_joint_status",
    "lcmt_teleop_collision_event",
    "lcmt_teleop_haptic_command",
    "lcmt_teleop_joint_command",
]
