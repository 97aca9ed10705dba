"""The experiment's journal: a folder of records that a rerun continues, shards merge into and
a changed experiment is refused from.

A folder holds ``grid.json`` (what makes its records parts of one experiment: the grid, the
base scenario and the code that computes records, :func:`grid_fingerprint`), ``records.jsonl``
(one finished task per line, on disk before the next: :class:`RecordLog`; a line cut short by
a stopped run is dropped and its task runs again, :func:`read_records`) and ``.lock`` (one run
at a time, :class:`FolderLock`). Changing the code that only reads records
(:data:`READS_RECORDS_ONLY`: the reports, the claims) keeps a finished grid's fingerprint, so
it can be judged again without running it.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from pathlib import Path

from telesmooth.atomic_files import write_text
from telesmooth.studies.experiment import ExperimentConfig
from telesmooth.user_input import MAX_JSON_BYTES, read_file_bytes

__all__ = ["GRID_FILE", "MAX_RECORDS_BYTES", "READS_RECORDS_ONLY", "RECORDS_FILE",
           "REPORT_FIELDS", "FolderLock", "RecordLog", "check_grid", "code_fingerprint",
           "grid_fingerprint", "read_records"]


GRID_FILE = "grid.json"
RECORDS_FILE = "records.jsonl"
MAX_RECORDS_BYTES = 512 << 20
"""Largest records.jsonl read, bytes."""


READS_RECORDS_ONLY = ("scripts", "tests", "docs", "studies/claims.py", "studies/verdicts.py",
                      "studies/journal.py")
"""Parts of the package that only read records (the reports, the claims): changing them does
not change a record, so a finished grid can be reported again with them."""

REPORT_FIELDS = ("kf_form",)
"""Fields of :class:`ExperimentConfig` that only change how the records are judged."""


def code_fingerprint() -> str:
    """sha256 of the package's sources and data files that compute records (everything but
    :data:`READS_RECORDS_ONLY`): records of another version of that code are not mixed in."""
    import telesmooth

    root = Path(telesmooth.__file__).resolve().parent
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*")):
        relative = path.relative_to(root)
        if (path.is_file() and path.suffix in (".py", ".yaml", ".sdf", ".lcm")
                and relative.parts[0] not in (".venv", ".git")
                and not any(relative.as_posix() == part or relative.parts[0] == part
                            for part in READS_RECORDS_ONLY)
                and not any(part.startswith(".") for part in relative.parts)):
            digest.update(relative.as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def grid_fingerprint(base, config: ExperimentConfig) -> dict:
    """What makes two runs parts of the same experiment: the grid (without how it is run or
    judged: :data:`REPORT_FIELDS`), the base scenario and the code that computes records.
    {"fingerprint": sha256 hex, "config", "base", "code"}."""
    grid = json.loads(json.dumps(dataclasses.asdict(config), default=repr))   # as stored
    for field in REPORT_FIELDS:
        grid.pop(field, None)
    code = code_fingerprint()
    text = json.dumps({"config": grid, "base": repr(base), "code": code}, sort_keys=True)
    return {"fingerprint": hashlib.sha256(text.encode()).hexdigest(), "config": grid,
            "base": repr(base), "code": code}


def check_grid(out: Path, grid: dict) -> None:
    """Writes grid.json into a new folder, or refuses a folder of another experiment."""
    path = out / GRID_FILE
    if path.exists():
        try:
            held = json.loads(read_file_bytes(path, what=str(path), max_bytes=MAX_JSON_BYTES))
            if not isinstance(held, dict):
                raise ValueError("not a mapping")
        except (OSError, ValueError) as error:
            raise ValueError(f"--out {str(out)!r}: {GRID_FILE} cannot be read ({error}); "
                             "use another folder") from None
        if held.get("fingerprint") != grid["fingerprint"]:
            changed = sorted(key for key in set(held.get("config", {})) | set(grid["config"])
                             if held.get("config", {}).get(key) != grid["config"].get(key))
            if held.get("base") != grid["base"]:
                changed.append("the base scenario")
            if held.get("code") != grid["code"]:
                changed.append("the code (telesmooth was changed since)")
            raise ValueError(
                f"--out {str(out)!r} holds the records of another experiment (it differs in: "
                f"{', '.join(changed) or 'the grid'}); a changed configuration is not mixed "
                "in: use another folder")
        return
    write_text(path, json.dumps(grid, indent=1) + "\n")


def read_records(out: Path) -> dict:
    """The records kept in a folder, by task key. A last line cut short (a run stopped while
    writing it) is ignored: its task runs again."""
    path = Path(out) / RECORDS_FILE
    records = {}
    if not path.exists():
        return records
    data = read_file_bytes(path, what=str(path), max_bytes=MAX_RECORDS_BYTES)
    lines = data.split(b"\n")
    for number, line in enumerate(lines[:-1], start=1):   # the last piece: cut short or b""
        try:
            record = json.loads(line)
            records[record["key"]] = record
        except (ValueError, TypeError, KeyError) as error:
            raise ValueError(f"{path}: line {number} is not a task record ({error}); use "
                             "another --out folder") from None
    return records


class RecordLog:
    """Appends each finished task's record to records.jsonl, on disk before the next."""

    def __init__(self, out: Path):
        self.path = out / RECORDS_FILE
        # Drop a last line cut short, so the appended lines start on a line of their own.
        if self.path.exists():
            data = self.path.read_bytes()
            if data and not data.endswith(b"\n"):
                with self.path.open("r+b") as handle:
                    handle.truncate(data.rfind(b"\n") + 1)

    def __call__(self, record: dict) -> None:
        with self.path.open("a") as handle:
            handle.write(json.dumps(record, default=float) + "\n")
            handle.flush()
            os.fsync(handle.fileno())


class FolderLock:
    """One run at a time per output folder (an advisory lock on ``.lock``): two runs on one
    folder would compute the same tasks twice and could cut each other's lines."""

    def __init__(self, out: Path):
        self.path = out / ".lock"

    def __enter__(self):
        import fcntl

        self.handle = self.path.open("a")
        try:
            fcntl.flock(self.handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self.handle.close()
            raise ValueError(f"--out {str(self.path.parent)[:80]!r} is being used by another "
                             "experiment run; wait for it or use another folder") from None
        return self

    def __exit__(self, *exc):
        self.handle.close()          # closing releases the lock
        return False
