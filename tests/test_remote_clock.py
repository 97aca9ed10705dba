"""The operator process's estimate of the robot's clock (systems/robot_predictor.py:
RemoteClock, and RobotPredictor's local time): hand-made telemetry and packets with known
clocks. Each test's comment says which wrong implementation it catches."""

import numpy as np
import pytest

from telesmooth.systems.robot_predictor import RemoteClock, RobotPredictor, TelemetrySample

POLL, PUBLISH, BATCH = 0.01, 0.001, 0.04


def sample(*, sent, arrival, last_seq):
    q = np.zeros(3)
    return TelemetrySample(sample_t_s=sent - PUBLISH, sent_t_s=sent, arrival_t_s=arrival,
                           q_link=q, q_motor=q, v_link=q, v_motor=q,
                           tool_position_m=np.zeros(3), guard_mode=0,
                           stream_distance_rad=0.0, last_command_seq=last_seq, q_commanded=q)


def test_the_robots_clock_against_the_consoles_is_the_median_plus_half_a_batch():
    # Catches: the mean (one late batch drags it), the newest offset only, no half batch.
    clock = RemoteClock(poll_period_s=POLL, publish_offset_s=PUBLISH, batch_period_s=BATCH)
    assert not clock.ready()
    # The robot's clock reads 100 s more than the console's; batches taken 5, 15, 12 ms after
    # their newest message was sent, and one 400 ms late (a busy console).
    for k, wait in enumerate((0.005, 0.015, 0.012, 0.400, 0.008)):
        clock.newest(sample(sent=100.0 + k, arrival=float(k) + wait, last_seq=-1))
    # Offsets 100 − wait: median of (5, 15, 12, 400, 8) ms is 12 ms.
    assert clock.robot_minus_local == pytest.approx(100.0 - 0.012 + 0.5 * BATCH, abs=1e-12)
    assert clock.now(3.0) == pytest.approx(103.0 - 0.012 + 0.02, abs=1e-12)


def test_a_packets_delivery_is_the_median_acceptance_less_half_a_poll():
    # Catches: the smallest offset (a ground that ran late and caught up stamped one packet
    # 0.12 s early: the copy's commands then ran that much ahead of the robot's), no half
    # poll, an acceptance taken from the sample's instant instead of its message's.
    clock = RemoteClock(poll_period_s=POLL, publish_offset_s=PUBLISH, batch_period_s=BATCH)
    # Ground clock + 2.89 s = the robot's, packet 3 stamped 0.12 s late.
    for seq in range(5):
        ground_t = 0.25 * seq + (0.12 if seq == 3 else 0.0)
        clock.packet(seq, ground_t)
        accepted = 0.25 * seq + 2.89
        # The first telemetry naming it leaves publish_offset after the accepting poll.
        clock.telemetry(sample(sent=accepted + PUBLISH, arrival=0.0, last_seq=seq))
    # Acceptance − send: 2.89 four times and 2.77 once; median 2.89, less half a poll.
    assert clock.robot_minus_ground == pytest.approx(2.89 - 0.005, abs=1e-12)
    assert clock.send_time(10.0) == pytest.approx(12.885, abs=1e-12)
    # A later message naming an already accepted packet does not count it again.
    clock.telemetry(sample(sent=50.0, arrival=0.0, last_seq=4))
    assert clock.robot_minus_ground == pytest.approx(2.885, abs=1e-12)


def test_a_packet_heard_before_its_acceptance_is_matched_when_the_telemetry_names_it():
    # Catches: a match made only in one order (the packet first, or the telemetry first).
    clock = RemoteClock(poll_period_s=POLL, publish_offset_s=PUBLISH, batch_period_s=BATCH)
    clock.telemetry(sample(sent=5.001 + PUBLISH, arrival=0.0, last_seq=7))
    assert clock.robot_minus_ground is None
    clock.packet(7, 2.0)
    assert clock.robot_minus_ground == pytest.approx(3.001 - 0.005, abs=1e-12)


class WallClock:
    def __init__(self, *instants):
        self.instants = list(instants)

    def __call__(self):
        return self.instants.pop(0)


def test_with_a_wall_clock_the_local_time_follows_it_not_the_simulated_time():
    # Catches: the simulated time used in a live process (it lags the wall clock by however
    # late the process runs, and the robot's clock estimated against it then drifts with
    # the lateness), or a wall clock not counted from the first update's simulated time.
    predictor = RobotPredictor(lambda start: None, num_joints=3, remote=True,
                               wall_clock=WallClock(1000.0, 1000.5, 1001.0))
    context = predictor.CreateDefaultContext()
    context.SetTime(2.0)
    assert predictor._local_time(context) == 2.0         # the first: the simulated time
    context.SetTime(2.2)                                  # the process ran 0.3 s late
    assert predictor._local_time(context) == 2.5
    context.SetTime(3.0)                                  # and caught up
    assert predictor._local_time(context) == 3.0
    plain = RobotPredictor(lambda start: None, num_joints=3, remote=True)
    context = plain.CreateDefaultContext()
    context.SetTime(2.2)
    assert plain._local_time(context) == 2.2
