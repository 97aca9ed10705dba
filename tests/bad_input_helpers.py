"""Shared checks of the bad-input tests (``tests/test_bad_input_*.py``).

The contract of every entry point for bad input: exit status 2, one line on stderr that
starts ``telesmooth <command>: error:`` and holds at most 300 characters naming the option or
key path as the user wrote it and the value; nothing written (no output file or folder, no
temporary file left behind) and every input file's bytes unchanged.
"""

from __future__ import annotations

import contextlib
import hashlib
import signal
from pathlib import Path

from telesmooth.scripts.cli import main

MAX_LINE = 300


def run(capsys, *argv):
    """``telesmooth *argv`` in this process: (status, stdout, stderr)."""
    try:
        status = main([str(arg) for arg in argv])
    except SystemExit as exit_:       # argparse (and the link relay) exit with the status
        status = exit_.code
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def write_trajectory(folder, name: str = "in.csv", rows: int = 40, jump: float = 0.0):
    """A valid 4 Hz joint trajectory ``t,a,b`` (radians) in ``folder``, joint a stepping by
    ``jump`` half-way; returns its path."""
    import numpy as np

    from telesmooth.smoothing.trajectory_io import write_joint_csv

    t = 0.25 * np.arange(rows)
    q = 0.1 * np.sin(np.outer(t, [1.0, 2.0]) / 3.0)
    q[rows // 2:, 0] += jump
    path = Path(folder) / name
    write_joint_csv(path, t, q, ["a", "b"])
    return path


def digest(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _signature(path: Path):
    if path.is_dir():
        return "dir"
    info = path.stat()
    if info.st_size > 16 << 20:      # e.g. a sparse 1 GiB file: its size and change time
        return (info.st_size, info.st_mtime_ns)
    return digest(path)


def snapshot(folder) -> dict:
    """Every file under ``folder`` (hidden ones too) with its digest, and every folder."""
    folder = Path(folder)
    return {str(p.relative_to(folder)): _signature(p)
            for p in sorted(folder.rglob("*")) if not p.is_symlink() and (p.is_file()
                                                                          or p.is_dir())}


def assert_one_line_error(status, stdout, stderr, command: str, *words: str) -> str:
    """Exit 2 and one bounded error line naming ``words``; returns the line."""
    assert status == 2, (status, stderr)
    lines = [line for line in stderr.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith(f"telesmooth {command}: error: ")]
    assert len(errors) == 1 and lines[-1] == errors[0], stderr
    line = errors[0]
    assert len(line) <= MAX_LINE, (len(line), line)
    assert "Traceback" not in stderr
    for word in words:
        assert word in line, (word, line)
    return line


@contextlib.contextmanager
def deadline(seconds: int):
    """Fails the test (instead of hanging the suite) if the block runs longer than
    ``seconds``; a reader that blocks on a FIFO or reads /dev/zero forever is caught."""
    def expire(signum, frame):
        raise TimeoutError(f"still running after {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
