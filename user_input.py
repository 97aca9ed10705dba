"""What users give the package: files read within fixed bounds, plain numbers, and messages
that quote values short and name fields as the user wrote them.

Every reader of the package takes its bytes through :func:`read_file_bytes`, which refuses what
is not a regular file (a folder, ``/dev/zero``, a FIFO that would block forever, a socket)
*before* reading, and refuses a file larger than the reader's bound (in bytes, named in the
message with the bound). The per-format bounds (rows, nesting, aliases, members) are applied by
the readers themselves with the limits below, so memory and time stay proportional to a small
file whatever the bytes are.

:func:`quote` is how every message shows a value the user gave: its ``repr`` cut to a short
prefix, with the full length when cut, so that a megabyte string in a file becomes a
100-character message and not a megabyte one. :func:`name_fields` turns a config's message
about its own field (``lag = 0 must be >= 1``) into one about the option or key the user wrote
(``--lag = 0 must be >= 1``); :func:`unknown_choice` is the message for a name that is not one
of a list (with the closest names, and the list cut short).
"""

from __future__ import annotations

import difflib
import os
import re
import stat
from collections.abc import Mapping, Sequence

__all__ = [
    "InputFileError",
    "ASCII_BLANKS",
    "MAX_CSV_BYTES",
    "MAX_CSV_COLUMNS",
    "MAX_CSV_LINE_CHARS",
    "MAX_CSV_ROWS",
    "MAX_JSON_BYTES",
    "MAX_JSON_DEPTH",
    "MAX_KEY_FILE_BYTES",
    "MAX_NPZ_ARRAY_BYTES",
    "MAX_NPZ_BYTES",
    "MAX_NPZ_MEMBERS",
    "MAX_YAML_ALIASES",
    "MAX_YAML_BYTES",
    "MAX_YAML_DEPTH",
    "MAX_YAML_NODES",
    "MAX_YAML_SCALAR_CHARS",
    "describe_size",
    "name_fields",
    "parse_plain_number",
    "quote",
    "quote_path",
    "read_file_bytes",
    "unknown_choice",
]

MAX_CSV_BYTES = 64 << 20
"""Largest CSV file read (joint trajectories, haptic recordings), bytes."""
MAX_CSV_ROWS = 1_000_000
"""Most data rows of a CSV file (2.8 h at 100 Hz, 69 h at 4 Hz)."""
MAX_CSV_COLUMNS = 1_000
"""Most columns of a CSV file."""
MAX_CSV_LINE_CHARS = 1 << 20
"""Longest line of a CSV file, characters."""
MAX_YAML_BYTES = 1 << 20
"""Largest YAML text (a scenario file, ``--scenario-text``, ``--link``), bytes."""
MAX_YAML_DEPTH = 32
"""Deepest nesting of YAML mappings and lists."""
MAX_YAML_NODES = 100_000
"""Most YAML nodes after alias expansion (what a billion-laughs text would multiply)."""
MAX_YAML_ALIASES = 1_000
"""Most alias uses (``*name``) in one YAML text."""
MAX_YAML_SCALAR_CHARS = 4_096
"""Longest YAML scalar (a key or a value), characters."""
MAX_JSON_BYTES = 1 << 20
"""Largest JSON file read (the operator σ store), bytes."""
MAX_JSON_DEPTH = 16
"""Deepest nesting of a JSON file read."""
MAX_KEY_FILE_BYTES = 4_096
"""Largest uplink key file, bytes (a key is 64 hex digits)."""
MAX_NPZ_BYTES = 64 << 20
"""Largest NPZ file read, bytes."""
MAX_NPZ_ARRAY_BYTES = 256 << 20
"""Largest array of an NPZ file once decompressed, bytes (what its header and zip entry
claim; both are checked before anything is decompressed)."""
MAX_NPZ_MEMBERS = 16
"""Most members of an NPZ archive."""

_QUOTE_CHARS = 60
ASCII_BLANKS = " \t\r\n\v\f"
"""The white space a plain number may have around it."""
_PLAIN_NUMBER = re.compile(
    r"[ \t\r\n\v\f]*[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?[ \t\r\n\v\f]*")
_NON_FINITE = re.compile(r"[ \t\r\n\v\f]*[+-]?(?:nan|inf|infinity)[ \t\r\n\v\f]*",
                         re.IGNORECASE)


class InputFileError(ValueError):
    """An input file that cannot be read within its bounds (the message names it)."""


def quote(value, limit: int = _QUOTE_CHARS) -> str:
    """``repr(value)`` cut to about ``limit`` characters, e.g. ``'xxxxxxxx…' (4194304
    characters)``; short values are their ``repr``."""
    if isinstance(value, (str, bytes)) and len(value) > limit:
        unit = "characters" if isinstance(value, str) else "bytes"
        return f"{value[:limit]!r}… ({len(value)} {unit})"
    text = repr(value)
    if len(text) > limit + 2:
        return f"{text[:limit]}… ({len(text)} characters)"
    return text


