"""The operator's input as a pure state machine: ``console_step(params, state, inputs)``.

The console is the operator's hand. In a browser it has one slider per pose coordinate
(moved by the mouse or by keys, one ``key_step`` per key press), an **Enable** button (the
clutch), a **Stop** button and, optionally, a gamepad. Every ``period_s`` (100 Hz, the
haptic rate) this step turns what the controls say into the pose, the clutch and the stop
sent to the ground station, with these rules (no motion without intent):

* **The clutch.** The console starts disengaged. Each click of Enable toggles it (a gamepad's
  button 0 too). While it is disengaged the published pose does not move, whatever the
  sliders do; engaging again puts the sliders back on the published pose if they moved
  meanwhile (the console asks for that with ``set_sliders``), so the hand continues from
  where it stopped: no jump.
* **The stop.** A click of Stop (or the gamepad's button 1) disengages the clutch and sets
  ``stop`` until the operator engages again; the ground brings the robot to rest within the
  limits while ``stop`` is set. Engaging after a stop re-anchors the hand at the robot's
  commanded pose when the caller knows it (``anchor_pose``): the robot resumes from where
  it stopped.
* **The hand moves, it does not jump.** The sliders (and the gamepad's sticks, which move
  the sliders at a rate) set where the operator wants the hand; the published pose moves
  towards it at most ``max_speed_m_per_s`` (and ``max_angular_speed_rad_per_s`` for the
  angles), as a real hand on a haptic device would. A slider dragged across the workspace
  is followed at that speed, never in one step that the inverse kinematics would refuse.
* **The arm's workspace.** A wanted pose outside the arm's reach is saturated at its
  boundary (``saturate``, :func:`reach_saturation`), and so is the way to it: the published
  pose slides along the boundary, and where the straight way crosses the unreachable part
  (the planar arm's wrist through the shoulder) it holds at the edge until the operator
  goes round. ``saturated`` says so in both cases and the display shows the warning; the
  ground never gets an unreachable pose from the console.
* **Losing the operator.** No browser connected (the page closed, the browser gone), or a
  gamepad that was driving disappears: the clutch is released at once and ``notice`` says
  why. The ground then holds its target (the robot finishes the FIFO's 0.75 s and rests).
  The console keeps publishing the disengaged clutch, so the ground knows within one haptic
  period; a console that stops publishing altogether is caught by the ground's own timeout.

Gamepad (the browser's standard mapping): left stick x/y → x/y, right stick x → the tool
angle φ (planar) or yaw (6-DOF), right stick y → z (6-DOF); full deflection moves the wanted
pose at ``max_speed_m_per_s`` (``max_angular_speed_rad_per_s``); a deflection below
``gamepad_deadzone`` is none.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

__all__ = [
    "ConsoleInputs",
    "ConsoleNotice",
    "ConsoleOutputs",
    "ConsoleParams",
    "ConsoleState",
    "GAMEPAD_ENABLE_BUTTON",
    "GAMEPAD_STOP_BUTTON",
    "Gamepad",
    "console_initial_state",
    "console_params",
    "console_step",
    "reach_saturation",
]

GAMEPAD_ENABLE_BUTTON = 0
"""The gamepad button that toggles the clutch (A / cross in the standard mapping)."""
GAMEPAD_STOP_BUTTON = 1
"""The gamepad button that stops (B / circle)."""


class ConsoleNotice(enum.IntEnum):
    """Why the clutch is released, when the console released it or the operator stopped."""

    NONE = 0
    STOPPED = 1
    NO_BROWSER = 2
    GAMEPAD_LOST = 3

    @property
    def text(self) -> str:
        return ("", "stopped by the operator", "no browser connected: clutch released",
                "gamepad lost: clutch released")[self]


@dataclasses.dataclass(frozen=True)
class ConsoleParams:
    """What the console's steps depend on besides its state (immutable).

    Attributes:
        pose_names: The pose coordinates, e.g. ``("x_m", "y_m", "phi_rad")``; names ending in
            ``_rad`` are angles, the others positions.
        period_s: Step period, s (the haptic rate).
        max_speed_m_per_s: Fastest the published position moves, m/s (> 0).
        max_angular_speed_rad_per_s: Fastest an angle moves, rad/s (> 0).
        gamepad_deadzone: Stick deflections below this are none, in [0, 1).
        saturate: (pose) → (pose within the arm's reach, whether it had to move); None
            accepts every pose.
        slider_steps: The page's slider step of each coordinate (the page keeps a slider on
            a whole number of steps), or None (no quantisation). A slider reading that moves
            less than half a step is not a change, and the gamepad moves the sliders only
            when the wanted pose reaches the next step.
    """

    pose_names: tuple[str, ...]
    period_s: float = 0.01
    max_speed_m_per_s: float = 0.05
    max_angular_speed_rad_per_s: float = 0.2
    gamepad_deadzone: float = 0.1
    saturate: Callable[[np.ndarray], tuple[np.ndarray, bool]] | None = None
    slider_steps: tuple[float, ...] | None = None

    def quantize(self, values) -> np.ndarray:
        """``values`` on the sliders' steps (unchanged without steps)."""
        values = np.array(values, dtype=float)
        if self.slider_steps is None:
            return values
        steps = np.asarray(self.slider_steps, dtype=float)
        return np.round(values / steps) * steps

    def sliders_moved(self, read, held) -> bool:
        """Whether the sliders ``read`` differ from those ``held`` by half a step or more."""
        steps = (np.full(len(self.pose_names), 2e-9) if self.slider_steps is None
                 else np.asarray(self.slider_steps, dtype=float))
        return bool(np.any(np.abs(np.asarray(read) - np.asarray(held)) >= 0.5 * steps))

    @property
    def angular(self) -> np.ndarray:
        """Which coordinates are angles, (m,) bool."""
        return np.array([name.endswith("_rad") for name in self.pose_names])


