"""The operator's display: the paper's pre-simulator view and the predicted robot, in Meshcat.

In one Meshcat scene, redrawn every ``period_s`` (25 Hz by default):

* **solid**: the arm at the current planning position, the inverse kinematics of the hand
  now (the paper's "solid-frame model ... represents current planning position"); blue,
  red while the pre-simulator reports a collision, amber while the inverse kinematics
  holds the target (unreachable, a joint limit);
* **wire-frame**: the arm at the position received from the robot, its newest telemetry
  (the paper's "wire-frame model ... position received from space robot"), old by the
  downlink's delay;
* **predicted** (translucent green): the ground's copy of the robot run ahead of the
  telemetry to now (:class:`~telesmooth.systems.robot_predictor.RobotPredictor`);
* the hand (a small sphere at the pose the operator commands), the workspace's obstacles,
  the robot's tool trail (from its telemetry), and a status panel in the page's control
  panel (:func:`telesmooth.console.status.status_lines`): clutch and stop, link and
  telemetry age ("NO TELEMETRY FOR x s"), the robot's guard, the FIFO and the
  pre-simulator, σ, the sent commands against the limits, the prediction's residual, the
  real-time rate.

:class:`ArmDrawing` draws one robot from joint angles (the rigid arm's link frames, each
link's capsule). :class:`OperatorDisplay` is a Drake system whose periodic publish draws;
it must run in the Meshcat object's thread.
"""

from __future__ import annotations

import math

import numpy as np
from pydrake.geometry import Capsule, Rgba, Sphere
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import MultibodyPlant
from pydrake.systems.framework import LeafSystem

from telesmooth.arms.description import ArmDescription
from telesmooth.arms.drake_models import add_arm
from telesmooth.console.status import StatusInputs, fd_ratios, status_lines

__all__ = ["PREDICTOR_PORTS", "ArmDrawing", "DisplayClock", "OperatorDisplay", "capsule_mesh",
           "link_visual_pose", "predictor_ports"]

PLANNING_RGBA = Rgba(0.25, 0.45, 0.9, 1.0)
COLLISION_RGBA = Rgba(0.9, 0.15, 0.1, 1.0)
IK_HELD_RGBA = Rgba(0.95, 0.65, 0.1, 1.0)
RECEIVED_RGBA = Rgba(0.05, 0.05, 0.05, 1.0)
PREDICTED_RGBA = Rgba(0.1, 0.75, 0.3, 0.35)
HAND_RGBA = Rgba(0.95, 0.3, 0.7, 1.0)
HAND_OVER_TOOL = 1.25
"""The hand's ball, in radii of the tool link (a smaller one hides inside the solid arm)."""
LEGEND = ("solid: planning; wire: from robot",
          "green: predicted; pink: hand; red: hit")
"""What each drawing is, as rows of the control panel above the status (a page read without
docs/operator.md must say which arm is which; each fits the 240-pixel panel)."""
TRAIL_RGBA = Rgba(0.2, 0.2, 0.2, 1.0)


def link_visual_pose(link) -> RigidTransform:
    """The pose of a link's capsule in the link frame: centred on the segment, its axis (the
    capsule's z) along ``segment_m`` (as the arm's SDFormat places the visual)."""
    segment = np.asarray(link.segment_m, dtype=float)
    u = segment / np.linalg.norm(segment)
    pitch = math.atan2(math.hypot(u[0], u[1]), u[2])
    yaw = math.atan2(u[1], u[0]) if math.hypot(u[0], u[1]) > 1e-12 else 0.0
    return RigidTransform(RollPitchYaw(0.0, pitch, yaw), 0.5 * segment)


def capsule_mesh(radius: float, length: float, *, around: int = 12, cap_rings: int = 3):
    """A capsule's triangle mesh along z, centred at the origin: (vertices (3, N),
    faces (3, M) int32), for a wire-frame drawing."""
    rings = []   # (z, ring radius), bottom to top
    for k in range(cap_rings, 0, -1):
        angle = 0.5 * math.pi * k / cap_rings
        rings.append((-0.5 * length - radius * math.sin(angle), radius * math.cos(angle)))
    rings += [(-0.5 * length, radius), (0.5 * length, radius)]
    for k in range(1, cap_rings + 1):
        angle = 0.5 * math.pi * k / cap_rings
        rings.append((0.5 * length + radius * math.sin(angle), radius * math.cos(angle)))
    vertices = []
    for z, r in rings:
        for i in range(around):
            a = 2.0 * math.pi * i / around
            vertices.append((r * math.cos(a), r * math.sin(a), z))
    faces = []
    for ring in range(len(rings) - 1):
        for i in range(around):
            a, b = ring * around + i, ring * around + (i + 1) % around
            c, d = a + around, b + around
            faces += [(a, b, d), (a, d, c)]
    return (np.asfortranarray(np.array(vertices, dtype=float).T),
            np.asfortranarray(np.array(faces, dtype=np.int32).T))


