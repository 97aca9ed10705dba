"""The operator's console as a pure step (console/input.py): the clutch, the stop, the hand's
speed limit, re-anchoring, losing the operator, the gamepad, the arm's reach.

Scripted scenarios: a ``Page`` (a browser that keeps what ``set_sliders`` puts on the sliders
and counts clicks) drives ``console_step``; every expected pose is written out by hand from
the defaults (period 0.01 s, 0.05 m/s → 0.5 mm per step, 0.2 rad/s → 2 mrad per step).
Properties: hypothesis streams of arbitrary inputs, derandomized (conftest), 200 examples.
Each test's comment says which wrong implementation it catches.
"""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, example, given, settings
from hypothesis import strategies as st

from telesmooth.arms.air_bearing import SHOULDER_IN_BASE_M
from telesmooth.arms.planar import AIR_BEARING_ARM
from telesmooth.console.input import (
    ConsoleInputs,
    ConsoleNotice,
    ConsoleState,
    Gamepad,
    console_initial_state,
    console_params,
    console_step,
    reach_saturation,
)
from telesmooth.safety.state_codec import VectorCodec

PLANAR = ("x_m", "y_m", "phi_rad")
SPATIAL = ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")
STEP_M = 0.0005        # 0.05 m/s × 0.01 s
STEP_RAD = 0.002       # 0.2 rad/s × 0.01 s
ROUNDING = 1e-15
L1, L2, L3 = AIR_BEARING_ARM.link_lengths_m
# The wrist's closest approach to the shoulder is with the elbow at its ±170° limit (law of
# cosines, the links' interior angle 10°): 0.1268 m; the reach keeps a 0.01 m margin.
FOLDED = math.sqrt(L1 ** 2 + L2 ** 2 - 2 * L1 * L2 * math.cos(math.radians(10.0)))
INNER, OUTER = FOLDED + 0.01, L1 + L2 - 0.01     # 0.1368 and 0.89 m


class Page:
    """The browser page: sliders that keep what the console puts on them, click counters
    that only grow, the connection, a gamepad. ``step`` makes one console step."""

    def __init__(self, params, pose):
        self.params = params
        self.state = console_initial_state(params, pose)
        self.sliders = np.array(pose, dtype=float)
        self.enable_clicks = 0
        self.stop_clicks = 0
        self.connections = 1
        self.gamepad = Gamepad()

    def step(self, *, enable=0, stop=0, sliders=None, anchor=None):
        self.enable_clicks += enable
        self.stop_clicks += stop
        if sliders is not None:
            self.sliders = np.array(sliders, dtype=float)
        inputs = ConsoleInputs(sliders=self.sliders.copy(), enable_clicks=self.enable_clicks,
                               stop_clicks=self.stop_clicks, gamepad=self.gamepad,
                               connections=self.connections, anchor_pose=anchor)
        self.state, out = console_step(self.params, self.state, inputs)
        if out.set_sliders is not None:
            self.sliders = np.array(out.set_sliders, dtype=float)
        return out


def planar_page(pose=(0.5, 0.0, 0.0), **settings):
    return Page(console_params(PLANAR, **settings), pose)


def engaged_page(pose=(0.5, 0.0, 0.0), names=PLANAR, **settings):
    page = Page(console_params(names, **settings), pose)
    out = page.step(enable=1)
    assert out.enable
    return page


def wrist_radius(pose):
    return math.hypot(pose[0] - L3 * math.cos(pose[2]), pose[1] - L3 * math.sin(pose[2]))


# --- the clutch ---------------------------------------------------------------------------


def test_starts_disengaged_and_the_pose_does_not_move_whatever_the_sliders_do():
    # Catches: a console that starts engaged, or follows the sliders with the clutch released.
    page = planar_page()
    for sliders in ([0.6, 0.1, 0.3], [-0.4, 0.8, -2.0], [0.5, 0.0, 0.0], [0.9, 0.9, 3.0]):
        for _ in range(10):
            out = page.step(sliders=sliders)
            np.testing.assert_array_equal(out.pose, [0.5, 0.0, 0.0])
            assert (out.enable, out.stop, out.set_sliders) == (False, False, None)