def console_params(pose_names, **settings) -> ConsoleParams:
    """Validated :class:`ConsoleParams` (each error names the field and the value)."""
    names = tuple(str(name) for name in pose_names)
    if not names:
        raise ValueError("pose_names must name at least one coordinate")
    params = ConsoleParams(pose_names=names, **settings)
    for field in ("period_s", "max_speed_m_per_s", "max_angular_speed_rad_per_s"):
        value = getattr(params, field)
        if isinstance(value, bool) or not (isinstance(value, (int, float))
                                           and math.isfinite(value) and value > 0.0):
            raise ValueError(f"{field} = {value!r} must be positive and finite")
    zone = params.gamepad_deadzone
    if isinstance(zone, bool) or not (isinstance(zone, (int, float)) and 0.0 <= zone < 1.0):
        raise ValueError(f"gamepad_deadzone = {zone!r} must be in [0, 1)")
    if params.saturate is not None and not callable(params.saturate):
        raise ValueError(f"saturate = {params.saturate!r} must be None or callable")
    if params.slider_steps is not None:
        steps = tuple(float(v) for v in params.slider_steps)
        if len(steps) != len(names) or not all(math.isfinite(v) and v > 0 for v in steps):
            raise ValueError(f"slider_steps = {params.slider_steps!r} must be "
                             f"{len(names)} positive numbers")
        params = dataclasses.replace(params, slider_steps=steps)
    return params


class Gamepad(NamedTuple):
    """The browser's first gamepad (Meshcat's ``GetGamepad()``): ``index`` None when there
    is none; ``axes`` in [−1, 1]; ``buttons`` in [0, 1]."""

    index: int | None = None
    axes: tuple[float, ...] = ()
    buttons: tuple[float, ...] = ()


class ConsoleInputs(NamedTuple):
    """What the console reads at one step.

    Attributes:
        sliders: The sliders' values, (m,), in the pose's units.
        enable_clicks, stop_clicks: How often Enable and Stop were clicked since the start
            (Meshcat counts; pressing the button's key counts as a click).
        gamepad: The first gamepad.
        connections: Browsers connected to the page.
        anchor_pose: The robot's commanded pose (the forward kinematics of the last command
            sent), (m,), or None when the caller does not know it.
    """

    sliders: np.ndarray
    enable_clicks: int = 0
    stop_clicks: int = 0
    gamepad: Gamepad = Gamepad()
    connections: int = 1
    anchor_pose: np.ndarray | None = None


class ConsoleState(NamedTuple):
    """The console between steps (immutable: :func:`console_step` returns a new one).

    Attributes:
        pose: The published hand pose, (m,).
        wanted: Where the operator wants the hand (the sliders, saturated), (m,).
        sliders: The slider values at the last step, (m,) (a change is the operator's).
        enabled: The clutch.
        stop: The operator's stop is in force.
        enable_clicks, stop_clicks: The click counts already handled.
        gamepad_pressed: The gamepad's Enable and Stop buttons were down at the last step,
            (2,) (a press is a rising edge).
        had_gamepad: A gamepad was connected (its loss releases the clutch).
        saturated: The reach limits the hand: the wanted pose was outside it and was moved
            onto its boundary (``wanted_outside``), or the last step was (the hand slides
            along the edge or holds at it).
        wanted_outside: The wanted pose was moved onto the reach's boundary when it was
            last set.
        notice: Why the clutch is released, if the console released it or the operator
            stopped (:class:`ConsoleNotice`).
    """

    pose: np.ndarray
    wanted: np.ndarray
    sliders: np.ndarray
    enabled: bool = False
    stop: bool = False
    enable_clicks: int = 0
    stop_clicks: int = 0
    gamepad_pressed: np.ndarray = np.zeros(2, dtype=bool)
    had_gamepad: bool = False
    saturated: bool = False
    notice: ConsoleNotice = ConsoleNotice.NONE
    wanted_outside: bool = False


