"""The operator's console as a Drake system (systems/operator_console.py): in a Simulator, with
a scripted page for Meshcat's controls, its outputs are the pure ``console_step``'s, at 100 Hz
from t = 0; it moves the sliders when the step asks; it re-anchors at the forward kinematics
of ``q_anchor`` after a stop when ``anchor`` says the ground holds the robot. Then the console
on a real Meshcat page (its sliders round what is put on them to their step). Each test's
comment says which wrong implementation it catches."""

import numpy as np
import pytest
from pydrake.geometry import Meshcat
from pydrake.systems.analysis import Simulator

from telesmooth.console.input import (
    ConsoleInputs,
    ConsoleNotice,
    Gamepad,
    console_initial_state,
    console_params,
    console_step,
    reach_saturation,
)
from telesmooth.systems.operator_console import (
    ENABLE_BUTTON,
    SLIDERS,
    STOP_BUTTON,
    MeshcatControls,
    OperatorConsole,
)

PLANAR = ("x_m", "y_m", "phi_rad")
POSE0 = np.array([0.7, 0.0, 0.0])
PERIOD = 0.01


class ScriptedControls:
    """Meshcat's controls as a script: read k returns ``script(k)`` (a dict of ConsoleInputs
    fields; no "sliders": the page's sliders), the sliders keep what set_sliders puts on
    them. Records every read's anchor_pose and every set_sliders (read index, pose)."""

    def __init__(self, script, pose=POSE0):
        self._script = script
        self.sliders = np.array(pose, dtype=float)
        self.anchors = []
        self.set_calls = []

    @property
    def reads(self):
        return len(self.anchors)

    def inputs(self, k, anchor_pose=None):
        fields = dict(self._script(k))
        if "sliders" in fields:
            self.sliders = np.array(fields["sliders"], dtype=float)
        fields["sliders"] = self.sliders.copy()
        fields.setdefault("anchor_pose", anchor_pose)
        return ConsoleInputs(**fields)

    def read(self, anchor_pose=None):
        inputs = self.inputs(self.reads, anchor_pose)
        self.anchors.append(None if anchor_pose is None else np.array(anchor_pose))
        return inputs

    def set_sliders(self, pose):
        self.set_calls.append((self.reads - 1, np.array(pose, dtype=float)))
        self.sliders = np.array(pose, dtype=float)


def session(k):
    """Engage at read 2, drag x at read 4, stop at read 30, engage again at read 40, the
    page closed at read 60, back at read 65 and engaged at read 70."""
    fields = {"enable_clicks": (k >= 2) + (k >= 40) + (k >= 70), "stop_clicks": int(k >= 30),
              "connections": 0 if 60 <= k < 65 else 1}
    if k == 4:
        fields["sliders"] = [0.72, -0.01, 0.1]
    if k == 50:
        fields["sliders"] = [2.0, 0.0, 0.0]      # outside the reach
    return fields


def make_console(script, **kwargs):
    params = console_params(PLANAR, period_s=PERIOD,
                            saturate=reach_saturation("air_bearing_arm"))
    controls = ScriptedControls(script)
    return OperatorConsole(params, controls, initial_pose=POSE0, **kwargs), controls


def outputs(console, context):
    return (console.get_pose_desired_output_port().Eval(context).copy(),
            console.get_enable_output_port().Eval(context)[0],
            console.get_stop_requested_output_port().Eval(context)[0],
            console.get_notice_output_port().Eval(context)[0],
            console.get_saturated_output_port().Eval(context)[0])


def test_the_update_runs_at_100_hz_from_t_0_and_outputs_the_state_without_feedthrough():
    # Catches: a first update one period late (offset = period), a period other than the
    # params' (e.g. the 25 Hz display's), outputs computed from the inputs (feedthrough).
    console, controls = make_console(session)
    simulator = Simulator(console)
    for t, reads in ((0.005, 1), (0.015, 2), (0.095, 10), (0.995, 100)):
        simulator.AdvanceTo(t)
        assert controls.reads == reads, t
    assert not console.HasAnyDirectFeedthrough()