def test_one_enable_click_engages_and_puts_the_sliders_on_the_published_pose():
    # Catches: engaging that picks up sliders moved while released (a jump to them), or that
    # does not ask the page to put the sliders back (set_sliders None).
    page = planar_page()
    page.step(sliders=[0.7, 0.2, 1.0])
    page.step()
    out = page.step(enable=1)
    assert out.enable and not out.stop
    np.testing.assert_array_equal(out.pose, [0.5, 0.0, 0.0])
    np.testing.assert_array_equal(out.set_sliders, [0.5, 0.0, 0.0])
    for _ in range(5):   # the page now shows the pose: nothing moves
        out = page.step()
        np.testing.assert_array_equal(out.pose, [0.5, 0.0, 0.0])
        assert out.enable and out.set_sliders is None
    assert page.state.notice is ConsoleNotice.NONE


def test_two_clicks_in_one_step_leave_the_clutch_as_it_was():
    # Catches: "any new click toggles once" (two clicks would engage) instead of one toggle
    # per click.
    page = planar_page()
    out = page.step(enable=2)
    assert not out.enable and out.set_sliders is None
    out = page.step(enable=1)
    assert out.enable
    out = page.step(enable=2)
    assert out.enable and out.set_sliders is None
    out = page.step(enable=3)
    assert not out.enable
    out = page.step()       # the clicks were counted: the same count does not toggle again
    assert not out.enable


# --- the hand moves at the speed limit ------------------------------------------------------


def test_a_diagonal_slider_move_is_followed_at_max_speed_times_period_and_lands_on_it():
    # Catches: a per-coordinate clip (the diagonal step would be (0.5, 0.5) mm, 0.71 mm long),
    # no speed limit (one jump), a limit in the wrong units, an approach that never lands.
    page = engaged_page()
    target = [0.503, 0.004, 0.0]            # 3-4-5: 5 mm away, 10 steps of 0.5 mm
    for k in range(1, 10):
        out = page.step(sliders=target if k == 1 else None)
        np.testing.assert_allclose(out.pose, [0.5 + 0.0003 * k, 0.0004 * k, 0.0],
                                   rtol=0, atol=ROUNDING)
        assert out.set_sliders is None
    out = page.step()
    np.testing.assert_array_equal(out.pose, target)    # the last step lands exactly
    out = page.step()
    np.testing.assert_array_equal(out.pose, target)


def test_each_angle_moves_alone_at_its_own_limit_and_the_positions_together():
    # Catches: the angles limited together (one norm over roll and pitch), angles and
    # positions in one norm (the angles would slow the position down), the angular limit
    # taken from the linear one.
    page = engaged_page((0.4, 0.0, 0.6, 0.0, 0.0, 0.0), SPATIAL)
    target = [0.403, 0.0, 0.6, 0.01, -0.004, 0.0]
    for k in range(1, 6):
        out = page.step(sliders=target if k == 1 else None)
        expected = [0.4 + STEP_M * k, 0.0, 0.6, STEP_RAD * k, -STEP_RAD * min(k, 2), 0.0]
        np.testing.assert_allclose(out.pose, expected, rtol=0, atol=ROUNDING)
    out = page.step()
    np.testing.assert_array_equal(out.pose, target)


def test_a_slider_outside_the_reach_is_saturated_and_the_page_told():
    # Catches: a console that sends the unreachable slider value on (no saturation), or
    # saturates without moving the slider onto the boundary / without the flag.
    page = engaged_page((0.7, 0.0, 0.0), saturate=reach_saturation("air_bearing_arm"))
    out = page.step(sliders=[1.5, 0.0, 0.0])       # wrist at 1.3 m
    np.testing.assert_allclose(out.set_sliders, [OUTER + L3, 0.0, 0.0], rtol=0, atol=1e-15)
    assert page.state.saturated
    np.testing.assert_allclose(out.pose, [0.7 + STEP_M, 0.0, 0.0], rtol=0, atol=ROUNDING)
    out = page.step(sliders=[0.8, 0.0, 0.0])        # back inside: the flag clears
    assert not page.state.saturated and out.set_sliders is None


# --- the stop and re-anchoring ------------------------------------------------------------


def test_stop_disengages_and_holds_stop_through_further_steps_until_enable():
    # Catches: a stop that is a one-step pulse, a stop that still moves the pose in its step,
    # a stop that does not release the clutch, a stop that Enable does not clear.
    page = engaged_page()
    page.step(sliders=[0.6, 0.0, 0.0])
    page.step()
    out = page.step(stop=1)
    frozen = [0.5 + 2 * STEP_M, 0.0, 0.0]
    np.testing.assert_allclose(out.pose, frozen, rtol=0, atol=ROUNDING)
    assert (out.enable, out.stop) == (False, True)
    assert page.state.notice is ConsoleNotice.STOPPED
    for sliders in ([0.3, 0.3, 0.3], None, None, [0.7, -0.2, 0.0]):
        later = page.step(sliders=sliders)
        np.testing.assert_array_equal(later.pose, out.pose)
        assert (later.enable, later.stop) == (False, True)
    out = page.step(stop=1)                    # a second stop changes nothing
    assert (out.enable, out.stop) == (False, True)
    out = page.step(enable=1)
    assert (out.enable, out.stop) == (True, False)
    assert page.state.notice is ConsoleNotice.NONE
    np.testing.assert_array_equal(out.set_sliders, out.pose)


