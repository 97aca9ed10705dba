"""The operators' σ store: the σ each operator's last operation under reduced-Q reached, per
joint, in a JSON file, read back as the next operation's σ_0 (``telesmooth smooth
--operator NAME --sigma-store FILE``).

The file is replaced atomically, so an interrupted write never loses stored operators, and it
is read within bounds (a regular UTF-8 file of at most ``MAX_JSON_BYTES``, nested at most
``MAX_JSON_DEPTH``; a key given twice in one object is an error).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from telesmooth.arms.joint_vectors import as_per_joint
from telesmooth.atomic_files import write_text
from telesmooth.user_input import MAX_JSON_BYTES, MAX_JSON_DEPTH, quote, read_file_bytes

__all__ = ["SIGMA_FILE_FORMAT", "load_operator_sigma", "save_operator_sigma",
           "stored_operators"]


SIGMA_FILE_FORMAT = "telesmooth-operator-sigma/1"


def save_operator_sigma(path, operator: str, joint_names, sigma, *, destination=None) -> None:
    """Stores the σ an operator reached, per joint, in a JSON file (other operators kept).

    The file is replaced atomically (:func:`~telesmooth.atomic_files.write_text`), so an
    interrupted write never loses stored operators.

    Args:
        path: The σ store (read if it exists).
        operator, joint_names, sigma: What to store.
        destination: Where to write the updated store; default ``path`` (e.g. a staged
            temporary file of :class:`~telesmooth.atomic_files.Outputs`).
    """
    if not isinstance(operator, str) or not operator.strip():
        raise ValueError(f"operator = {quote(operator)} must be a non-empty name")
    names = list(joint_names)
    values = as_per_joint("sigma", sigma, len(names), names)
    path = Path(path)
    data = {"format": SIGMA_FILE_FORMAT, "operators": {}}
    if path.exists():
        data = _read_sigma_file(path)
    data["operators"][operator] = {name: float(v) for name, v in zip(names, values)}
    write_text(path if destination is None else destination,
               json.dumps(data, indent=2, sort_keys=True) + "\n")


def load_operator_sigma(path, operator: str, joint_names) -> np.ndarray:
    """Reads an operator's stored σ for ``joint_names``, shape (num_joints,).

    Raises:
        ValueError: unknown operator, a joint missing from the file, a joint in the file that
            the recording does not have, or a non-positive/non-finite σ.
    """
    data = _read_sigma_file(Path(path))
    operators = data["operators"]
    if operator not in operators:
        raise ValueError(
            f"operator = {operator!r} has no stored sigma in {path}; known: {sorted(operators)}"
        )
    stored = operators[operator]
    return as_per_joint(f"sigma of operator {operator!r}", stored, len(joint_names),
                        list(joint_names))


def stored_operators(path) -> list[str]:
    """Names of the operators with a stored σ in ``path`` (empty if the file does not exist)."""
    path = Path(path)
    return sorted(_read_sigma_file(path)["operators"]) if path.exists() else []


def _read_sigma_file(path: Path) -> dict:
    """The σ store, read within bounds (a regular UTF-8 file of at most ``MAX_JSON_BYTES``,
    nesting at most ``MAX_JSON_DEPTH``; a key given twice in one object is an error)."""
    raw = read_file_bytes(path, what=f"{path}", max_bytes=MAX_JSON_BYTES)
    try:
        data = json.loads(raw.decode("utf-8"), object_pairs_hook=_unique_keys)
    except UnicodeDecodeError as error:
        raise ValueError(f"{path}: not a valid sigma file (not UTF-8: {error.reason} at byte "
                         f"{error.start})") from None
    except (json.JSONDecodeError, _DuplicateKey) as error:
        raise ValueError(f"{path}: not a valid sigma file ({error})") from None
    except RecursionError:
        raise ValueError(f"{path}: not a valid sigma file (nested too deeply)") from None
    if _json_depth(data) > MAX_JSON_DEPTH:
        raise ValueError(f"{path}: not a valid sigma file (nested deeper than "
                         f"{MAX_JSON_DEPTH} levels)")
    if not isinstance(data, dict) or data.get("format") != SIGMA_FILE_FORMAT:
        raise ValueError(f"{path}: format must be {SIGMA_FILE_FORMAT!r}")
    if not isinstance(data.get("operators"), dict):
        raise ValueError(f"{path}: 'operators' must be a mapping")
    for name, joints in data["operators"].items():
        if not isinstance(joints, dict):
            raise ValueError(f"{path}: operator {quote(name)} must map joint names to sigma")
        for joint, value in joints.items():
            if (isinstance(value, bool) or not isinstance(value, (int, float))
                    or not math.isfinite(value) or value <= 0):
                raise ValueError(
                    f"{path}: sigma for operator {quote(name)}, joint {quote(joint)} = "
                    f"{quote(value)} must be finite and > 0"
                )
    return data


class _DuplicateKey(ValueError):
    pass


def _unique_keys(pairs) -> dict:
    """json object hook: a key given twice is an error, not the last value silently."""
    data = {}
    for key, value in pairs:
        if key in data:
            raise _DuplicateKey(f"key {quote(key)} is given twice")
        data[key] = value
    return data


def _json_depth(data) -> int:
    depth, level = 0, [data]
    while level:
        depth += 1
        level = [child for item in level if isinstance(item, (dict, list))
                 for child in (item.values() if isinstance(item, dict) else item)]
    return depth