def test_the_outputs_follow_the_pure_step_and_the_sliders_are_moved_when_it_asks():
    # Catches: a state vector that loses a field between updates (the clicks handled twice,
    # the gamepad edge lost), outputs wired to the wrong field of the state, set_sliders not
    # called (or called on every step).
    console, controls = make_console(session)
    simulator = Simulator(console)
    context = simulator.get_mutable_context()
    reference = ScriptedControls(session)
    state = console_initial_state(console.params, POSE0)
    asked = []
    for k in range(90):
        simulator.AdvanceTo(k * PERIOD + 0.5 * PERIOD)
        state, out = console_step(console.params, state, reference.inputs(k))
        if out.set_sliders is not None:
            reference.sliders = out.set_sliders.copy()
            asked.append((k, out.set_sliders))
        pose, enable, stop, notice, saturated = outputs(console, context)
        np.testing.assert_array_equal(pose, state.pose)
        assert (enable, stop, notice, saturated) == (state.enabled, state.stop,
                                                     int(state.notice), state.saturated), k
    # Engaging at read 2 leaves the sliders alone (they have not moved since the start); the
    # re-engagement at 40 after the stop, the reach at 50 and the engagement at 70 (after the
    # sliders moved while the page was away) put them on the pose.
    assert [k for k, _ in controls.set_calls] == [k for k, _ in asked] == [40, 50, 70]
    for (_, done), (_, wanted) in zip(controls.set_calls, asked):
        np.testing.assert_array_equal(done, wanted)
    # The script did what it says: the outputs went through every rule.
    assert console.console_state(context).notice is ConsoleNotice.NONE
    assert console.console_state(context).enabled


def test_an_engagement_after_a_stop_re_anchors_at_the_forward_kinematics_of_q_anchor():
    # Catches: the anchor read without the holding flag, q_anchor not passed through the
    # forward kinematics, the anchor used on an engagement that follows no stop.
    def fk(q):
        return np.array([0.5 * q[0], 0.25 * q[1], q[2]])

    def script(k):
        return {"enable_clicks": (k >= 2) + (k >= 20), "stop_clicks": int(k >= 10),
                **({"sliders": [0.75, 0.0, 0.0]} if k == 3 else {})}

    console, controls = make_console(script, forward_kinematics=fk, num_joints=3)
    context = console.CreateDefaultContext()
    console.get_q_anchor_input_port().FixValue(context, [1.2, 0.4, -0.3])
    anchor = console.get_anchor_input_port().FixValue(context, [0.0])
    simulator = Simulator(console, context)
    simulator.AdvanceTo(0.155)                       # stopped at read 10, not yet holding
    assert all(a is None for a in controls.anchors)
    stopped = console.get_pose_desired_output_port().Eval(context).copy()
    assert console.get_stop_requested_output_port().Eval(context)[0] == 1.0
    assert stopped[0] > 0.7                          # it had moved towards the slider
    anchor.GetMutableData().set_value([1.0])          # the ground holds the robot now
    simulator.AdvanceTo(0.205)                       # engaged at read 20
    np.testing.assert_array_equal(controls.anchors[-1], [0.6, 0.1, -0.3])
    np.testing.assert_array_equal(console.get_pose_desired_output_port().Eval(context),
                                  [0.6, 0.1, -0.3])
    assert controls.set_calls[-1][0] == 20
    np.testing.assert_array_equal(controls.set_calls[-1][1], [0.6, 0.1, -0.3])


def test_without_the_holding_flag_an_engagement_after_a_stop_continues_from_the_pose():
    # Catches: an anchor taken while the ground does not hold the robot there (it is still
    # moving: the hand would jump to a pose the robot leaves).
    def script(k):
        return {"enable_clicks": (k >= 2) + (k >= 20), "stop_clicks": int(k >= 10)}

    console, controls = make_console(script, forward_kinematics=lambda q: np.zeros(3),
                                     num_joints=3)
    context = console.CreateDefaultContext()
    console.get_q_anchor_input_port().FixValue(context, [1.2, 0.4, -0.3])
    console.get_anchor_input_port().FixValue(context, [0.0])
    Simulator(console, context).AdvanceTo(0.205)
    assert all(a is None for a in controls.anchors)
    np.testing.assert_array_equal(console.get_pose_desired_output_port().Eval(context), POSE0)
    assert console.get_enable_output_port().Eval(context)[0] == 1.0


def test_unconnected_anchor_ports_are_no_anchor():
    # Catches: evaluating an unconnected optional input (an error in every diagram without
    # the ground's FIFO).
    console, controls = make_console(session, forward_kinematics=lambda q: np.zeros(3),
                                     num_joints=3)
    Simulator(console).AdvanceTo(0.455)
    assert controls.reads == 46 and all(a is None for a in controls.anchors)