def test_stop_wins_over_an_enable_click_in_the_same_step():
    # Catches: Enable handled before Stop (the operator's stop would be lost).
    page = planar_page()
    out = page.step(enable=1, stop=1)
    assert (out.enable, out.stop) == (False, True)


def test_enable_after_a_stop_re_anchors_at_the_anchor_pose_and_moves_the_sliders_there():
    # Catches: ignoring the anchor (the hand would go on from where the robot no longer is),
    # re-anchoring without moving the sliders (the next step would pull the hand back).
    page = engaged_page()
    page.step(stop=1)
    anchor = np.array([0.61, -0.07, 0.25])
    out = page.step(enable=1, anchor=anchor)
    assert out.enable and not out.stop
    np.testing.assert_array_equal(out.pose, anchor)
    np.testing.assert_array_equal(out.set_sliders, anchor)
    for _ in range(3):
        out = page.step(anchor=[0.0, 0.0, 0.0])       # an anchor while engaged: ignored
        np.testing.assert_array_equal(out.pose, anchor)


def test_enable_after_a_stop_without_an_anchor_continues_from_where_it_was():
    # Catches: a re-anchoring that jumps somewhere (e.g. to the sliders or the origin).
    page = engaged_page()
    page.step(sliders=[0.6, 0.0, 0.0])
    page.step(stop=1)
    out = page.step(enable=1)
    np.testing.assert_allclose(out.pose, [0.5 + STEP_M, 0.0, 0.0], rtol=0, atol=ROUNDING)
    np.testing.assert_array_equal(out.set_sliders, out.pose)


def test_an_anchor_is_used_only_after_a_stop():
    # Catches: re-anchoring at every engagement (a clutch re-engaged by the operator would
    # jump to the robot's commanded pose).
    page = engaged_page()
    page.step(enable=1)                       # released by the operator, no stop
    out = page.step(enable=1, anchor=[0.61, -0.07, 0.25])
    np.testing.assert_array_equal(out.pose, [0.5, 0.0, 0.0])


def test_a_non_finite_or_misshapen_anchor_is_ignored():
    # Catches: a NaN anchor taken as the hand pose (a NaN pose sent to the ground).
    for anchor in ([0.6, math.nan, 0.0], [0.6, 0.1]):
        page = engaged_page()
        page.step(stop=1)
        out = page.step(enable=1, anchor=anchor)
        assert out.enable
        np.testing.assert_array_equal(out.pose, [0.5, 0.0, 0.0])


# --- losing the operator --------------------------------------------------------------------


def test_no_browser_releases_the_clutch_and_enable_cannot_engage_without_one():
    # Catches: a console that keeps driving with the page closed, or engages with nobody
    # there, or reports the wrong notice.
    page = engaged_page()
    page.step(sliders=[0.6, 0.0, 0.0])
    page.connections = 0
    out = page.step()
    assert (out.enable, out.stop) == (False, False)
    assert page.state.notice is ConsoleNotice.NO_BROWSER
    np.testing.assert_allclose(out.pose, [0.5 + STEP_M, 0.0, 0.0], rtol=0, atol=ROUNDING)
    out = page.step(enable=1)
    assert not out.enable and out.set_sliders is None
    assert page.state.notice is ConsoleNotice.NO_BROWSER
    page.connections = 1
    out = page.step()                 # reconnecting does not engage by itself
    assert not out.enable
    out = page.step(enable=1)
    assert out.enable and page.state.notice is ConsoleNotice.NONE


def test_a_stop_stays_in_force_when_the_browser_goes():
    # Catches: a connection loss that overwrites the operator's stop.
    page = engaged_page()
    page.step(stop=1)
    page.connections = 0
    out = page.step()
    assert (out.enable, out.stop) == (False, True)


# --- the gamepad ----------------------------------------------------------------------------