def quote_path(path, limit: int = 120) -> str:
    """``repr`` of a path (a string), its end kept when long (the file name matters most):
    ``'…/some/folder/file.csv'``."""
    text = str(path)
    if len(text) > limit:
        text = "…" + text[-limit:]
    return repr(text)


def parse_plain_number(text: str) -> float:
    """``text`` as a float if it is a plain decimal number: an optional sign, ASCII digits
    with at most one ``.``, an optional exponent (``e``/``E``, sign, digits), ASCII white
    space around; or ``nan``/``inf``/``infinity`` (any case, signed), which callers refuse
    by name.

    ``float()`` accepts more (``1_0e-3``, Arabic-Indic or full-width digits, other Unicode
    spaces): spellings that no data file means, refused here so that a typo is not read as a
    different number.

    Raises:
        ValueError: anything else (the caller names the field and quotes the value).
    """
    if _PLAIN_NUMBER.fullmatch(text) or _NON_FINITE.fullmatch(text):
        return float(text)   # may be inf (1e999 overflows): callers check finiteness
    raise ValueError(f"{quote(text)} is not a plain decimal number")


_FIELD_AT_START = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)(?=[\s=\[:]|\.[A-Za-z_]|$)")


def leading_field(message: str) -> str | None:
    """The word a message starts with, if it can be a field name (``"lag"`` for ``"lag = 0
    must be >= 1"``, ``"sigma"`` for ``"sigma[1] = -1 …"`` or ``"sigma has 2 value(s)"``),
    else None; callers check it against their fields."""
    match = _FIELD_AT_START.match(message)
    return None if match is None else match.group(1)


def name_fields(message: str, names: Mapping[str, str]) -> str:
    """``message`` with its leading field name replaced by what the user wrote.

    Args:
        message: A validation message that may start with a field name.
        names: Field name → the option or key path the user wrote (``{"lag": "--lag"}``).

    Returns:
        The message, its first word renamed if it is one of ``names``; else unchanged.
    """
    field = leading_field(message)
    if field is None or field not in names:
        return message
    return names[field] + message[len(field):]


def unknown_choice(field: str, value, choices: Sequence[str], *, noun: str = "names") -> str:
    """The message for ``value`` not being one of ``choices``: the closest names, then the
    list (cut short when long), e.g. ``"--shape = 'Sshap' is not one of the 30 LASA shapes;
    did you mean 'Sshape'? (Angle, BendedLine, …)"``."""
    close = difflib.get_close_matches(str(value), [str(c) for c in choices], n=3)
    listing = ", ".join(str(c) for c in choices)
    if len(listing) > 120:
        listing = listing[:120].rsplit(", ", 1)[0] + ", …"
    hint = f"; did you mean {' or '.join(repr(c) for c in close)}?" if close else ""
    return (f"{field} = {quote(value)} is not one of the {len(choices)} {noun}{hint} "
            f"({listing})")


def describe_size(num_bytes: int) -> str:
    """``1.0 GiB``, ``64 MiB``, ``4096 bytes``: a byte count for people."""
    for unit, shift in (("GiB", 30), ("MiB", 20), ("KiB", 10)):
        if num_bytes >= 1 << shift:
            value = num_bytes / (1 << shift)
            return f"{value:.1f} {unit}" if value != int(value) else f"{int(value)} {unit}"
    return f"{num_bytes} bytes"


_KINDS = {stat.S_IFDIR: "a folder", stat.S_IFCHR: "a character device",
          stat.S_IFBLK: "a block device", stat.S_IFIFO: "a FIFO (a pipe)",
          stat.S_IFSOCK: "a socket"}


def read_file_bytes(path, *, what: str, max_bytes: int) -> bytes:
    """The bytes of the regular file ``path``, at most ``max_bytes`` of them.

    The file is opened without blocking (a FIFO with no writer would otherwise wait forever)
    and examined before anything is read.

    Args:
        path: The file.
        what: How messages name it, as the user wrote it (e.g. ``"--scenario = 'a.yaml'"``).
        max_bytes: The bound.

    Raises:
        InputFileError: the file is missing or unreadable, is not a regular file (a folder, a
            device, a FIFO, a socket), or holds more than ``max_bytes`` bytes.
    """
    try:
        descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY)
    except OSError as error:
        raise InputFileError(f"{what}: cannot read it ({error.strerror})") from None
    try:
        info = os.fstat(descriptor)
        if not stat.S_ISREG(info.st_mode):
            kind = _KINDS.get(stat.S_IFMT(info.st_mode), "not a regular file")
            raise InputFileError(f"{what} is {kind}, not a file")
        if info.st_size > max_bytes:
            raise InputFileError(f"{what} is {describe_size(info.st_size)}; the limit is "
                                 f"{describe_size(max_bytes)}")
        chunks, size = [], 0
        while size <= max_bytes:
            chunk = os.read(descriptor, min(1 << 20, max_bytes + 1 - size))
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        if size > max_bytes:   # it grew while we read
            raise InputFileError(f"{what} is over the limit of {describe_size(max_bytes)}")
        return b"".join(chunks)
    except OSError as error:
        raise InputFileError(f"{what}: cannot read it ({error.strerror})") from None
    finally:
        os.close(descriptor)
