"""Shared by the tests that run `telesmooth` commands as real processes on udpm buses."""

import csv
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

TELESMOOTH = [sys.executable, "-m", "telesmooth.scripts.cli"]


def worker_port(first_port: int, spread: int = 90) -> int:
    """A udpm port from ``first_port`` on: + the pid modulo ``spread`` (two sessions on one
    host part), + 1000 per pytest-xdist worker (the workers run modules at the same time, and
    every module's range lies within 7300–8299)."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    index = int(worker[2:]) if worker[2:].isdigit() else 0
    return first_port + 1000 * index + os.getpid() % spread


def bus_urls(first_port: int) -> tuple[str, str]:
    """Two udpm buses (A, B) that stay on this host (ttl=0), 100 ports apart, chosen from
    ``first_port`` by :func:`worker_port`."""
    port = worker_port(first_port)
    return (f"udpm://239.255.76.67:{port}?ttl=0", f"udpm://239.255.76.67:{port + 100}?ttl=0")


def read_rows(path) -> np.ndarray:
    """A CSV file the processes wrote, without its header, as floats."""
    with open(path, newline="") as handle:
        rows = list(csv.reader(handle))
    return np.array(rows[1:], dtype=float)


class CliProcess(subprocess.Popen):
    """A `telesmooth` command (``args`` after the program) in a child process.

    stdout and stderr go to ``log_path``: a pipe nobody drains would fill up and block the
    process (the onboard one logs every rejected packet).
    """

    def __init__(self, args, log_path):
        self.log_path = Path(log_path)
        with open(self.log_path, "w") as log:
            super().__init__(TELESMOOTH + list(args), stdout=log, stderr=log, text=True)

    def wait_for(self, text: str, timeout_s: float) -> str:
        """Waits until the log contains ``text``; returns the log so far."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            log = self.log_path.read_text()
            if text in log:
                return log
            if self.poll() is not None:
                break
            time.sleep(0.05)
        raise AssertionError(f"no {text!r} within {timeout_s} s: {self.log_path.read_text()}")

    def stop(self, timeout_s: float = 60) -> int:
        """SIGINT, then the exit code (0 expected: the tools stop cleanly on it)."""
        self.send_signal(signal.SIGINT)
        return self.wait(timeout=timeout_s)


PROCESS_TEST_TIMEOUT_S = 600
"""The longest a process test waits for one process (a loaded machine starts them slowly)."""


class CpuHog:
    """A CPU-bound process beside the processes under test (``python3 -c "while True: pass"``),
    as a context manager: started on entry, killed on exit."""

    def __enter__(self):
        self.process = subprocess.Popen(["python3", "-c", "while True: pass"])
        return self

    def __exit__(self, *exc):
        self.process.kill()
        self.process.wait(timeout=30)
        return False


def guard_gaps(received_t, timeout_s):
    """The accepted packets' arrival times (onboard simulation time, s) and the indices after
    which the next packet came later than ``timeout_s`` (the guard then rightly stops)."""
    t = np.asarray(received_t, dtype=float)
    return np.flatnonzero(np.diff(t) > timeout_s)


class BusPump:
    """Pumps ``lcm.LCM`` buses (handle their subscriptions) in a daemon thread until
    :meth:`close`."""

    def __init__(self, *buses):
        self.buses = buses
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        while not self._stop.is_set():
            for bus in self.buses:
                bus.handle_timeout(5)

    def close(self):
        self._stop.set()
        self._thread.join(timeout=5)