# --- on a real Meshcat page -----------------------------------------------------------------


class Pad:
    """Meshcat's Gamepad as GetGamepad returns it."""

    def __init__(self, index=None, axes=(), button_values=()):
        self.index, self.axes, self.button_values = index, list(axes), list(button_values)


class Browser:
    """A real Meshcat whose browser side (a connection, the clicks, the gamepad) is ours;
    everything else (the sliders: their range, step and rounding) is Meshcat's own."""

    def __init__(self, meshcat):
        self._meshcat = meshcat
        self.pad = Pad()
        self.clicks = {ENABLE_BUTTON: 0, STOP_BUTTON: 0}

    def __getattr__(self, name):
        return getattr(self._meshcat, name)

    def GetGamepad(self):
        return self.pad

    def GetNumActiveConnections(self):
        return 1

    def GetButtonClicks(self, name):
        return self.clicks[name]


@pytest.fixture(scope="module")
def meshcat():
    return Meshcat()


def meshcat_console(meshcat, pose):
    for name in PLANAR:
        meshcat.DeleteSlider(SLIDERS[name], strict=False)
    for button in (ENABLE_BUTTON, STOP_BUTTON):
        meshcat.DeleteButton(button, strict=False)
    browser = Browser(meshcat)
    controls = MeshcatControls(browser, PLANAR, initial_pose=pose,
                               position_range_m={"x_m": (-1.2, 1.2), "y_m": (-1.2, 1.2)})
    console = OperatorConsole(console_params(PLANAR, period_s=PERIOD,
                                             slider_steps=controls.slider_steps),
                              controls, initial_pose=pose)
    simulator = Simulator(console)
    return browser, console, simulator


def test_meshcat_controls_read_the_page():
    # Catches: sliders read in another order than the pose's, the buttons swapped.
    browser = Browser(Meshcat())
    controls = MeshcatControls(browser, PLANAR, initial_pose=[0.5, -0.25, 1.0],
                               position_range_m={"x_m": (-1.2, 1.2), "y_m": (-1.2, 1.2)})
    browser.clicks[STOP_BUTTON] = 2
    browser.pad = Pad(0, [0.5, -1.0], [1.0])
    inputs = controls.read(anchor_pose=np.array([0.1, 0.2, 0.3]))
    np.testing.assert_array_equal(inputs.sliders, [0.5, -0.25, 1.0])
    assert (inputs.enable_clicks, inputs.stop_clicks, inputs.connections) == (0, 2, 1)
    assert inputs.gamepad == Gamepad(0, (0.5, -1.0), (1.0,))
    np.testing.assert_array_equal(inputs.anchor_pose, [0.1, 0.2, 0.3])


def test_on_a_meshcat_page_the_sticks_move_the_hand_at_max_speed(meshcat):
    # Catches: a console whose gamepad path does not survive the page's slider rounding.
    browser, console, simulator = meshcat_console(meshcat, [0.5, 0.0, 0.0])
    context = simulator.get_mutable_context()
    browser.clicks[ENABLE_BUTTON] = 1
    simulator.AdvanceTo(0.005)
    assert console.get_enable_output_port().Eval(context)[0] == 1.0
    browser.pad = Pad(0, [0.0, -1.0, 1.0, 0.0], [0.0, 0.0])   # left stick up, right stick right
    simulator.AdvanceTo(2.005)                               # 200 steps: 0.1 m and 0.4 rad
    np.testing.assert_allclose(console.get_pose_desired_output_port().Eval(context),
                               [0.5, 0.1, 0.4], rtol=0, atol=1e-12)


def test_on_a_meshcat_page_engaging_off_the_slider_grid_does_not_move_the_hand(meshcat):
    # Catches: motion without intent after engaging (or re-anchoring) at a pose that is not
    # on the sliders' grid, which the robot's anchor never is.
    pose = [0.5012, 0.0013, 0.0071]
    browser, console, simulator = meshcat_console(meshcat, pose)
    browser.clicks[ENABLE_BUTTON] = 1
    simulator.AdvanceTo(0.5)
    context = simulator.get_context()
    assert console.get_enable_output_port().Eval(context)[0] == 1.0
    np.testing.assert_array_equal(console.get_pose_desired_output_port().Eval(context), pose)
