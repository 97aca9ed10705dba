"""The Drake systems of the teleoperation chain: one LeafSystem (or small diagram) per stage.

Ground side, at the haptic rate and then the 4 Hz uplink: the operator (``haptic_source``, or
``haptic_command_receiver`` for a live device over LCM), the inverse kinematics
(``inverse_kinematics``), the pre-simulator (``collision_checker``; ``collision_stop`` for the
jerk-limited stop), the 0.75 s safety delay (``delay_fifo``, optionally behind ``period_mean``),
the online smoother (``reduced_q_smoother``), the zero-order-hold uplink (``uplink``) and its
LCM messages (``joint_command_sender``, ``collision_event_sender``), and the link status read
from the robot's telemetry (``link_monitor``). Onboard: the packet checks
(``joint_command_receiver``), the link guard around :func:`telesmooth.safety.guard.guard_step`
(``link_guard``), the flexible-joint plant with its command interpolator and laser tracker
(``flexible_arm``, ``command_interpolator``, ``laser_tracker``) and the telemetry
(``joint_status_sender``). Around them: the playback source of an offline plan
(``planned_path_source``), the in-process link with faults (``link_channel``), an LCM
subscriber that bad bytes cannot kill (``lcm_safe_subscriber``) and shared timing checks
(``timing``). The numerical and safety cores they wrap are pure Python in
:mod:`telesmooth.smoothing` and :mod:`telesmooth.safety`; docs/architecture.md gives every
system's ports.
"""