def pad(axes=(0.0, 0.0, 0.0, 0.0), buttons=(0.0, 0.0)):
    return Gamepad(index=0, axes=tuple(axes), buttons=tuple(buttons))


def test_gamepad_button_0_toggles_on_its_rising_edge_only():
    # Catches: a level-triggered button (held down it would toggle every step).
    page = planar_page()
    page.gamepad = pad(buttons=(1.0, 0.0))
    assert page.step().enable
    for _ in range(5):
        assert page.step().enable            # held down: no new toggle
    page.gamepad = pad()
    assert page.step().enable
    page.gamepad = pad(buttons=(1.0, 0.0))
    assert not page.step().enable
    page.gamepad = pad()
    assert not page.step().enable
    page.gamepad = pad(buttons=(0.4, 0.0))   # less than half pressed is up
    assert not page.step().enable


def test_gamepad_button_1_stops():
    # Catches: the stop button not mapped, or mapped to the clutch.
    page = engaged_page()
    page.gamepad = pad(buttons=(0.0, 1.0))
    out = page.step()
    assert (out.enable, out.stop) == (False, True)
    out = page.step()
    assert (out.enable, out.stop) == (False, True)


@pytest.mark.parametrize("axes, per_step", [
    ((0.0, -1.0, 0.0, 0.0), (0.0, STEP_M, 0.0)),      # left stick up: +y
    ((0.0, 1.0, 0.0, 0.0), (0.0, -STEP_M, 0.0)),      # left stick down: −y
    ((1.0, 0.0, 0.0, 0.0), (STEP_M, 0.0, 0.0)),       # left stick right: +x
    ((-0.5, 0.0, 0.0, 0.0), (-0.5 * STEP_M, 0.0, 0.0)),
    ((0.0, 0.0, 0.5, 0.0), (0.0, 0.0, 0.5 * STEP_RAD)),   # right stick right: +φ
    ((0.0, 0.0, 0.0, -1.0), (0.0, 0.0, 0.0)),        # right stick y: z, which a planar pose lacks
])
def test_planar_sticks_move_the_wanted_pose_at_axis_times_max_speed(axes, per_step):
    # Catches: a flipped y (stick up = −1 must be +y), axes mapped to the wrong coordinate,
    # a rate not scaled by the deflection, sliders not moved with the wanted pose.
    page = engaged_page()
    page.gamepad = pad(axes)
    for k in range(1, 5):
        out = page.step()
        expected = np.array([0.5, 0.0, 0.0]) + k * np.array(per_step)
        np.testing.assert_allclose(out.pose, expected, rtol=0, atol=ROUNDING)
        if any(per_step):
            np.testing.assert_array_equal(out.set_sliders, page.state.wanted)
            np.testing.assert_allclose(out.set_sliders, expected, rtol=0, atol=ROUNDING)
        else:
            assert out.set_sliders is None


def test_spatial_right_stick_moves_z_and_yaw():
    # Catches: a flipped z (right stick up = −1 must be +z), the right stick x on roll.
    page = engaged_page((0.4, 0.0, 0.6, 0.0, 0.0, 0.0), SPATIAL)
    page.gamepad = pad((0.0, 0.0, -1.0, -1.0))
    out = page.step()
    np.testing.assert_allclose(out.pose, [0.4, 0.0, 0.6 + STEP_M, 0.0, 0.0, -STEP_RAD],
                               rtol=0, atol=ROUNDING)


def test_stick_deflections_below_the_deadzone_are_none():
    # Catches: no deadzone (a resting stick drifts the hand), or a deadzone applied to the
    # sum of the axes instead of each axis.
    page = engaged_page(gamepad_deadzone=0.1)
    page.gamepad = pad((0.099, -0.099, 0.099, -0.099))
    for _ in range(5):
        out = page.step()
        np.testing.assert_array_equal(out.pose, [0.5, 0.0, 0.0])
        assert out.set_sliders is None
    page.gamepad = pad((0.2, 0.05, math.nan, 0.0))  # a NaN axis is none too
    out = page.step()
    np.testing.assert_allclose(out.pose, [0.5 + 0.2 * STEP_M, 0.0, 0.0], rtol=0, atol=ROUNDING)