class ConsoleOutputs(NamedTuple):
    """What one step publishes and asks of the page.

    Attributes:
        pose: The hand pose for the ground station, (m,).
        enable: The clutch.
        stop: The operator's stop.
        set_sliders: Put the sliders here (after engaging, or as the gamepad moves the wanted
            pose), (m,); None: leave them.
    """

    pose: np.ndarray
    enable: bool
    stop: bool
    set_sliders: np.ndarray | None = None


def console_initial_state(params: ConsoleParams, pose) -> ConsoleState:
    """Disengaged at ``pose`` (m,), the sliders on it."""
    pose = np.array(pose, dtype=float)
    if pose.shape != (len(params.pose_names),) or not np.all(np.isfinite(pose)):
        raise ValueError(f"pose = {pose.tolist()!r} must be {len(params.pose_names)} finite "
                         f"numbers ({', '.join(params.pose_names)})")
    return ConsoleState(pose=pose.copy(), wanted=pose.copy(), sliders=pose.copy(),
                        gamepad_pressed=np.zeros(2, dtype=bool))


def _buttons_down(gamepad: Gamepad) -> np.ndarray:
    """Whether the Enable and Stop buttons are down, (2,) bool."""
    buttons = gamepad.buttons if gamepad.index is not None else ()
    return np.array([len(buttons) > index and float(buttons[index]) > 0.5
                     for index in (GAMEPAD_ENABLE_BUTTON, GAMEPAD_STOP_BUTTON)])


def _gamepad_rate(params: ConsoleParams, gamepad: Gamepad) -> np.ndarray:
    """The wanted pose's rate from the sticks, (m,) per second."""
    m = len(params.pose_names)
    rate = np.zeros(m)
    axes = [0.0 if abs(a) < params.gamepad_deadzone or not math.isfinite(a) else float(a)
            for a in gamepad.axes]
    axes += [0.0] * (4 - len(axes))
    names = params.pose_names
    speed, turn = params.max_speed_m_per_s, params.max_angular_speed_rad_per_s
    for name, value in (("x_m", axes[0] * speed), ("y_m", -axes[1] * speed),
                        ("z_m", -axes[3] * speed), ("phi_rad", axes[2] * turn),
                        ("yaw_rad", axes[2] * turn)):
        if name in names:
            rate[names.index(name)] = value
    return rate


def _move_towards(params: ConsoleParams, pose, wanted) -> np.ndarray:
    """``pose`` moved towards ``wanted`` by at most one step of the speed limits (the
    positions together, each angle alone)."""
    step = np.asarray(wanted, dtype=float) - pose
    angular = params.angular
    out = np.array(pose, dtype=float)
    linear = ~angular
    if np.any(linear):
        distance = float(np.linalg.norm(step[linear]))
        limit = params.max_speed_m_per_s * params.period_s
        scale = 1.0 if distance <= limit else limit / distance
        out[linear] += scale * step[linear]
    limit = params.max_angular_speed_rad_per_s * params.period_s
    out[angular] += np.clip(step[angular], -limit, limit)
    # Within a rounding of the wanted pose: take it exactly (the last step lands on it).
    close = np.abs(out - wanted) <= 1e-12 * np.maximum(1.0, np.abs(wanted))
    out[close] = np.asarray(wanted, dtype=float)[close]
    return out


def _saturated(params: ConsoleParams, pose) -> tuple[np.ndarray, bool]:
    """``pose`` within the arm's reach (and whether it had to move)."""
    if params.saturate is None:
        return np.array(pose, dtype=float), False
    inside, moved = params.saturate(pose)
    return np.array(inside, dtype=float), bool(moved)


