"""LCM message types of the ground/onboard split.

The ``*.lcm`` files here are the definitions; ``telesmooth_lcmt/`` is the Python code
generated from them by the ``lcm-gen`` shipped with the ``lcm`` package. Regenerate after
changing a definition with ``python -m telesmooth.lcm_types.generate`` (a test checks the
committed code matches). Import the types from here:

    from telesmooth.lcm_types import lcmt_teleop_joint_command

Received bytes are decoded with :func:`decode_exact`, never with the generated ``decode``
alone: lcm-gen's decoders accept some damaged packets (a byte array cut short by a
truncated datagram decodes short; a string's terminator is not checked).
"""

from telesmooth.lcm_types.telesmooth_lcmt import (
    lcmt_onboard_joint_status,
    lcmt_teleop_collision_event,
    lcmt_teleop_haptic_command,
    lcmt_teleop_joint_command,
)

__all__ = [
    "decode_exact",
    "lcmt_onboard_joint_status",
    "lcmt_teleop_collision_event",
    "lcmt_teleop_haptic_command",
    "lcmt_teleop_joint_command",
]


class _ExactReader:
    """A read() for the generated decoders that refuses to read past the end (the decoders
    themselves accept a short read for a byte array)."""

    def __init__(self, data: bytes):
        self._data = data
        self.position = 0

    def read(self, size: int) -> bytes:
        if size < 0 or self.position + size > len(self._data):
            raise ValueError(f"Decode error: {len(self._data)} bytes end inside a field (it "
                             f"needs {size} bytes at offset {self.position})")
        chunk = self._data[self.position:self.position + size]
        self.position += size
        return chunk


def decode_exact(lcm_type, data: bytes):
    """Decodes ``data`` as ``lcm_type``, refusing what the generated ``decode`` lets through:
    a packet cut short inside a byte array (which would decode short), bytes after the
    message, and anything that does not encode back to exactly ``data`` (a damaged string
    terminator, invalid UTF-8 in a string).

    Raises:
        ValueError: ``"Decode error"`` (the generated decoder's message) for a wrong type
            fingerprint, or ``"Decode error: …"`` saying what is wrong.
    """
    data = bytes(data)
    reader = _ExactReader(data)
    msg = lcm_type.decode(reader)
    if reader.position != len(data):
        raise ValueError(f"Decode error: {len(data) - reader.position} bytes after the "
                         f"{reader.position}-byte message")
    try:
        again = msg.encode()
    except Exception as error:  # noqa: BLE001 - e.g. an array shorter than its size field
        raise ValueError(f"Decode error: the decoded message does not encode "
                         f"({type(error).__name__}: {error})") from None
    if again != data:
        raise ValueError("Decode error: the packet does not encode back to itself (a damaged "
                         "string or terminator)")
    return msg
