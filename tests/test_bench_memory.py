"""The bench's peak-memory figure (``peak_above_baseline_mb`` of every row) against a known
allocation: a row that fills a 256 MiB array reports about 256 MB, a row that allocates nothing
reports almost nothing, also when the process that starts the rows holds a lot of memory
itself (a pytest worker after many tests; Linux's ``ru_maxrss`` carries the parent's resident
set across fork and exec)."""

import numpy as np

from telesmooth.scripts.bench_core import in_fresh_process

ALLOCATED_MB = 256


def _fill(megabytes: int) -> dict:
    block = np.ones(megabytes * 2**20 // 8)      # every page written, so it is resident
    return {"sum": float(block.sum())}


def _nothing() -> dict:
    return {"sum": 0.0}


def test_a_row_that_fills_an_array_reports_its_size():
    row = in_fresh_process(_fill, ALLOCATED_MB)
    assert row["sum"] == ALLOCATED_MB * 2**20 // 8
    # The array (less what the interpreter may have returned to the system since the baseline
    # was read), plus a few MB of interpreter and allocator overhead at most.
    assert 0.9 * ALLOCATED_MB <= row["peak_above_baseline_mb"] <= ALLOCATED_MB + 32


def test_a_row_that_allocates_nothing_reports_almost_nothing():
    row = in_fresh_process(_nothing)
    assert row["peak_above_baseline_mb"] <= 16
    assert row["peak_rss_mb"] >= row["baseline_rss_mb"] > 0


def test_the_parent_process_memory_does_not_count():
    held = np.ones(ALLOCATED_MB * 2**20 // 8)          # the parent holds 256 MiB, resident
    row = in_fresh_process(_nothing)
    assert held[-1] == 1.0
    assert row["peak_above_baseline_mb"] <= 16


def test_the_stated_measure_is_the_one_read():
    """The JSON's ``memory_measure`` names what :func:`peak_resident_mb` reads: on Linux the
    high-water mark ``VmHWM`` of /proc/self/status, read here independently."""
    from pathlib import Path

    from telesmooth.scripts.bench_core import MEMORY_MEASURE, peak_resident_mb

    assert "VmHWM" in MEMORY_MEASURE
    status = Path("/proc/self/status")
    if not status.exists():
        import pytest
        pytest.skip("no /proc/self/status: VmHWM is Linux's")
    def vm_hwm_mb() -> float:
        line = next(line for line in status.read_text().splitlines()
                    if line.startswith("VmHWM:"))
        return int(line.split()[1]) / 2**10                                  # kB

    before = vm_hwm_mb()
    figure = peak_resident_mb()
    after = vm_hwm_mb()
    # The mark only grows: read between two independent reads, the figure lies between them.
    assert before <= figure <= after