def _step_within_reach(params: ConsoleParams, pose, wanted) -> tuple[np.ndarray, bool]:
    """One speed-limited step towards ``wanted`` that stays within the reach, and whether the
    reach limited it (the hand is at the edge).

    A step that would leave the reach is put back on its boundary, and of the way from
    ``pose`` to that point the farthest part whose boundary point is still within one step
    is taken (bisection; the edge curves, so the boundary point can be a little more than a
    step away): the hand slides along the edge. Where the straight way runs into the
    unreachable part head-on (the planar wrist straight at the shoulder) the boundary point
    is ``pose`` itself and the hand holds; the operator goes round."""
    pose = np.asarray(pose, dtype=float)
    step = _move_towards(params, pose, wanted)
    inside, moved = _saturated(params, step)
    if not moved:
        return step, False
    angular = params.angular
    reach = params.max_speed_m_per_s * params.period_s
    turn = params.max_angular_speed_rad_per_s * params.period_s

    def within_a_step(candidate) -> bool:
        delta = candidate - pose
        return bool(np.linalg.norm(delta[~angular]) <= reach
                    and np.all(np.abs(delta[angular]) <= turn))

    if within_a_step(inside):
        return inside, True
    best, lo, hi = pose.copy(), 0.0, 1.0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        candidate = _saturated(params, pose + mid * (inside - pose))[0]
        if within_a_step(candidate):
            best, lo = candidate, mid
        else:
            hi = mid
    return best, True


def console_step(params: ConsoleParams, state: ConsoleState,
                 inputs: ConsoleInputs) -> tuple[ConsoleState, ConsoleOutputs]:
    """One step of the console (the rules of the module docstring).

    Args:
        params: :func:`console_params`.
        state: The state after the last step (:func:`console_initial_state` at first).
        inputs: This step's :class:`ConsoleInputs`.

    Returns:
        (the new state, what to publish and ask of the page). No argument is changed.
    """
    sliders = np.array(inputs.sliders, dtype=float)
    if sliders.shape != state.pose.shape:
        raise ValueError(f"sliders has shape {sliders.shape}; expected {state.pose.shape}")
    if not np.all(np.isfinite(sliders)):
        sliders = np.array(state.sliders, dtype=float)   # a broken reading is no move
    gamepad = inputs.gamepad
    enabled, stop, notice = state.enabled, state.stop, state.notice
    pose, wanted = state.pose, state.wanted
    set_sliders = None
    # The clicks since the last step: each Enable toggles, any Stop stops.
    new_enable = max(0, int(inputs.enable_clicks) - state.enable_clicks)
    new_stop = max(0, int(inputs.stop_clicks) - state.stop_clicks)
    down = _buttons_down(gamepad)
    pressed = down & ~np.asarray(state.gamepad_pressed, dtype=bool)
    new_enable += int(pressed[0])
    new_stop += int(pressed[1])
    had_gamepad = state.had_gamepad or gamepad.index is not None
    # Losing the operator, known before any click is handled: nothing engages then.
    no_browser = inputs.connections <= 0
    gamepad_lost = state.had_gamepad and gamepad.index is None

    if new_stop:
        enabled, stop, notice = False, True, ConsoleNotice.STOPPED
    elif new_enable % 2 == 1:
        if enabled:
            enabled, notice = False, ConsoleNotice.NONE
        elif not (no_browser or gamepad_lost):
            enabled, notice = True, ConsoleNotice.NONE
            if stop and inputs.anchor_pose is not None:
                anchor = np.array(inputs.anchor_pose, dtype=float)
                if anchor.shape == pose.shape and np.all(np.isfinite(anchor)):
                    pose = _saturated(params, anchor)[0]   # resume where the robot stopped
            stop = False
            # The hand continues from the published pose: the sliders go back on it (if they
            # moved while disengaged; otherwise they are left alone, so that a key already
            # pressed is not undone).
            wanted = pose.copy()
            if params.sliders_moved(sliders, params.quantize(pose)):
                set_sliders = pose.copy()
            sliders = state.sliders if set_sliders is None else params.quantize(pose)
    # Losing the operator releases the clutch (the stop, if any, stays in force).
    if no_browser and enabled:
        enabled, notice = False, ConsoleNotice.NO_BROWSER
    if gamepad_lost and enabled:
        enabled, notice = False, ConsoleNotice.GAMEPAD_LOST

    outside = state.wanted_outside
    held = state.sliders      # where the sliders are, as far as the console knows
    if set_sliders is not None:
        held = params.quantize(set_sliders)
    elif enabled:
        changed = params.sliders_moved(sliders, state.sliders)
        if changed:
            wanted, held = sliders.copy(), sliders.copy()
        rate = _gamepad_rate(params, gamepad) if gamepad.index is not None else None
        moving = rate is not None and bool(np.any(rate != 0.0))
        if moving:
            wanted = wanted + rate * params.period_s
        if changed or moving:
            wanted, outside = _saturated(params, wanted)
        # The sliders follow the wanted pose when it moved by other means (the gamepad, the
        # reach), a step at a time.
        if (moving or outside) and params.sliders_moved(params.quantize(wanted), held):
            set_sliders = wanted.copy()
            held = params.quantize(wanted)
    if enabled:
        pose, at_edge = _step_within_reach(params, pose, wanted)
    else:
        at_edge = state.saturated and not state.wanted_outside
    new_state = ConsoleState(
        pose=np.array(pose, dtype=float), wanted=np.array(wanted, dtype=float),
        sliders=np.array(held, dtype=float),
        enabled=enabled, stop=stop,
        enable_clicks=max(state.enable_clicks, int(inputs.enable_clicks)),
        stop_clicks=max(state.stop_clicks, int(inputs.stop_clicks)),
        gamepad_pressed=down, had_gamepad=had_gamepad and gamepad.index is not None,
        saturated=outside or at_edge, notice=notice, wanted_outside=outside)
    return new_state, ConsoleOutputs(pose=new_state.pose.copy(), enable=enabled, stop=stop,
                                     set_sliders=set_sliders)


