"""The operator's console in the browser: Meshcat's controls → the hand, the clutch, the stop.

:class:`MeshcatControls` adds the console's controls to a Meshcat page (one slider per pose
coordinate with its keys, an Enable button on Space, a Stop button on Escape) and reads them
(with the page's gamepad and how many browsers are connected). :class:`OperatorConsole` is
the thin Drake system around the pure step :func:`telesmooth.console.input.console_step`:
every haptic period it reads the controls, steps the console's state (kept in the Context
as one vector, :class:`~telesmooth.systems.codec_state.CodecState`) and outputs the hand
pose, the clutch and the stop like a haptic device (``HapticCommandReceiver``'s ports).

Meshcat is not thread-safe: the Simulator that runs this system must run in the thread that
created the Meshcat object (``telesmooth teleop`` does).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
from pydrake.systems.framework import LeafSystem

from telesmooth.console.input import (
    ConsoleInputs,
    ConsoleNotice,
    ConsoleParams,
    Gamepad,
    console_initial_state,
    console_step,
)
from telesmooth.systems.codec_state import CodecState

__all__ = ["ENABLE_BUTTON", "KEYS", "MeshcatControls", "OperatorConsole", "SLIDERS",
           "STOP_BUTTON"]

ENABLE_BUTTON = "Enable (Space)"
"""The clutch button's name on the page (its key: Space)."""
STOP_BUTTON = "Stop (Esc)"
"""The stop button's name on the page (its key: Escape)."""

SLIDERS = {"x_m": "x [m]", "y_m": "y [m]", "z_m": "z [m]", "phi_rad": "phi [rad]",
           "roll_rad": "roll [rad]", "pitch_rad": "pitch [rad]", "yaw_rad": "yaw [rad]"}
"""The slider of each pose coordinate, by its name on the page."""

KEYS = {"x_m": ("KeyA", "KeyD"), "y_m": ("KeyS", "KeyW"), "z_m": ("KeyK", "KeyI"),
        "phi_rad": ("KeyJ", "KeyL"), "yaw_rad": ("KeyJ", "KeyL"),
        "roll_rad": ("KeyU", "KeyO"), "pitch_rad": ("KeyQ", "KeyE")}
"""(decrement, increment) keys of each coordinate (browser ``KeyboardEvent.code`` values):
A/D −x/+x, S/W −y/+y, K/I −z/+z, J/L the tool angle φ (planar) or yaw, U/O roll, Q/E pitch."""


class MeshcatControls:
    """The console's controls on a Meshcat page, read and set from the Meshcat thread.

    Args:
        meshcat: The page's Meshcat.
        pose_names: The pose coordinates (e.g. ``PLANAR_POSE_NAMES``).
        initial_pose: Where the sliders start, (m,).
        position_range_m: (low, high) of each position slider, m, per coordinate.
        position_step_m, angle_step_rad: One key press.
    """

    def __init__(self, meshcat, pose_names, *, initial_pose, position_range_m,
                 position_step_m: float = 0.005, angle_step_rad: float = 0.02):
        self._meshcat = meshcat
        self._names = tuple(pose_names)
        self.slider_steps = tuple(angle_step_rad if name.endswith("_rad") else position_step_m
                                  for name in self._names)
        """The sliders' steps (the page keeps each slider on a whole number of them)."""
        pose = np.asarray(initial_pose, dtype=float)
        meshcat.AddButton(ENABLE_BUTTON, "Space")
        meshcat.AddButton(STOP_BUTTON, "Escape")
        for index, name in enumerate(self._names):
            angular = name.endswith("_rad")
            low, high = (-math.pi, math.pi) if angular else position_range_m[name]
            down, up = KEYS[name]
            meshcat.AddSlider(SLIDERS[name], float(low), float(high),
                              angle_step_rad if angular else position_step_m,
                              float(pose[index]), decrement_keycode=down,
                              increment_keycode=up)

    def read(self, anchor_pose=None) -> ConsoleInputs:
        """The controls now, as the console step's inputs."""
        meshcat = self._meshcat
        gamepad = meshcat.GetGamepad()
        # The page sends an empty gamepad when the browser loses it; Meshcat then keeps the
        # old index with no axes: that is no gamepad.
        present = gamepad.index is not None and len(gamepad.axes) > 0
        return ConsoleInputs(
            sliders=np.array([meshcat.GetSliderValue(SLIDERS[name]) for name in self._names]),
            enable_clicks=meshcat.GetButtonClicks(ENABLE_BUTTON),
            stop_clicks=meshcat.GetButtonClicks(STOP_BUTTON),
            gamepad=Gamepad(index=gamepad.index if present else None,
                            axes=tuple(gamepad.axes), buttons=tuple(gamepad.button_values)),
            connections=meshcat.GetNumActiveConnections(),
            anchor_pose=anchor_pose)

    def set_sliders(self, pose) -> None:
        for name, value in zip(self._names, pose):
            self._meshcat.SetSliderValue(SLIDERS[name], float(value))


