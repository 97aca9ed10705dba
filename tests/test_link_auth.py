"""HMAC-SHA256 authentication of uplink commands and key handling (telesmooth.link.auth)."""

import hashlib
import hmac
import os
import re
import stat
import struct
import warnings

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from telesmooth.lcm_types import lcmt_teleop_joint_command
from telesmooth.link.auth import (
    AUTH_FORGED,
    AUTH_MALFORMED,
    AUTH_UNSIGNED,
    KEY_ENVIRONMENT_VARIABLE,
    MIN_KEY_BYTES,
    TAG_BYTES,
    UplinkKeyError,
    canonical_bytes,
    generate_key_file,
    load_key,
    sign,
    verify,
    verify_classified,
)

KEY = bytes(range(32))
OTHER_KEY = bytes(range(1, 33))


def _command(seq=4, session_id=1_700_000_000_123_456):
    msg = lcmt_teleop_joint_command()
    msg.utime, msg.seq, msg.sample_utime, msg.num_joints = 1_000_000, seq, 250_000, 3
    msg.joint_name = ["shoulder", "elbow", "wrist"]
    msg.joint_position_smoothed = [0.1, -0.2, 0.3]
    msg.joint_velocity_smoothed = [0.01, 0.0, -0.02]
    msg.mode = lcmt_teleop_joint_command.MODE_TRACK
    msg.session_id = session_id
    msg.onboard_epoch = 0x5DEECE66D   # covered by the tag like every other field
    return msg


def _hand_built_canonical(msg):
    """The LCM wire format written out by hand, with auth_tag_size = 0 and no tag bytes."""
    out = struct.pack(">Q", lcmt_teleop_joint_command().get_hash())   # the fingerprint
    out += struct.pack(">qiqi", msg.utime, msg.seq, msg.sample_utime, len(msg.joint_name))
    for name in msg.joint_name:
        encoded = name.encode("utf-8")
        out += struct.pack(">I", len(encoded) + 1) + encoded + b"\0"
    n = len(msg.joint_name)
    out += struct.pack(f">{n}d", *msg.joint_position_smoothed)
    out += struct.pack(f">{n}d", *msg.joint_velocity_smoothed)
    out += struct.pack(">bqqh", msg.mode, msg.session_id, msg.onboard_epoch, 0)
    return out


def _fields(msg):
    return {name: getattr(msg, name) for name in msg.__slots__}


def _same_content(a, b):
    return {k: (list(v) if isinstance(v, (list, tuple)) else v) for k, v in _fields(a).items()} \
        == {k: (list(v) if isinstance(v, (list, tuple)) else v) for k, v in _fields(b).items()}


# --- signing ----------------------------------------------------------------------------------

def test_tag_equals_an_independent_hmac_over_the_hand_built_encoding():
    msg = _command()
    signed = sign(msg, KEY)
    expected = hmac.new(KEY, _hand_built_canonical(msg), hashlib.sha256).digest()
    assert signed.auth_tag == expected
    assert signed.auth_tag_size == TAG_BYTES == 32
    assert canonical_bytes(msg) == _hand_built_canonical(msg)
    # The signed message's own encoding is the canonical one with the tag appended.
    assert signed.encode() == _hand_built_canonical(msg)[:-2] + struct.pack(">h", 32) + expected


def test_round_trip_sign_encode_decode_verify():
    signed = sign(_command(), KEY)
    received = lcmt_teleop_joint_command.decode(signed.encode())
    assert verify(received, KEY) is None
    assert verify_classified(received, KEY) == (None, None)
    # Re-signing a signed message replaces the tag with the same one.
    assert sign(received, KEY).auth_tag == signed.auth_tag


def test_sign_does_not_mutate_its_input_and_returns_an_independent_copy():
    msg = _command()
    before = msg.encode()
    names, positions = msg.joint_name, msg.joint_position_smoothed
    signed = sign(msg, KEY)
    assert msg.encode() == before and msg.auth_tag_size == 0 and msg.auth_tag == b""
    assert msg.joint_name is names and msg.joint_position_smoothed is positions
    assert signed is not msg
    signed.joint_position_smoothed[0] = 99.0
    signed.joint_name[0] = "changed"
    assert msg.encode() == before


