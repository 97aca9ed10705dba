"""The robot's telemetry as the ground logs it (systems/joint_status_decoder.py).

Oracle: a hand-made ``lcmt_onboard_joint_status`` whose every field holds a distinct value,
and the vector written out here position by position from the documented order (time in s,
seq, last command seq, guard mode, stream distance, q_link, q_motor, tool position,
q_commanded), independently of ``telemetry_layout``.
"""

import numpy as np
import pytest

from telesmooth.lcm_types import lcmt_onboard_joint_status
from telesmooth.systems.joint_status_decoder import (
    TELEMETRY_FIELDS,
    JointStatusDecoder,
    telemetry_layout,
    telemetry_vector,
)


def _message(num_joints=3):
    msg = lcmt_onboard_joint_status()
    msg.utime = 12_345_678           # 12.345678 s
    msg.seq = 41
    msg.num_joints = num_joints
    msg.joint_position_link = [0.11, 0.12, 0.13][:num_joints]
    msg.joint_position_motor = [0.21, 0.22, 0.23][:num_joints]
    msg.tool_position_measured = [1.5, -2.5, 3.5]
    msg.last_command_seq = 17
    msg.last_command_session_id = 99          # not part of the vector
    msg.joint_position_commanded = [0.31, 0.32, 0.33][:num_joints]
    msg.guard_mode = 3
    msg.accepted_count = 18
    msg.onboard_epoch = 5
    msg.stream_distance_rad = 0.004
    msg.joint_velocity_link = [0.5, 0.6, 0.7][:num_joints]     # not part of the vector
    msg.joint_velocity_motor = [0.8, 0.9, 1.0][:num_joints]
    return msg


EXPECTED = [12.345678, 41, 17, 3, 0.004,
            0.11, 0.12, 0.13,       # q_link
            0.21, 0.22, 0.23,       # q_motor
            1.5, -2.5, 3.5,         # tool position
            0.31, 0.32, 0.33]       # q_commanded


def test_every_field_where_the_layout_says():
    # Catches: fields swapped (q_link and q_motor, seq and last_command_seq), the time left in
    # microseconds, a layout whose slices overlap or skip a position, or the tool's 3 values
    # sized by the joint count.
    vector = telemetry_vector(_message(), 3)
    np.testing.assert_allclose(vector, EXPECTED, rtol=0, atol=1e-15)
    layout = telemetry_layout(3)
    assert list(layout) == list(TELEMETRY_FIELDS)
    hand = {"utime_s": (0, 1), "seq": (1, 2), "last_command_seq": (2, 3), "guard_mode": (3, 4),
            "stream_distance_rad": (4, 5), "q_link": (5, 8), "q_motor": (8, 11),
            "tool_position": (11, 14), "q_commanded": (14, 17)}
    assert {name: (s.start, s.stop) for name, s in layout.items()} == hand
    assert telemetry_layout(6)["q_commanded"] == slice(20, 26)      # ends at 3J + 8, J = 6
    # The decoded bytes of a real message give the same vector.
    decoded = lcmt_onboard_joint_status.decode(_message().encode())
    np.testing.assert_array_equal(telemetry_vector(decoded, 3), vector)


@pytest.mark.parametrize("message, joints", [
    (_message(2), 3),                          # another arm's message
    (_message(3), 2),
    (lcmt_onboard_joint_status(), 3),          # the default: nothing arrived yet
])
def test_a_message_of_another_arm_or_none_reads_as_nan(message, joints):
    # Catches: a value invented from a message that does not fit (zeros, or the first
    # joints of a longer message), and the default message's utime 0 / seq 0 read as data.
    vector = telemetry_vector(message, joints)
    assert vector.shape == (3 * joints + 8,)
    assert np.all(np.isnan(vector))


def test_the_system_outputs_the_vector_of_its_input():
    # Catches: an output port sized or filled differently from telemetry_vector, or one that
    # does not follow its input (state instead of direct feedthrough).
    decoder = JointStatusDecoder(num_joints=3)
    context = decoder.CreateDefaultContext()
    port = decoder.get_telemetry_output_port()
    assert port.size() == 17
    decoder.get_lcm_message_input_port().FixValue(context, lcmt_onboard_joint_status())
    assert np.all(np.isnan(port.Eval(context)))         # the default message
    decoder.get_lcm_message_input_port().FixValue(context, _message())
    np.testing.assert_allclose(port.Eval(context), EXPECTED, rtol=0, atol=1e-15)
    assert decoder.HasDirectFeedthrough(0, 0)
    with pytest.raises(ValueError, match="num_joints"):
        JointStatusDecoder(num_joints=0)