class OperatorConsole(LeafSystem):
    r"""The browser console as the operator's hand.

    .. pydrake_system::

        name: OperatorConsole
        input_ports:
        - q_anchor (optional)
        - anchor (optional)
        output_ports:
        - pose_desired
        - enable
        - stop_requested
        - notice
        - saturated

    - ``q_anchor`` (J, rad), ``anchor`` (1,): the robot's commanded pose (the uplink's held
      command) and whether the ground holds the robot there (the FIFO's ``holding``); when
      the operator engages after a stop, the hand is re-anchored at the forward kinematics
      of ``q_anchor`` (unconnected: it continues from where it was).
    - ``pose_desired`` (m,): the hand pose; ``enable`` (1,): the clutch; ``stop_requested``
      (1,): the operator's stop (:mod:`telesmooth.console.input`).
    - ``notice`` (1,): the :class:`~telesmooth.console.input.ConsoleNotice` (why the clutch
      is released, if the console released it); ``saturated`` (1,): the arm's reach limits
      the hand (the wanted pose was outside it, or the way to it leaves it and the hand
      slides along the edge or holds there).

    Update: periodic discrete every ``params.period_s`` from 0: read the controls
    (``controls.read``), :func:`~telesmooth.console.input.console_step`, move the sliders if
    the step asks. Outputs read the state (no feedthrough).
    """

    def __init__(self, params: ConsoleParams, controls, *, initial_pose,
                 forward_kinematics: Callable[[np.ndarray], np.ndarray] | None = None,
                 num_joints: int | None = None):
        super().__init__()
        self._params = params
        self._controls = controls
        self._fk = forward_kinematics
        initial = console_initial_state(params, initial_pose)
        self._state = CodecState(self, initial)
        if num_joints is not None:
            self._q_anchor_input = self.DeclareVectorInputPort("q_anchor", int(num_joints))
            self._anchor_input = self.DeclareVectorInputPort("anchor", 1)
        else:
            self._q_anchor_input = self._anchor_input = None
        # A discrete update, like the live device's receiver: the inverse kinematics' update
        # at the same instant reads the console's state of the tick before (Drake's x⁻), and
        # so does a logger: the hand logged at t is the hand the IK read at t.
        self.DeclarePeriodicDiscreteUpdateEvent(params.period_s, 0.0, self._update)

        output = self._state.output
        self._pose_output = output("pose_desired", "pose")
        self._enable_output = output("enable", "enabled")
        self._stop_output = output("stop_requested", "stop")
        self._notice_output = output("notice", "notice")
        self._saturated_output = output("saturated", "saturated")

    @property
    def params(self) -> ConsoleParams:
        return self._params

    def console_state(self, context):
        """The :class:`~telesmooth.console.input.ConsoleState` in ``context``."""
        return self._state.get(context)

    def get_q_anchor_input_port(self):
        return self._q_anchor_input

    def get_anchor_input_port(self):
        return self._anchor_input

    def get_pose_desired_output_port(self):
        return self._pose_output

    def get_enable_output_port(self):
        return self._enable_output

    def get_stop_requested_output_port(self):
        return self._stop_output

    def get_notice_output_port(self):
        return self._notice_output

    def get_saturated_output_port(self):
        return self._saturated_output

    def _anchor_pose(self, context):
        if self._anchor_input is None or self._fk is None:
            return None
        if not (self._anchor_input.HasValue(context)
                and self._anchor_input.Eval(context)[0] > 0.5):
            return None
        return np.asarray(self._fk(self._q_anchor_input.Eval(context)), dtype=float)

    def _update(self, context, discrete_state) -> None:
        current = self.console_state(context)
        inputs = self._controls.read(anchor_pose=self._anchor_pose(context))
        new, outputs = console_step(self._params, current, inputs)
        if outputs.set_sliders is not None:
            self._controls.set_sliders(outputs.set_sliders)
        self._state.store(discrete_state, new)

    @staticmethod
    def notice_text(value: float) -> str:
        return ConsoleNotice(int(round(value))).text