def test_verify_does_not_mutate_its_input():
    signed = sign(_command(), KEY)
    before = signed.encode()
    verify(signed, KEY)
    verify(signed, OTHER_KEY)
    assert signed.encode() == before


@pytest.mark.parametrize("tamper", [
    lambda m: setattr(m, "seq", m.seq + 1),
    lambda m: setattr(m, "session_id", m.session_id + 1),
    lambda m: setattr(m, "utime", m.utime + 1),
    lambda m: setattr(m, "sample_utime", m.sample_utime - 1),
    lambda m: setattr(m, "mode", lcmt_teleop_joint_command.MODE_HOLD),
    lambda m: m.joint_position_smoothed.__setitem__(1, -0.2 + 1e-12),
    lambda m: m.joint_velocity_smoothed.__setitem__(2, 0.0),
    lambda m: m.joint_name.__setitem__(1, "elbow2"),
], ids=["seq", "session_id", "utime", "sample_utime", "mode", "position", "velocity",
        "joint_name"])
def test_changing_any_field_after_signing_is_detected(tamper):
    signed = sign(_command(seq=7, session_id=123), KEY)
    tamper(signed)
    cls, reason = verify_classified(signed, KEY)
    assert cls == AUTH_FORGED
    assert reason.startswith("HMAC mismatch (forged or corrupted;")
    assert f"seq = {signed.seq}, session_id = {signed.session_id}" in reason


def test_replayed_fields_from_another_packet_do_not_verify():
    """Pasting the tag of packet 3 onto packet 4 fails: seq is covered."""
    tag_3 = sign(_command(seq=3), KEY).auth_tag
    forged = _command(seq=4)
    forged.auth_tag_size, forged.auth_tag = 32, tag_3
    assert verify_classified(forged, KEY)[0] == AUTH_FORGED


def test_wrong_key_fails():
    signed = sign(_command(), KEY)
    assert verify(signed, OTHER_KEY) == ("HMAC mismatch (forged or corrupted; seq = 4, "
                                         "session_id = 1700000000123456)")


def test_unsigned_and_malformed_tags_are_classified():
    assert verify_classified(_command(), KEY) == (AUTH_UNSIGNED, "unsigned (auth_tag_size = 0)")
    short = _command()
    short.auth_tag_size, short.auth_tag = 4, b"\0" * 4
    assert verify_classified(short, KEY) == (AUTH_MALFORMED, "auth_tag_size = 4, expected 32")
    inconsistent = sign(_command(), KEY)
    inconsistent.auth_tag = inconsistent.auth_tag[:31]
    assert verify_classified(inconsistent, KEY) == (
        AUTH_MALFORMED, "auth_tag has 31 bytes but auth_tag_size = 32")
    unencodable = sign(_command(), KEY)
    unencodable.num_joints = 5
    cls, reason = verify_classified(unencodable, KEY)
    assert cls == AUTH_MALFORMED and reason.startswith("cannot encode the message")


@pytest.mark.parametrize("key, message", [
    (b"short", "key: 5 bytes, need at least 16"),
    ("00" * 32, "key: must be bytes, got str"),
])
def test_bad_key_arguments_are_errors_not_verdicts(key, message):
    with pytest.raises(UplinkKeyError, match=re.escape(message)):
        sign(_command(), key)
    with pytest.raises(UplinkKeyError, match=re.escape(message)):
        verify(sign(_command(), KEY), key)


def _string_terminator_positions(msg):
    """Byte offsets of the NUL after each joint name in msg.encode()."""
    positions, offset = [], 8 + 24
    for name in msg.joint_name:
        offset += 4 + len(name.encode("utf-8"))
        positions.append(offset)
        offset += 1
    return positions