class ArmDrawing:
    """One robot in Meshcat, drawn from joint angles.

    Args:
        meshcat: The Meshcat.
        arm: The arm (its rigid model gives the link frames).
        path: Meshcat path of this robot; each link is ``path/<link name>``.
        rgba: Colour.
        wireframe: Draw the links' edges only.
    """

    def __init__(self, meshcat, arm: ArmDescription, path: str, *, rgba: Rgba,
                 wireframe: bool = False):
        self._meshcat = meshcat
        self._path = path
        self._wireframe = wireframe
        plant = MultibodyPlant(0.0)
        add_arm(plant, arm, flexible=False)
        plant.Finalize()
        self._plant = plant
        self._context = plant.CreateDefaultContext()
        self._drawn = None
        self._links = [arm.base] + list(arm.links)
        self._bodies = [plant.GetBodyByName(link.name) for link in self._links]
        meshcat.Delete(path)
        for link in self._links:
            self._set_link(link, rgba)

    def _set_link(self, link, rgba) -> None:
        visual = f"{self._path}/{link.name}/visual"
        if self._wireframe:
            vertices, faces = capsule_mesh(link.radius_m, link.length_m)
            self._meshcat.SetTriangleMesh(visual, vertices, faces, rgba, wireframe=True)
        else:
            self._meshcat.SetObject(visual, Capsule(link.radius_m, link.length_m), rgba)
        self._meshcat.SetTransform(visual, link_visual_pose(link))

    def set_color(self, rgba: Rgba) -> None:
        for link in self._links:
            self._set_link(link, rgba)

    def set_visible(self, visible: bool) -> None:
        self._meshcat.SetProperty(self._path, "visible", bool(visible))

    def draw(self, q) -> None:
        """Puts the links at joint angles ``q`` (rad; nothing is drawn for a non-finite q, nor
        for the angles already drawn: a robot at rest costs the page nothing)."""
        q = np.asarray(q, dtype=float)
        if not np.all(np.isfinite(q)) or (self._drawn is not None
                                          and np.array_equal(q, self._drawn)):
            return
        self._drawn = q.copy()
        self._plant.SetPositions(self._context, q)
        for link, body in zip(self._links, self._bodies):
            self._meshcat.SetTransform(f"{self._path}/{link.name}",
                                       self._plant.EvalBodyPoseInWorld(self._context, body))


class DisplayClock:
    """How the run keeps up with the wall clock, for the status panel (set by the runner)."""

    def __init__(self):
        self.realtime_rate = math.nan
        self.late_ticks = 0



PREDICTOR_PORTS = ("q_received", "tool_received", "q_predicted", "telemetry_age",
                   "telemetry_silence", "residual", "robot_guard_mode", "robot_stream_distance")
"""The display's inputs that the robot predictor gives, under the predictor's port names."""


def predictor_ports(predictor) -> dict:
    """{display input name: the predictor's output port} for :data:`PREDICTOR_PORTS`."""
    return {name: predictor.get_output(name) for name in PREDICTOR_PORTS}