def test_a_gamepad_that_disappears_while_engaged_releases_the_clutch():
    # Catches: a console that keeps driving on the last stick reading after the pad is gone.
    page = planar_page()
    page.gamepad = pad(buttons=(1.0, 0.0))
    assert page.step().enable
    page.gamepad = pad((0.0, -1.0, 0.0, 0.0))
    page.step()
    page.gamepad = Gamepad()
    out = page.step()
    assert (out.enable, out.stop) == (False, False)
    assert page.state.notice is ConsoleNotice.GAMEPAD_LOST
    np.testing.assert_allclose(out.pose, [0.5, STEP_M, 0.0], rtol=0, atol=ROUNDING)
    out = page.step(enable=1)          # the mouse can engage again without the pad
    assert out.enable and page.state.notice is ConsoleNotice.NONE


def test_a_gamepad_lost_while_released_or_never_present_gives_no_notice():
    # Catches: GAMEPAD_LOST raised when no pad was driving.
    page = planar_page()
    page.gamepad = pad()
    page.step()
    page.gamepad = Gamepad()
    out = page.step()
    assert not out.enable and page.state.notice is ConsoleNotice.NONE
    page = engaged_page()
    for _ in range(3):
        assert page.step().enable


# --- the reach ------------------------------------------------------------------------------


def test_planar_reach_moves_a_far_wrist_onto_the_outer_circle_on_the_same_ray():
    # Catches: a reach of L1 + L2 + L3 (the tool, not the wrist), no margin, a saturation
    # that changes φ or leaves the wrist's ray.
    saturate = reach_saturation("air_bearing_arm")
    pose, moved = saturate([0.9 + 0.2, 1.2, 0.0])          # wrist (0.9, 1.2): r = 1.5
    assert moved is True
    # wrist (0.9, 1.2) · 0.89 / 1.5 = (0.534, 0.712), the tool 0.2 further along φ = 0.
    np.testing.assert_allclose(pose, [0.534 + 0.2, 0.712, 0.0], rtol=0, atol=1e-15)
    pose, moved = saturate([1.5, 0.2, math.pi / 2])        # wrist (1.5, 0): r = 1.5
    assert moved
    np.testing.assert_allclose(pose, [0.89, 0.2, math.pi / 2], rtol=0, atol=1e-15)


def test_planar_reach_moves_a_near_wrist_onto_the_inner_circle_and_keeps_inside_poses():
    # Catches: no inner boundary (the wrist closer than the elbow's ±170° limit allows is
    # unreachable), |L1 − L2| taken for it (0.1 m: the elbow cannot fold that far), or a reach
    # that moves poses already inside.
    saturate = reach_saturation("air_bearing_arm")
    pose, moved = saturate([0.03 + 0.2, 0.04, 0.0])        # wrist (0.03, 0.04): r = 0.05
    assert moved
    # Onto r = INNER (the elbow's limit, not |L1 − L2|) along the wrist's ray, φ kept.
    np.testing.assert_allclose(pose, [0.03 * INNER / 0.05 + 0.2, 0.04 * INNER / 0.05, 0.0],
                               rtol=0, atol=1e-15)
    for inside in ([0.7, 0.0, 0.0], [0.1, 0.5, 2.0], [0.88 + 0.2, 0.0, 0.0],
                   [0.14 + 0.2, 0.0, 0.0], [0.0, -0.6, -1.5]):
        pose, moved = saturate(np.array(inside))
        assert moved is False
        np.testing.assert_array_equal(pose, inside)
    pose, moved = reach_saturation("air_bearing_arm", margin_m=0.0)([1.2, 0.0, 0.0])
    assert moved
    np.testing.assert_allclose(pose, [1.1, 0.0, 0.0], rtol=0, atol=1e-15)


def test_planar_reach_does_not_change_its_argument():
    # Catches: a saturation that writes into the caller's array (the state's wanted pose).
    pose = np.array([1.5, 0.0, 0.0])
    reach_saturation("air_bearing_arm")(pose)
    np.testing.assert_array_equal(pose, [1.5, 0.0, 0.0])


def test_spatial_reach_is_the_sphere_about_the_shoulder():
    # Catches: the sphere centred at the base origin instead of the shoulder pitch point, a
    # radius including the 0.25 m column, an orientation that is changed.
    saturate = reach_saturation("space_arm")
    centre = np.asarray(SHOULDER_IN_BASE_M)
    np.testing.assert_array_equal(centre, [0.0, 0.0, 0.45])
    far = np.concatenate([centre + [0.0, 0.9, 1.2], [0.1, -0.2, 0.3]])     # r = 1.5
    pose, moved = saturate(far)
    assert moved
    # 1.1 m (0.5 + 0.4 + 0.12 + 0.04 + 0.04) − 0.01: (0, 0.9, 1.2) · 1.09 / 1.5.
    np.testing.assert_allclose(pose, [0.0, 0.654, 0.45 + 0.872, 0.1, -0.2, 0.3],
                               rtol=0, atol=1e-15)
    inside = np.array([0.5, 0.2, 0.6, 1.0, 0.5, -1.0])
    pose, moved = saturate(inside)
    assert moved is False
    np.testing.assert_array_equal(pose, inside)
    pose, moved = saturate([0.0, 0.0, 0.45, 0.0, 0.0, 0.0])   # at the shoulder itself
    assert moved
    assert np.linalg.norm(pose[:3] - centre) == pytest.approx(0.01, abs=1e-15)