def _flip_outcome(encoded, position, mask, original):
    """'decode', 'verify' (a check failed), or 'same' (decoded content identical)."""
    corrupted = bytearray(encoded)
    corrupted[position] ^= mask
    try:
        received = lcmt_teleop_joint_command.decode(bytes(corrupted))
    except Exception:
        return "decode"
    if verify(received, KEY) is not None:
        return "verify"
    assert _same_content(received, original), position
    return "same"


def test_every_single_byte_flip_fails_decode_or_verify_except_ignored_terminators():
    """Exhaustive over positions. LCM's decoder drops each string's terminating byte
    unread, so flipping it decodes to the very message that was signed: those bytes (and only
    those) are not protected, and protecting them would give nothing."""
    signed = sign(_command(), KEY)
    encoded = signed.encode()
    terminators = _string_terminator_positions(signed)
    assert all(encoded[p] == 0 for p in terminators)
    for mask in (0x01, 0x80, 0xFF):
        outcomes = [_flip_outcome(encoded, p, mask, signed) for p in range(len(encoded))]
        assert [p for p, o in enumerate(outcomes) if o == "same"] == terminators
        assert "verify" in outcomes and "decode" in outcomes


@settings(max_examples=300, deadline=None)
@given(data=st.data(), mask=st.integers(1, 255), seq=st.integers(0, 2**31 - 1),
       names=st.lists(st.text(min_size=1, max_size=8), min_size=1, max_size=4))
def test_random_byte_flips_never_verify_as_a_different_message(data, mask, seq, names):
    msg = _command(seq=seq)
    msg.num_joints = len(names)
    msg.joint_name = names
    msg.joint_position_smoothed = [0.5 * i for i in range(len(names))]
    msg.joint_velocity_smoothed = [-0.1 * i for i in range(len(names))]
    signed = sign(msg, KEY)
    encoded = signed.encode()
    position = data.draw(st.integers(0, len(encoded) - 1))
    outcome = _flip_outcome(encoded, position, mask, signed)
    assert outcome in ("decode", "verify") or position in _string_terminator_positions(signed)


# --- keys -------------------------------------------------------------------------------------

def _write(path, text, mode=0o600):
    path.write_text(text)
    os.chmod(path, mode)
    return path


