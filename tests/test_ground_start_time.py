"""When the ground process starts its clock (scripts/processes.py: ground_start_time).

The robot polls at whole multiples of its poll period on its own clock; ``clock_offset_s``
maps that clock onto ``time.monotonic()`` (monotonic = robot + offset). A packet published
``publish_offset_s`` after a ground tick (ticks at start + k·0.25 s) must reach the robot
half a poll before its next poll. Oracle, from that statement alone:

    (start + publish_offset − clock_offset) mod poll = poll / 2,

start in [now + poll, now + 2·poll) (the first such instant at least one poll ahead), and
``now`` itself when the robot's clock is unknown (NaN offset).
"""

import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from telesmooth.diagrams.scenario import LoadScenario
from telesmooth.scripts.processes import RobotTelemetry, ground_start_time


def _telemetry(offset):
    return RobotTelemetry(pose=np.zeros(3), onboard_epoch=1, last_session=0,
                          clock_offset_s=offset)


def _scenario(poll, publish_offset):
    return SimpleNamespace(command_receiver=SimpleNamespace(poll_period_s=poll),
                           publish_offset_s=publish_offset)


def _phase_error(start, poll, publish_offset, offset):
    """Distance, on the circle of one poll, of the packet's arrival (robot clock) from the
    middle between two polls."""
    arrival = start + publish_offset - offset
    residue = math.fmod(arrival - poll / 2.0, poll)
    return min(abs(residue), poll - abs(residue))


@pytest.mark.parametrize("now, offset, poll, publish_offset", [
    (1000.0, 0.0, 0.01, 0.001),
    (12345.678, 37.1234567, 0.01, 0.001),
    (5.0, -3.3333, 0.01, 0.0),
    (86400.25, 2.0e4 + 0.0049, 0.02, 0.0031),
    (0.5, 0.123, 0.05, 0.007),
])
def test_packets_arrive_half_a_poll_before_the_robots_poll(now, offset, poll, publish_offset):
    # Catches: the half poll left out (packets then arrive on a poll, where timing jitter
    # splits them between two polls), the publish offset or the clock offset left out or
    # with the wrong sign, and a start less than one poll or two polls or more away.
    start = ground_start_time(_telemetry(offset), _scenario(poll, publish_offset), now=now)
    assert _phase_error(start, poll, publish_offset, offset) < 1e-9
    assert now + poll - 1e-9 <= start < now + 2 * poll


@given(now=st.floats(0.0, 1e6), offset=st.floats(-1e5, 1e5),
       poll=st.sampled_from([0.002, 0.01, 0.02, 0.05]),
       publish_offset=st.floats(0.0, 0.01))
def test_the_rule_for_any_clock(now, offset, poll, publish_offset):
    # Catches the same defects over any phase of ``now`` against the robot's polls, e.g. a
    # start that is a poll too late or too early for some phases only.
    start = ground_start_time(_telemetry(offset), _scenario(poll, publish_offset), now=now)
    # Rounding: start and now are ~1e6 s, whose floats are spaced 1.2e-10 s apart.
    assert _phase_error(start, poll, publish_offset, offset) < 1e-8
    assert now + poll - 1e-8 <= start < now + 2 * poll + 1e-8


def test_exactly_one_poll_ahead_is_taken_not_skipped():
    # Catches a ">" for ">=": when now + poll is itself such an instant it is the answer (the
    # numbers are exact in binary: the phase is 0).
    start = ground_start_time(_telemetry(0.0), _scenario(0.5, 0.25), now=10.0)
    assert start == 10.5


def test_without_the_robots_clock_it_starts_now():
    # Catches: a NaN offset turned into a NaN start (the ground would never start) or into a
    # wait of a poll or two for nothing.
    scenario = LoadScenario()
    assert ground_start_time(_telemetry(math.nan), scenario, now=321.5) == 321.5
    # ... and the built-in scenario's own periods follow the rule.
    start = ground_start_time(_telemetry(4.56789), scenario, now=321.5)
    poll = scenario.command_receiver.poll_period_s
    assert _phase_error(start, poll, scenario.publish_offset_s, 4.56789) < 1e-9