def test_reach_of_an_unknown_arm_is_an_error():
    # Catches: an unknown arm silently given no reach (every pose accepted).
    with pytest.raises(ValueError, match="arm_name"):
        reach_saturation("scara")


# --- console_params -------------------------------------------------------------------------


@pytest.mark.parametrize("field, value", [
    ("period_s", 0.0), ("period_s", -0.01), ("period_s", math.inf), ("period_s", True),
    ("max_speed_m_per_s", 0.0), ("max_speed_m_per_s", math.nan),
    ("max_speed_m_per_s", "0.05"),
    ("max_angular_speed_rad_per_s", -0.2), ("max_angular_speed_rad_per_s", math.inf),
    ("gamepad_deadzone", -0.1), ("gamepad_deadzone", 1.0), ("gamepad_deadzone", math.nan),
    ("gamepad_deadzone", True),
    ("saturate", 3.0), ("saturate", "air_bearing_arm"),
])
def test_console_params_rejects_a_bad_value_naming_the_field(field, value):
    # Catches: a missing check (e.g. deadzone 1.0 would silence the sticks, a bool period
    # would be taken as 1 s, a string saturate would fail at the first step).
    with pytest.raises(ValueError, match=field):
        console_params(PLANAR, **{field: value})


def test_console_params_accepts_the_edges_and_needs_a_pose():
    # Catches: a deadzone check that rejects 0 (no deadzone) or an off-by-one at the edges.
    params = console_params(PLANAR, gamepad_deadzone=0.0, saturate=None, period_s=1)
    assert params.gamepad_deadzone == 0.0
    np.testing.assert_array_equal(params.angular, [False, False, True])
    with pytest.raises(ValueError, match="pose_names"):
        console_params(())


def test_initial_state_rejects_a_wrong_pose_and_step_a_wrong_slider_shape():
    # Catches: a NaN start pose accepted (published as is), sliders of another arm's shape
    # broadcast into the pose.
    params = console_params(PLANAR)
    for pose in ([0.5, 0.0], [0.5, math.nan, 0.0]):
        with pytest.raises(ValueError, match="pose"):
            console_initial_state(params, pose)
    state = console_initial_state(params, [0.5, 0.0, 0.0])
    with pytest.raises(ValueError, match="sliders"):
        console_step(params, state, ConsoleInputs(sliders=np.zeros(2)))


# --- properties -----------------------------------------------------------------------------

STREAM_SETTINGS = settings(derandomize=True, database=None, deadline=None, max_examples=200,
                           suppress_health_check=[HealthCheck.too_slow])
POSE0 = (0.7, 0.0, 0.0)      # wrist 0.5 m from the shoulder, inside the annulus
coordinate = st.floats(-1.3, 1.3, allow_nan=False)
angle = st.floats(-math.pi, math.pi, allow_nan=False)
planar_pose = st.tuples(coordinate, coordinate, angle).map(np.array)
axis = st.floats(-1.0, 1.0, allow_nan=False) | st.just(math.nan)
gamepads = st.none() | st.builds(
    lambda axes, buttons: Gamepad(index=0, axes=tuple(axes), buttons=tuple(buttons)),
    st.lists(axis, min_size=0, max_size=5), st.lists(st.sampled_from([0.0, 1.0]), max_size=3))
events = st.fixed_dictionaries({
    "sliders": st.none() | planar_pose,          # None: the page's sliders as they are
    "enable": st.sampled_from([0, 0, 0, 1, 1, 2]),
    "stop": st.sampled_from([0] * 7 + [1]),
    "connections": st.sampled_from([1, 1, 1, 0]),
    "gamepad": gamepads,
    "anchor": st.none() | planar_pose,
    "hold": st.integers(1, 25),                  # steps this event lasts (clicks: the first)
})
QUIET = {"sliders": None, "enable": 0, "stop": 0, "connections": 1, "gamepad": None,
         "anchor": None, "hold": 1}