def test_load_key_from_file_strips_whitespace(tmp_path):
    path = _write(tmp_path / "uplink.key", "\n  " + KEY.hex() + "  \n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load_key(path, environ={}) == KEY
        assert load_key(str(path), environ={KEY_ENVIRONMENT_VARIABLE: OTHER_KEY.hex()}) == KEY


def test_load_key_from_environment():
    assert load_key(environ={KEY_ENVIRONMENT_VARIABLE: " " + KEY.hex().upper() + "\n"}) == KEY


@pytest.mark.parametrize("text, reason", [
    ("not-a-key!", "not a hex string"),
    ("abc", "not a hex string"),                      # odd number of digits
    ("", "empty"),
    ("00" * (MIN_KEY_BYTES - 1), f"key is {MIN_KEY_BYTES - 1} bytes, need at least 16"),
])
def test_key_errors_name_the_source_and_reason(tmp_path, text, reason):
    path = _write(tmp_path / "uplink.key", text)
    with pytest.raises(UplinkKeyError,
                       match=re.escape(f"uplink key file {str(path)!r}: {reason}")):
        load_key(path)
    with pytest.raises(UplinkKeyError, match=re.escape(
            f"environment variable {KEY_ENVIRONMENT_VARIABLE}: {reason}")):
        load_key(environ={KEY_ENVIRONMENT_VARIABLE: text})


def test_key_errors_do_not_echo_key_material(tmp_path):
    secret = KEY.hex()[:-1] + "z"   # almost a key
    with pytest.raises(UplinkKeyError) as error:
        load_key(environ={KEY_ENVIRONMENT_VARIABLE: secret})
    assert secret not in str(error.value) and KEY.hex()[:16] not in str(error.value)


def test_missing_key_names_the_variable_and_the_file(tmp_path):
    with pytest.raises(UplinkKeyError, match=f"{KEY_ENVIRONMENT_VARIABLE} is not set"):
        load_key(environ={})
    missing = tmp_path / "nope.key"
    with pytest.raises(UplinkKeyError, match=re.escape(f"uplink key file {str(missing)!r}: "
                                                       "cannot read it")):
        load_key(missing)
    assert issubclass(UplinkKeyError, ValueError)


@pytest.mark.skipif(os.name != "posix", reason="POSIX permissions")
@pytest.mark.parametrize("mode", [0o644, 0o640, 0o604, 0o660, 0o602, 0o620, 0o601])
def test_key_file_accessible_to_others_is_refused_with_the_chmod_that_fixes_it(tmp_path, mode):
    # As ssh refuses a private key others can read or write: a warning scrolls away, and a
    # key others could have changed authenticates nothing.
    path = _write(tmp_path / "uplink.key", KEY.hex(), mode)
    with pytest.raises(UplinkKeyError) as error:
        load_key(path)
    message = str(error.value)
    assert f"mode {mode:#o}" in message and f"chmod 600 {path}" in message
    assert KEY.hex() not in message and KEY.hex()[:16] not in message
    os.chmod(path, 0o600)
    assert load_key(path) == KEY


def test_a_hex_key_given_as_the_key_file_is_not_echoed(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(UplinkKeyError) as error:
        load_key(KEY.hex())
    message = str(error.value)
    assert "hex string" in message and "not shown" in message
    assert KEY.hex()[:16] not in message and KEY.hex()[-16:] not in message


@pytest.mark.parametrize("special", ["/dev/zero", "/dev/urandom", "fifo"])
def test_a_key_file_that_never_ends_is_refused_before_reading(tmp_path, special):
    path = special
    if special == "fifo":
        path = tmp_path / "fifo"
        os.mkfifo(path)
    with pytest.raises(UplinkKeyError, match="is a (character device|FIFO)"):
        load_key(path)


def test_a_key_file_larger_than_the_bound_is_refused(tmp_path):
    from telesmooth.user_input import MAX_KEY_FILE_BYTES

    path = _write(tmp_path / "big.key", KEY.hex() + " " * MAX_KEY_FILE_BYTES)
    with pytest.raises(UplinkKeyError, match="limit is 4 KiB"):
        load_key(path)


def test_generate_key_file_writes_a_fresh_private_key_and_refuses_to_overwrite(tmp_path):
    path = tmp_path / "uplink.key"
    old_umask = os.umask(0)   # even a permissive umask gives 0o600
    try:
        key = generate_key_file(path)
    finally:
        os.umask(old_umask)
    assert len(key) == 32
    assert path.read_text() == key.hex() + "\n"
    if os.name == "posix":
        assert stat.S_IMODE(path.stat().st_mode) == 0o600
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert load_key(path) == key
    with pytest.raises(UplinkKeyError, match="exists .a file.; refusing to overwrite"):
        generate_key_file(path)
    assert path.read_text() == key.hex() + "\n"
    assert generate_key_file(tmp_path / "second.key") != key   # random, not fixed
    assert sorted(p.name for p in tmp_path.iterdir()) == ["second.key", "uplink.key"]


def test_generate_key_file_makes_missing_folders_private(tmp_path):
    path = tmp_path / "home" / ".telesmooth" / "uplink.key"
    key = generate_key_file(path)
    assert load_key(path) == key
    for folder in (tmp_path / "home", tmp_path / "home" / ".telesmooth"):
        assert stat.S_IMODE(folder.stat().st_mode) == 0o700


@pytest.mark.parametrize("where", ["folder", "parent-file", "fifo"])
def test_generate_key_file_refuses_what_is_in_the_way(tmp_path, where):
    (tmp_path / "file").write_text("keep")
    path = {"folder": tmp_path, "parent-file": tmp_path / "file" / "uplink.key",
            "fifo": tmp_path / "fifo"}[where]
    if where == "fifo":
        os.mkfifo(path)
    with pytest.raises(UplinkKeyError, match="exists|is a file, not a folder"):
        generate_key_file(path)
    assert (tmp_path / "file").read_text() == "keep"
