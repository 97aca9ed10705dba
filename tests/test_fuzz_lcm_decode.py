"""Property-based fuzzing of the generated LCM types' decoders, through ``decode_exact``.

The contract, the conventions and the shared generators: tests/fuzz_helpers.py (a bad
input gets a clear ValueError or a held, flagged output; never another exception; what was
accepted is not altered).
"""

from __future__ import annotations

import struct

import pytest
from fuzz_helpers import (
    DECODE_ERRORS,
    LCM_TYPES,
    _decode,
    fuzz,
    lcm_messages,
)
from hypothesis import assume, given
from hypothesis import strategies as st

# ======================================================================================
# LCM decoding
# ======================================================================================


@fuzz(200)
@given(msg=lcm_messages())
def test_lcm_valid_messages_round_trip_bit_exactly(msg):
    data = msg.encode()
    decoded = type(msg).decode(data)
    assert decoded.encode() == data


@fuzz(200)
@given(lcm_type=st.sampled_from(LCM_TYPES), blob=st.binary(max_size=200))
def test_lcm_random_bytes_raise_decode_error(lcm_type, blob):
    assume(blob[:8] != lcm_type._get_packed_fingerprint())
    with pytest.raises(ValueError, match="^Decode error$") as info:
        lcm_type.decode(blob)
    assert type(info.value) is ValueError


@fuzz(300)
@given(lcm_type=st.sampled_from(LCM_TYPES), body=st.one_of(
    st.binary(max_size=200),
    # Headers with extreme counts/lengths, to look for hangs or huge allocations.
    st.builds(lambda head, count, tail: head + struct.pack(">i", count) + tail,
              st.binary(min_size=12, max_size=20), st.sampled_from([-1, -2**31, 2**31 - 1,
                                                                    2**30, 7]),
              st.binary(max_size=40)),
))
def test_lcm_fingerprint_then_garbage_raises_only_decode_errors(lcm_type, body):
    _decode(lcm_type, lcm_type._get_packed_fingerprint() + body)


@fuzz(150)
@given(msg=lcm_messages(), data=st.data())
def test_lcm_every_truncation_is_refused(msg, data):
    encoded = msg.encode()
    cut = data.draw(st.integers(0, len(encoded) - 1))
    result = _decode(type(msg), encoded[:cut])
    assert isinstance(result, DECODE_ERRORS), f"a {cut}/{len(encoded)}-byte prefix decoded"


@fuzz(300)
@given(msg=lcm_messages(), data=st.data())
def test_lcm_bit_flips_decode_or_raise_decode_errors(msg, data):
    encoded = bytearray(msg.encode())
    flips = data.draw(st.lists(st.integers(0, 8 * len(encoded) - 1), min_size=1, max_size=4))
    for bit in flips:
        encoded[bit // 8] ^= 1 << (bit % 8)
    result = _decode(type(msg), bytes(encoded))
    if bytes(encoded[:8]) != type(msg)._get_packed_fingerprint():
        assert type(result) is ValueError and str(result) == "Decode error"