speeds = st.tuples(st.sampled_from([0.01, 0.004]), st.floats(0.01, 5.0), st.floats(0.05, 20.0),
                   st.floats(0.0, 0.5))


def run_stream(params, stream, *, anchors=True):
    """Yields (state before, inputs, state after, outputs) of every step of the stream; the
    page keeps what set_sliders puts on it until the stream moves the sliders again."""
    state = console_initial_state(params, POSE0)
    sliders = np.array(POSE0)
    enable = stop = 0
    for event in stream:
        enable += event["enable"]
        stop += event["stop"]
        if event["sliders"] is not None:
            sliders = event["sliders"].copy()
        for _ in range(event["hold"]):
            inputs = ConsoleInputs(
                sliders=sliders.copy(), enable_clicks=enable, stop_clicks=stop,
                gamepad=Gamepad() if event["gamepad"] is None else event["gamepad"],
                connections=event["connections"],
                anchor_pose=event["anchor"] if anchors else None)
            new, out = console_step(params, state, inputs)
            yield state, inputs, new, out
            if out.set_sliders is not None:
                sliders = out.set_sliders.copy()
            state = new


def make_params(speed, saturate=None):
    period, linear, angular, deadzone = speed
    return console_params(PLANAR, period_s=period, max_speed_m_per_s=linear,
                          max_angular_speed_rad_per_s=angular, gamepad_deadzone=deadzone,
                          saturate=saturate)


@STREAM_SETTINGS
@given(stream=st.lists(events, min_size=1, max_size=10), speed=speeds,
       saturated=st.booleans())
def test_property_the_clutch_and_the_stop(stream, speed, saturated):
    # Catches: any path that moves the published pose with the clutch released (a stop step,
    # a lost browser, a lost gamepad, clicks with no browser), a stop with the clutch engaged,
    # outputs that differ from the new state.
    params = make_params(speed, reach_saturation("air_bearing_arm") if saturated else None)
    for before, inputs, after, out in run_stream(params, stream):
        assert not (out.stop and out.enable)
        if not out.enable:
            np.testing.assert_array_equal(out.pose, before.pose)
            if before.stop:          # the stop holds until the operator engages
                assert out.stop
        assert out.stop == after.stop and out.enable == after.enabled
        np.testing.assert_array_equal(out.pose, after.pose)
        if out.stop:
            assert after.notice is ConsoleNotice.STOPPED
        if out.enable:
            assert inputs.connections > 0 and after.notice is ConsoleNotice.NONE


@STREAM_SETTINGS
@given(stream=st.lists(events, min_size=1, max_size=10), speed=speeds,
       saturated=st.booleans())
def test_property_the_hand_never_moves_faster_than_the_limits(stream, speed, saturated):
    # Catches: a dropped speed limit, a per-coordinate position clip (√2 too fast on a
    # diagonal), a gamepad rate that bypasses the limit, a jump on engaging; the one allowed
    # jump, re-anchoring after a stop, goes to the anchor and at most one step from it.
    params = make_params(speed, reach_saturation("air_bearing_arm") if saturated else None)
    linear_limit = params.max_speed_m_per_s * params.period_s
    angular_limit = params.max_angular_speed_rad_per_s * params.period_s
    for before, inputs, _after, out in run_stream(params, stream):
        start = before.pose
        if before.stop and out.enable and inputs.anchor_pose is not None:
            start = inputs.anchor_pose       # re-anchored, then at most one step (the sticks)
            if params.saturate is not None:  # an anchor beyond the reach is put on its edge
                start = params.saturate(start)[0]
        move = out.pose - start
        assert np.linalg.norm(move[:2]) <= linear_limit + 1e-12
        assert abs(move[2]) <= angular_limit + 1e-12


@STREAM_SETTINGS
@given(stream=st.lists(events, min_size=1, max_size=10), speed=speeds,
       saturated=st.booleans())
def test_property_the_state_round_trips_through_the_codec_and_the_step_is_pure(
        stream, speed, saturated):
    # Catches: a state field the codec cannot carry exactly (e.g. a notice that comes back
    # an int, a bool array that comes back floats), a step that writes into its arguments
    # (the Drake system's state vector would change outside its update).
    params = make_params(speed, reach_saturation("air_bearing_arm") if saturated else None)
    codec = VectorCodec(console_initial_state(params, POSE0))
    for before, inputs, after, _out in run_stream(params, stream):
        frozen = codec.pack(before)
        again = codec.unpack(codec.pack(after))
        assert type(again) is ConsoleState
        for name, value in after._asdict().items():
            back = getattr(again, name)
            if isinstance(value, np.ndarray):
                assert back.dtype == value.dtype and np.array_equal(back, value), name
            else:
                assert type(back) is type(value) and back == value, name
        # Replaying the step leaves its arguments as they were.
        sliders = inputs.sliders.copy()
        console_step(params, before, inputs)
        np.testing.assert_array_equal(codec.pack(before), frozen)
        np.testing.assert_array_equal(inputs.sliders, sliders)


