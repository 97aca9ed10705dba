"""LCM channel names and default URL, defined once for both processes."""

TELEOP_HAPTIC_COMMAND = "TELEOP_HAPTIC_COMMAND"
"""Haptic device samples (lcmt_teleop_haptic_command), 100 Hz, device → ground."""

TELEOP_JOINT_COMMAND = "TELEOP_JOINT_COMMAND"
"""Smoothed joint commands (lcmt_teleop_joint_command), 4 Hz, ground → onboard."""

ONBOARD_JOINT_STATUS = "ONBOARD_JOINT_STATUS"
"""Robot telemetry (lcmt_onboard_joint_status), 100 Hz, onboard → ground."""

TELEOP_COLLISION_EVENT = "TELEOP_COLLISION_EVENT"
"""Pre-simulator collision and hold state (lcmt_teleop_collision_event), 4 Hz, ground → all."""

ALL_CHANNELS = (TELEOP_HAPTIC_COMMAND, TELEOP_JOINT_COMMAND, ONBOARD_JOINT_STATUS,
                TELEOP_COLLISION_EVENT)

DEFAULT_LCM_URL = "udpm://239.255.76.67:7667?ttl=0"
"""Multicast on this host only (ttl=0): never let teleoperation traffic leave the machine
unless you deliberately configure a routed URL for a two-machine set-up."""