def reach_saturation(arm_name: str, *, margin_m: float = 0.01):
    """The arm's reach as a ``saturate`` callable for :class:`ConsoleParams`.

    * ``air_bearing_arm`` (pose x, y, φ): the wrist point p − L₃(cos φ, sin φ) must lie in
      the annulus r_min + margin ≤ r ≤ L₁ + L₂ − margin about the shoulder, r_min the wrist's
      distance with the elbow at its limit (|L₁ − L₂| without one); outside, it is moved
      radially onto the annulus and the tool point follows (φ kept).
    * ``space_arm`` (x, y, z, roll, pitch, yaw): the tool point within the sphere of radius
      the links beyond the shoulder (1.1 m) − margin about the shoulder-pitch point (and at least
      ``margin`` from it); orientation is not saturated (the inverse kinematics holds an
      orientation it cannot reach, and says so).
    """
    from telesmooth.arms.air_bearing import SHOULDER_IN_BASE_M
    from telesmooth.arms.description import SPACE_ARM_6DOF
    from telesmooth.arms.planar import AIR_BEARING_ARM

    if arm_name == "air_bearing_arm":
        l1, l2, l3 = (float(v) for v in AIR_BEARING_ARM.link_lengths_m)
        # The elbow's limit keeps the wrist off the shoulder: at the limit angle it is
        # sqrt(L1² + L2² + 2 L1 L2 cos(q_max)) away (0.127 m at ±170°).
        elbow = float(np.min(np.abs([AIR_BEARING_ARM.joint_lower_rad[1],
                                     AIR_BEARING_ARM.joint_upper_rad[1]])))
        folded = math.sqrt(max(0.0, l1 * l1 + l2 * l2 + 2.0 * l1 * l2 * math.cos(elbow)))
        inner, outer = max(abs(l1 - l2), folded) + margin_m, l1 + l2 - margin_m

        def saturate(pose):
            pose = np.array(pose, dtype=float)
            direction = np.array([math.cos(pose[2]), math.sin(pose[2])])
            wrist = pose[:2] - l3 * direction
            radius = float(np.hypot(*wrist))
            if inner <= radius <= outer:
                return pose, False
            unit = wrist / radius if radius > 0.0 else np.array([1.0, 0.0])
            wrist = unit * min(max(radius, inner), outer)
            pose[:2] = wrist + l3 * direction
            return pose, True

        return saturate
    if arm_name == "space_arm":
        centre = np.asarray(SHOULDER_IN_BASE_M, dtype=float)
        # The links beyond the shoulder stretched out: upper arm, forearm, wrist and tool.
        outer = sum(float(np.linalg.norm(link.segment_m))
                    for link in SPACE_ARM_6DOF.links[1:]) - margin_m

        def saturate(pose):
            pose = np.array(pose, dtype=float)
            offset = pose[:3] - centre
            radius = float(np.linalg.norm(offset))
            if margin_m <= radius <= outer:
                return pose, False
            unit = offset / radius if radius > 0.0 else np.array([1.0, 0.0, 0.0])
            pose[:3] = centre + unit * min(max(radius, margin_m), outer)
            return pose, True

        return saturate
    raise ValueError(f"arm_name = {arm_name!r} must be 'air_bearing_arm' or 'space_arm'")