@STREAM_SETTINGS
@given(stream=st.lists(events, min_size=1, max_size=10), speed=speeds)
def test_property_the_wanted_pose_is_always_within_the_reach(stream, speed):
    # Catches: a saturation skipped on one of the paths that change the wanted pose (a slider
    # move, the sticks, engaging, re-anchoring outside the annulus).
    params = make_params(speed, reach_saturation("air_bearing_arm"))
    for _before, _inputs, after, _out in run_stream(params, stream):
        if after.enabled:
            assert INNER - 1e-12 <= wrist_radius(after.wanted) <= OUTER + 1e-12


@settings(STREAM_SETTINGS, phases=[Phase.explicit, Phase.generate])   # no shrinking
@given(stream=st.lists(events, min_size=1, max_size=10), speed=speeds)
# Hypothesis mixes the constants of the loaded modules into what it draws, so whether its own
# streams find the defect depends on which test files are collected; this one always does:
# engage, then the slider across the shoulder at 5 m/s.
@example(stream=[QUIET | {"enable": 1}, QUIET | {"sliders": np.array([-0.3, 0.0, 0.0]),
                                               "hold": 25}],
         speed=(0.01, 5.0, 0.2, 0.1))
def test_property_every_published_pose_is_within_the_reach(stream, speed):
    # Catches: a console that saturates only the wanted pose and not the path to it.
    params = make_params(speed, reach_saturation("air_bearing_arm"))
    for _before, _inputs, _after, out in run_stream(params, stream, anchors=False):
        if out.enable:
            assert INNER - 1e-12 <= wrist_radius(out.pose) <= OUTER + 1e-12


def test_a_slider_taken_across_the_shoulder_stops_the_wrist_at_the_rim_and_says_so():
    # Catches: the published wrist taken through the shoulder (r → 0 m, 4.4 s below the reach
    # at the deployed 0.05 m/s before the fix), a hand that stops without the reach warning,
    # or one that cannot leave the rim when the operator goes round.
    # Wrist from (0.5, 0) to (−0.5, 0) with φ = 0: both ends are inside the annulus, the
    # straight way between them is not.
    page = engaged_page((0.7, 0.0, 0.0), saturate=reach_saturation("air_bearing_arm"))
    page.step(sliders=[-0.3, 0.0, 0.0])
    radii = [wrist_radius(page.step().pose) for _ in range(2100)]
    assert min(radii) >= INNER - 1e-12
    # Held at the rim on the wrist's ray (0.5 − INNER m away at 0.5 mm a step), warned.
    np.testing.assert_allclose(page.state.pose, [INNER + 0.2, 0.0, 0.0], rtol=0, atol=1e-12)
    assert page.state.saturated
    # Going round: with the slider to the side the hand slides along the rim (warned) until
    # the straight way is clear, then moves on to the wanted pose.
    page.step(sliders=[-0.3, 0.6, 0.0])
    radii = [wrist_radius(page.step().pose) for _ in range(2000)]
    assert min(radii) >= INNER - 1e-12
    np.testing.assert_array_equal(page.state.pose, [-0.3, 0.6, 0.0])
    assert not page.state.saturated


def test_an_enable_click_as_the_gamepad_vanishes_keeps_the_stop_or_engages():
    # Catches rules applied in an order that leaves a half-done engagement when the Enable click
    # and the pad's loss arrive in one tick (the properties above cover this step too).
    page = planar_page()
    page.gamepad = pad(buttons=(1.0, 0.0))
    assert page.step().enable                       # engaged with the pad's button 0
    page.gamepad = pad(buttons=(0.0, 1.0))
    assert page.step().stop                         # stopped with its button 1
    page.gamepad = Gamepad()                        # the pad goes as the mouse clicks Enable
    out = page.step(enable=1, anchor=[0.6, 0.1, 0.2])
    if not out.enable:
        assert out.stop
        np.testing.assert_array_equal(out.pose, [0.5, 0.0, 0.0])
