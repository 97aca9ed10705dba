"""LCM types: committed code matches lcm-gen, every field round-trips, bad bytes are refused."""

import struct

import pytest

from telesmooth.lcm_types import (
    lcmt_onboard_joint_status,
    lcmt_teleop_collision_event,
    lcmt_teleop_haptic_command,
    lcmt_teleop_joint_command,
)
from telesmooth.lcm_types.generate import DEFINITIONS_DIRECTORY, generate


def test_committed_code_equals_a_fresh_lcm_gen_run(tmp_path):
    fresh = generate(tmp_path)
    committed = DEFINITIONS_DIRECTORY / "telesmooth_lcmt"
    fresh_files = sorted(p.name for p in fresh.glob("*.py"))
    assert fresh_files == sorted(p.name for p in committed.glob("*.py"))
    for name in fresh_files:
        assert (fresh / name).read_text() == (committed / name).read_text(), name


def _haptic():
    msg = lcmt_teleop_haptic_command()
    msg.utime, msg.seq, msg.num_axes = 123456, 7, 3
    msg.pose_desired = [0.7, -0.1, 0.25]
    msg.enable = True
    return msg


def _command():
    msg = lcmt_teleop_joint_command()
    msg.utime, msg.seq, msg.sample_utime, msg.num_joints = 1_000_000, 4, 250_000, 3
    msg.joint_name = ["shoulder", "elbow", "wrist"]
    msg.joint_position_smoothed = [0.1, -0.2, 0.3]
    msg.joint_velocity_smoothed = [0.01, 0.0, -0.02]
    msg.mode = lcmt_teleop_joint_command.MODE_HOLD
    msg.session_id = 1_790_000_000_000_000
    msg.auth_tag = bytes(range(32))
    msg.auth_tag_size = 32
    return msg


def _status():
    msg = lcmt_onboard_joint_status()
    msg.utime, msg.seq, msg.num_joints = 42, 9, 2
    msg.joint_position_link = [0.5, 0.25]
    msg.joint_position_motor = [0.51, 0.24]
    msg.tool_position_measured = [1.0, 0.0, 0.45]
    msg.last_command_seq, msg.command_rejected, msg.command_timeout = -1, False, True
    msg.last_command_session_id = 1_790_000_000_000_000
    msg.joint_position_commanded = [0.49, 0.26]
    msg.sample_utime = 32
    msg.joint_velocity_link, msg.joint_velocity_motor = [0.01, -0.02], [0.011, -0.019]
    msg.guard_mode = 1
    (msg.accepted_count, msg.rejected_invalid_count, msg.rejected_auth_count,
     msg.dropped_duplicate_count, msg.dropped_stale_count, msg.undecodable_count) = range(6)
    return msg


def _event():
    msg = lcmt_teleop_collision_event()
    msg.utime, msg.seq = 5, 6
    msg.collision_detected, msg.holding, msg.min_distance_m = True, True, -0.003
    return msg


@pytest.mark.parametrize("factory", [_haptic, _command, _status, _event])
def test_every_field_round_trips(factory):
    msg = factory()
    decoded = type(msg).decode(msg.encode())
    for field in msg.__slots__:
        original, copy = getattr(msg, field), getattr(decoded, field)
        if isinstance(original, (list, tuple)):
            assert list(copy) == list(original), field
        else:
            assert copy == original, field


def test_wrong_type_and_truncated_bytes_are_refused():
    data = _command().encode()
    with pytest.raises(ValueError, match="Decode error"):
        lcmt_onboard_joint_status.decode(data)
    with pytest.raises(struct.error):
        lcmt_teleop_joint_command.decode(data[:-50])   # cut inside the doubles


def test_a_truncated_auth_tag_decodes_short_and_fails_verification():
    # lcm-gen's Python reads a byte array with buf.read(n), which returns what is left: a
    # packet cut inside its tag still decodes, with a tag shorter than auth_tag_size. The
    # receiver's HMAC check refuses it.
    from telesmooth.link.auth import verify
    data = _command().encode()
    short = lcmt_teleop_joint_command.decode(data[:-5])
    assert short.auth_tag_size == 32 and len(short.auth_tag) == 27
    assert verify(short, b"k" * 32) is not None


def test_count_mismatch_cannot_be_encoded():
    msg = _command()
    msg.num_joints = 4
    with pytest.raises((struct.error, IndexError, ValueError)):
        msg.encode()


def test_fingerprints_are_distinct():
    prints = {t._get_packed_fingerprint() for t in (lcmt_onboard_joint_status,
              lcmt_teleop_collision_event, lcmt_teleop_haptic_command, lcmt_teleop_joint_command)}
    assert len(prints) == 4
