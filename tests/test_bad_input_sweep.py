"""The red-team sweep (``tests/bad_input_redteam.py``: 204 hostile or mistaken inputs to every
``telesmooth`` entry point, each in a forked child with memory and time limits) is part of the
suite: every case must come out "ok" (one clear error line and status 2, or success where the
case expects it; no traceback, hang, crash, leaked key, half-written output or changed input).

It runs as its own process (the sweep forks a child per case; a fresh interpreter has no
threads of earlier tests to fork), about 80 s on two cores. Marked ``sweep``:
``-m "not sweep"`` skips it.
"""

import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.sweep

SWEEP = Path(__file__).with_name("bad_input_redteam.py")


def test_every_case_of_the_red_team_sweep_is_ok():
    completed = subprocess.run([sys.executable, str(SWEEP)], capture_output=True, text=True,
                               timeout=3600)
    lines = completed.stderr.splitlines()
    summary = [line for line in lines if " cases in " in line]
    assert summary, completed.stderr[-2000:]
    bad = [line for line in lines if line and not line.startswith("ok ")
           and " cases in " not in line]
    assert completed.returncode == 0 and not bad, "\n".join(bad[:20] + summary)
    assert summary[-1].endswith("; 0 not ok") and int(summary[-1].split()[0]) >= 200