class OperatorDisplay(LeafSystem):
    r"""Draws the operator's seat in Meshcat (module docstring).

    .. pydrake_system::

        name: OperatorDisplay
        input_ports:
        - q_planning
        - hand_pose
        - enable
        - stop
        - notice (optional)
        - saturated (optional)
        - collision
        - min_distance
        - ik_status
        - holding
        - sigma
        - q_sent
        - sent_sequence (optional)
        - q_received
        - tool_received
        - q_predicted
        - telemetry_age
        - telemetry_silence
        - residual
        - robot_guard_mode
        - robot_stream_distance

    Connect them with :meth:`Connect`. Publish: periodic, every ``period_s`` from half a
    period (after the predictor's update of the same period), and forced.
    """

    def __init__(self, meshcat, arm: ArmDescription, *, pose_names, period_s: float,
                 uplink_period_s: float, max_acceleration, max_jerk,
                 residual_warning_m: float, distance_horizon_m: float = math.inf,
                 status_period_s: float = 0.5,
                 trail_points: int = 400, trail_period_s: float = 0.5,
                 clock: DisplayClock | None = None,
                 ik_names=None):
        super().__init__()
        self._meshcat = meshcat
        self._arm = arm
        n = arm.num_joints
        m = len(pose_names)
        self._planar = len(pose_names) == 3
        self._uplink_period = float(uplink_period_s)
        self._max_acceleration = np.asarray(max_acceleration, dtype=float)
        self._max_jerk = np.asarray(max_jerk, dtype=float)
        self._residual_warning = float(residual_warning_m)
        self._distance_horizon = float(distance_horizon_m)
        self._status_period = float(status_period_s)
        self._trail_points = int(trail_points)
        self._trail_period = float(trail_period_s)
        self._trail_time = -math.inf
        self._hand_drawn = None
        self.clock = clock or DisplayClock()
        self._ik_names = ik_names or {}
        sizes = {"q_planning": n, "hand_pose": m, "enable": 1, "stop": 1, "notice": 1,
                 "saturated": 1, "collision": 1, "min_distance": 1, "ik_status": 1,
                 "holding": 1, "sigma": n, "q_sent": n, "sent_sequence": 1, "q_received": n,
                 "tool_received": 3,
                 "q_predicted": n, "telemetry_age": 1, "telemetry_silence": 1, "residual": 1,
                 "robot_guard_mode": 1, "robot_stream_distance": 1}
        self._inputs = {name: self.DeclareVectorInputPort(name, size)
                        for name, size in sizes.items()}
        self.DeclarePeriodicPublishEvent(period_s, 0.5 * period_s, self._publish)
        self.DeclareForcedPublishEvent(self._publish)
        # What the drawing remembers between frames (the page's state, not the chain's).
        self._sent: list[np.ndarray] = []     # the last packets' q, consecutive
        self._sent_sequence = math.nan
        self._trail: list[np.ndarray] = []
        self._rows: list[str] = []
        self._rows_time = -math.inf
        self._planning_rgba = None
        self.frames = 0
        self._scene()

    def _scene(self) -> None:
        meshcat = self._meshcat
        self._planning = ArmDrawing(meshcat, self._arm, "/operator/planning",
                                    rgba=PLANNING_RGBA)
        self._received = ArmDrawing(meshcat, self._arm, "/operator/received",
                                    rgba=RECEIVED_RGBA, wireframe=True)
        self._predicted = ArmDrawing(meshcat, self._arm, "/operator/predicted",
                                     rgba=PREDICTED_RGBA)
        self._planning_rgba = PLANNING_RGBA
        # Wider than the tool link, so the hand shows where the solid arm reaches it.
        meshcat.SetObject("/operator/hand", Sphere(HAND_OVER_TOOL * self._arm.links[-1].radius_m),
                          HAND_RGBA)
        for row in LEGEND:
            meshcat.AddButton(row)
        if self._planar:
            # Above the arm, the workspace filling most of the page left of the controls.
            meshcat.SetCameraPose(np.array([0.62, -0.05, 1.7]), np.array([0.62, 0.0, 0.0]))
        else:
            meshcat.SetCameraPose(np.array([1.8, -1.6, 1.4]), np.array([0.4, 0.0, 0.4]))

    # -- wiring ---------------------------------------------------------------------------

    def get_input(self, name: str):
        return self._inputs[name]

    def ConnectPorts(self, builder, ports: dict) -> None:
        """Connects the inputs named in ``ports`` (input name → output port); the others stay
        unconnected (shown as unknown)."""
        for name, port in ports.items():
            builder.Connect(port, self._inputs[name])

    def Connect(self, builder, *, ground, predictor, console=None) -> None:
        """Connects every input from the ground station's systems, the predictor and (if
        given) the console."""
        haptic, ik, fifo = ground.haptic, ground.inverse_kinematics, ground.fifo
        checker, smoother, uplink = ground.collision_checker, ground.smoother, ground.uplink
        pairs = [
            (ik.get_q_target_output_port(), "q_planning"),
            (haptic.get_pose_desired_output_port(), "hand_pose"),
            (haptic.get_enable_output_port(), "enable"),
            (haptic.get_stop_requested_output_port(), "stop"),
            (checker.GetOutputPort("collision_detected"), "collision"),
            (checker.GetOutputPort("min_distance"), "min_distance"),
            (ik.get_ik_status_output_port(), "ik_status"),
            (fifo.get_holding_output_port(), "holding"),
            (smoother.get_sigma_output_port(), "sigma"),
            (uplink.get_q_sent_output_port(), "q_sent"),
            (uplink.get_sequence_number_output_port(), "sent_sequence"),
        ]
        pairs += [(port, name) for name, port in predictor_ports(predictor).items()]
        if console is not None:
            pairs += [(console.get_notice_output_port(), "notice"),
                      (console.get_saturated_output_port(), "saturated")]
        self.ConnectPorts(builder, {name: port for port, name in pairs})

    # -- drawing --------------------------------------------------------------------------

    def _value(self, context, name, default=math.nan):
        port = self._inputs[name]
        if not port.HasValue(context):
            return np.full(port.size(), default)
        return np.asarray(port.Eval(context), dtype=float)

    def _hand_point(self, pose) -> np.ndarray:
        return np.array([pose[0], pose[1], 0.0]) if self._planar else np.asarray(pose[:3])

    def _publish(self, context) -> None:
        meshcat = self._meshcat
        now = context.get_time()
        value = self._value
        collision = value(context, "collision")[0] > 0.5
        ik_status = int(value(context, "ik_status", 0.0)[0])
        rgba = (COLLISION_RGBA if collision else
                IK_HELD_RGBA if ik_status not in (0, 1) else PLANNING_RGBA)
        if rgba is not self._planning_rgba:
            self._planning.set_color(rgba)
            self._planning_rgba = rgba
        self._planning.draw(value(context, "q_planning"))
        self._received.draw(value(context, "q_received"))
        self._predicted.draw(value(context, "q_predicted"))
        hand = self._hand_point(value(context, "hand_pose"))
        if self._hand_drawn is None or not np.array_equal(hand, self._hand_drawn):
            meshcat.SetTransform("/operator/hand", RigidTransform(hand))
            self._hand_drawn = hand
        tool = value(context, "tool_received")
        if np.all(np.isfinite(tool)) and (not self._trail
                                          or np.any(tool != self._trail[-1])):
            self._trail.append(tool)
            del self._trail[:-self._trail_points]
            # The trail is a new line each time it is drawn: twice a second is plenty.
            if len(self._trail) >= 2 and now - self._trail_time >= self._trail_period - 1e-9:
                meshcat.SetLine("/operator/trail", np.array(self._trail).T, 2.0, TRAIL_RGBA)
                self._trail_time = now
        self._record_sent(value(context, "q_sent"), value(context, "sent_sequence")[0])
        if now - self._rows_time >= self._status_period - 1e-9:
            self._status(context)
            self._rows_time = now
        if math.isfinite(self.clock.realtime_rate):
            meshcat.SetRealtimeRate(self.clock.realtime_rate)
        self.frames += 1

    def _record_sent(self, q_sent, sequence) -> None:
        """Keeps the last packets for the finite differences: one entry per packet (a hold
        repeats its q), consecutive (a missed sequence number starts afresh, since the
        differences need equally spaced packets). Without ``sent_sequence`` (NaN) a packet
        is a change of ``q_sent``."""
        if not np.all(np.isfinite(q_sent)):
            return
        if math.isnan(sequence):
            new = not self._sent or bool(np.any(q_sent != self._sent[-1]))
        else:
            new = sequence != self._sent_sequence
            if new and sequence != self._sent_sequence + 1:
                self._sent.clear()
            self._sent_sequence = sequence
        if new:
            self._sent.append(np.array(q_sent))
            del self._sent[:-8]

    def status(self, context) -> StatusInputs:
        """The status panel's inputs now."""
        value = self._value
        acc, jerk = fd_ratios(np.array(self._sent), self._uplink_period,
                              self._max_acceleration, self._max_jerk)
        ik_status = int(value(context, "ik_status", 0.0)[0])
        return StatusInputs(
            enabled=value(context, "enable")[0] > 0.5, stop=value(context, "stop")[0] > 0.5,
            notice=int(value(context, "notice", 0.0)[0]),
            saturated=value(context, "saturated", 0.0)[0] > 0.5,
            telemetry_age_s=float(value(context, "telemetry_age")[0]),
            telemetry_silence_s=float(value(context, "telemetry_silence")[0]),
            robot_guard_mode=int(value(context, "robot_guard_mode", -1.0)[0]),
            stream_distance_rad=float(value(context, "robot_stream_distance")[0]),
            holding=value(context, "holding")[0] > 0.5,
            collision=value(context, "collision")[0] > 0.5,
            min_distance_m=float(value(context, "min_distance")[0]),
            ik_failure=("" if ik_status in (0, 1) else self._ik_names.get(ik_status, "?")),
            sigma=value(context, "sigma"), acceleration_ratio=acc, jerk_ratio=jerk,
            residual_m=float(value(context, "residual")[0]),
            residual_warning_m=self._residual_warning,
            distance_horizon_m=self._distance_horizon,
            realtime_rate=self.clock.realtime_rate, late_ticks=self.clock.late_ticks)

    def _status(self, context) -> None:
        rows = status_lines(self.status(context))
        if rows == self._rows:
            return
        for row in self._rows:
            self._meshcat.DeleteButton(row)
        for row in rows:
            self._meshcat.AddButton(row)
        self._rows = rows

    @property
    def rows(self) -> list[str]:
        """The status panel's rows as last drawn."""
        return list(self._rows)
