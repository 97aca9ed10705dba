"""HMAC-SHA256 authentication of uplink commands (``lcmt_teleop_joint_command``).

The ground process signs every command with a key shared with the onboard process; the
onboard process rejects commands that are unsigned, malformed or whose tag does not match
(forged, or corrupted on the link). The tag is

    auth_tag = HMAC-SHA256(key, encode(msg with auth_tag_size = 0, auth_tag = b""))

i.e. over the LCM fingerprint and every other field, ``seq`` and ``session_id`` included, so
a replayed packet carries a valid tag but an old ``(session_id, seq)``, which the onboard
side's ordering check rejects. Authentication does not encrypt: the commands stay readable.

The receiver recomputes the tag from the *decoded* message, so the tag protects exactly what
the decoder reads. LCM's decoder skips the terminating byte of each string unread; a
corrupted terminator therefore still verifies, but decodes to the very message that was
signed.

Keys are at least :data:`MIN_KEY_BYTES` bytes, stored as a hex string in a file readable by
its owner only (:func:`generate_key_file`; :func:`load_key` refuses a file others can access)
or in the environment variable :data:`KEY_ENVIRONMENT_VARIABLE`. Error messages name where a
key came from and what is wrong with it, but never contain key material.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import re
import secrets
import shlex
import stat
from collections.abc import Mapping
from pathlib import Path

from telesmooth.atomic_files import create_new_file
from telesmooth.user_input import MAX_KEY_FILE_BYTES, quote_path, read_file_bytes

__all__ = [
    "AUTH_CLASSES",
    "AUTH_FORGED",
    "AUTH_MALFORMED",
    "AUTH_UNSIGNED",
    "GENERATED_KEY_BYTES",
    "KEY_ENVIRONMENT_VARIABLE",
    "MIN_KEY_BYTES",
    "TAG_BYTES",
    "UplinkKeyError",
    "canonical_bytes",
    "check_key",
    "compute_tag",
    "generate_key_file",
    "load_key",
    "sign",
    "verify",
    "verify_classified",
]

KEY_ENVIRONMENT_VARIABLE = "TELESMOOTH_UPLINK_KEY"
"""Environment variable holding the uplink key as a hex string."""

MIN_KEY_BYTES = 16
"""Shortest accepted key, bytes (128 bits)."""

GENERATED_KEY_BYTES = 32
"""Length of the keys made by :func:`generate_key_file`, bytes (256 bits, the HMAC-SHA256
block-size sweet spot)."""

TAG_BYTES = 32
"""Length of an HMAC-SHA256 tag, bytes (``auth_tag_size`` of a signed message)."""

AUTH_UNSIGNED = "unsigned"
"""Rejection class: the message carries no tag (``auth_tag_size = 0``)."""

AUTH_MALFORMED = "malformed"
"""Rejection class: the tag has the wrong size or the message cannot be encoded."""

AUTH_FORGED = "forged"
"""Rejection class: the tag does not match (wrong key, forged, or corrupted in transit)."""

AUTH_CLASSES = (AUTH_UNSIGNED, AUTH_MALFORMED, AUTH_FORGED)
"""Every rejection class of :func:`verify_classified`, e.g. to initialise counters."""


class UplinkKeyError(ValueError):
    """The uplink key is missing, unreadable, not hex or too short (message names the source)."""


_KEY_LIKE = re.compile(rf"[0-9a-fA-F]{{{2 * MIN_KEY_BYTES},}}")
"""A string that looks like key material (at least a minimal key's hex digits)."""


def check_key(key, *, field: str = "key") -> bytes:
    """``key`` as bytes, or :class:`UplinkKeyError` naming ``field`` (not bytes, or shorter
    than :data:`MIN_KEY_BYTES`). Never prints the key."""
    if not isinstance(key, (bytes, bytearray)):
        raise UplinkKeyError(f"{field}: must be bytes, got {type(key).__name__}")
    if len(key) < MIN_KEY_BYTES:
        raise UplinkKeyError(f"{field}: {len(key)} bytes, need at least {MIN_KEY_BYTES}")
    return bytes(key)


def _copy_with_tag(msg, tag: bytes):
    """A copy of ``msg`` (lists copied too) carrying ``tag`` as its auth tag."""
    copy = type(msg)()
    for name in msg.__slots__:
        value = getattr(msg, name)
        setattr(copy, name, list(value) if isinstance(value, list) else value)
    copy.auth_tag_size = len(tag)
    copy.auth_tag = bytes(tag)
    return copy


def canonical_bytes(msg) -> bytes:
    """The bytes the tag covers: the LCM encoding of ``msg`` with its tag removed.

    That is ``encode()`` (8-byte fingerprint, then every field) of a copy with
    ``auth_tag_size = 0`` and ``auth_tag = b""``. ``msg`` is not modified.
    """
    return _copy_with_tag(msg, b"").encode()


def compute_tag(msg, key: bytes) -> bytes:
    """HMAC-SHA256(key, canonical_bytes(msg)), :data:`TAG_BYTES` bytes.

    Raises:
        UplinkKeyError: ``key`` is not bytes or shorter than :data:`MIN_KEY_BYTES`.
    """
    return hmac.new(check_key(key), canonical_bytes(msg), hashlib.sha256).digest()


def sign(msg, key: bytes):
    """A signed copy of the command ``msg``: ``auth_tag_size = 32``, ``auth_tag`` = the HMAC.

    Any tag ``msg`` already carries is replaced. ``msg`` itself is not modified.

    Args:
        msg: An ``lcmt_teleop_joint_command`` (any LCM message with ``auth_tag_size`` and
            ``auth_tag`` fields works).
        key: The shared key, ≥ :data:`MIN_KEY_BYTES` bytes.

    Raises:
        UplinkKeyError: bad ``key``.
    """
    return _copy_with_tag(msg, compute_tag(msg, key))


def verify_classified(msg, key: bytes) -> tuple[str | None, str | None]:
    """Checks the tag of ``msg``: ``(None, None)`` if authentic, else ``(class, reason)``.

    ``class`` is one of :data:`AUTH_CLASSES` (for counters); ``reason`` names the problem,
    e.g. ``"unsigned (auth_tag_size = 0)"``, ``"auth_tag_size = 4, expected 32"`` or
    ``"HMAC mismatch (forged or corrupted; seq = 7, session_id = 1700000000000000)"``.
    The comparison takes constant time; ``msg`` is not modified.

    Raises:
        UplinkKeyError: bad ``key`` (a configuration error, not a property of the message).
    """
    key = check_key(key)
    size = msg.auth_tag_size
    if size == 0:
        return AUTH_UNSIGNED, "unsigned (auth_tag_size = 0)"
    if size != TAG_BYTES:
        return AUTH_MALFORMED, f"auth_tag_size = {size}, expected {TAG_BYTES}"
    tag = bytes(msg.auth_tag)
    if len(tag) != size:
        return AUTH_MALFORMED, f"auth_tag has {len(tag)} bytes but auth_tag_size = {size}"
    try:
        expected = compute_tag(msg, key)
    except Exception as error:   # e.g. num_joints not matching the array lengths
        return AUTH_MALFORMED, f"cannot encode the message ({type(error).__name__}: {error})"
    if not hmac.compare_digest(tag, expected):
        return AUTH_FORGED, (f"HMAC mismatch (forged or corrupted; seq = {msg.seq}, "
                             f"session_id = {msg.session_id})")
    return None, None


def verify(msg, key: bytes) -> str | None:
    """None if ``msg`` carries a valid tag for ``key``, else the reason it does not.

    See :func:`verify_classified` for the reasons; ``msg`` is not modified.
    """
    return verify_classified(msg, key)[1]


def _parse_hex_key(text: str, source: str) -> bytes:
    # Never echo the text: it is (or nearly is) key material.
    text = text.strip()
    if not text:
        raise UplinkKeyError(f"{source}: empty, expected a hex key")
    try:
        key = bytes.fromhex(text)
    except ValueError:
        raise UplinkKeyError(f"{source}: not a hex string ({len(text)} characters; expected "
                             f"{2 * GENERATED_KEY_BYTES} hex digits as written by "
                             "generate_key_file)") from None
    if len(key) < MIN_KEY_BYTES:
        raise UplinkKeyError(f"{source}: key is {len(key)} bytes, need at least "
                             f"{MIN_KEY_BYTES} ({2 * MIN_KEY_BYTES} hex digits)")
    return key


def _key_file_label(path) -> str:
    """How messages name a key file: its path, unless the "path" looks like key material (a
    long hex string given where a file is expected), which is never printed."""
    text = os.fspath(path)
    if _KEY_LIKE.fullmatch(os.path.basename(text) or text):
        return (f"uplink key file (the value given is a {len(text)}-character hex string, a "
                "key where a file path is expected; not shown: write the key to a file with "
                "mode 600 and give its path)")
    return f"uplink key file {quote_path(text)}"


def load_key(path: str | os.PathLike | None = None, *,
             environ: Mapping[str, str] = os.environ) -> bytes:
    """Loads the uplink key: from the file ``path`` if given, else from the environment.

    The file (or the variable :data:`KEY_ENVIRONMENT_VARIABLE`) holds the key as a hex
    string; surrounding whitespace is ignored. As ssh does with private keys, a file that
    group or others can access (any permission bit outside the owner's) is refused, with the
    ``chmod`` that fixes it; a file that is not a regular file (``/dev/zero``, a FIFO) or is
    larger than :data:`~telesmooth.user_input.MAX_KEY_FILE_BYTES` is refused before reading.

    Args:
        path: Key file, or None to use ``environ[KEY_ENVIRONMENT_VARIABLE]``.
        environ: The environment to read (a mapping; ``os.environ`` by default).

    Returns:
        The key, ≥ :data:`MIN_KEY_BYTES` bytes.

    Raises:
        UplinkKeyError: no key, unreadable file, a file others can access, not hex, or too
            short; the message names the file path or the environment variable, never the
            key (nor a "path" that is itself a hex key).
    """
    if path is None:
        source = f"environment variable {KEY_ENVIRONMENT_VARIABLE}"
        text = environ.get(KEY_ENVIRONMENT_VARIABLE)
        if text is None:
            raise UplinkKeyError(f"no uplink key: {source} is not set and no key file was "
                                 "given")
        return _parse_hex_key(text, source)
    source = _key_file_label(path)
    try:
        mode = os.stat(path).st_mode
    except OSError as error:
        raise UplinkKeyError(f"{source}: cannot read it ({error.strerror})") from None
    if os.name == "posix" and stat.S_ISREG(mode) and mode & (stat.S_IRWXG | stat.S_IRWXO):
        shown = (shlex.quote(os.fspath(path)) if not source.endswith("not shown)")
                 else "FILE")
        raise UplinkKeyError(f"{source} has mode {stat.S_IMODE(mode):#o}: group or others can "
                             f"access the key; refusing it (fix: chmod 600 {shown})")
    try:
        raw = read_file_bytes(path, what=source, max_bytes=MAX_KEY_FILE_BYTES)
    except ValueError as error:
        raise UplinkKeyError(str(error)) from None
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError:
        raise UplinkKeyError(f"{source}: not a hex string (non-ASCII bytes)") from None
    return _parse_hex_key(text, source)


def generate_key_file(path: str | os.PathLike) -> bytes:
    """Writes a fresh random :data:`GENERATED_KEY_BYTES`-byte key, as hex, to a new file.

    The file is created with mode 0o600 (owner read/write only), complete or not at all
    (:func:`~telesmooth.atomic_files.create_new_file`); missing parent folders are created
    with mode 0o700 (e.g. ``~/.telesmooth``). An existing path is never overwritten.

    Returns:
        The key written.

    Raises:
        UplinkKeyError: ``path`` exists (a key, or anything else), a parent is a file, or
            the folder cannot be written; the message names the path.
    """
    if not os.fspath(path).strip():
        raise UplinkKeyError("uplink key file '': give the path of the file to create")
    path = Path(path)
    label = f"uplink key file {quote_path(os.fspath(path))}"
    if path.exists() or path.is_symlink():
        what = "a folder" if path.is_dir() else "a file" if path.is_file() else "a special file"
        raise UplinkKeyError(f"{label} exists ({what}); refusing to overwrite it (remove it "
                             "first to make a new key)")
    missing = []
    for parent in path.parents:
        if parent.is_dir():
            break
        if parent.exists() or parent.is_symlink():
            raise UplinkKeyError(f"{label}: {quote_path(str(parent))} is a file, not a folder")
        missing.append(parent)
    try:
        for parent in reversed(missing):
            os.mkdir(parent, 0o700)
        key = secrets.token_bytes(GENERATED_KEY_BYTES)
        create_new_file(path, (key.hex() + "\n").encode("ascii"), file_mode=0o600)
    except FileExistsError:
        raise UplinkKeyError(f"{label} exists; refusing to overwrite it") from None
    except OSError as error:
        raise UplinkKeyError(f"{label}: cannot create it ({error.strerror})") from None
    return key
