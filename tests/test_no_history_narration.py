"""The docs and the code state what is: no reference to the issue tracker, which is not in the
repository ("issue 20", "Issue 6 part 2", "(#12)"). How something came to be belongs in the
git log and in CHANGELOG.md, which is the one file allowed to tell it.

Scans every *.py and *.md file git tracks, except CHANGELOG.md and this file, and names each
hit as path:line.
"""

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
THIS_FILE = Path(__file__).resolve().relative_to(ROOT).as_posix()
EXCLUDED = {"CHANGELOG.md", THIS_FILE}

TRACKER_REFERENCES = (
    re.compile(r"\bissues? #?\d+", re.IGNORECASE),  # "issue 20", "Issue 6", "issues #19"
    re.compile(r"\(#\d+\)"),                         # "(#12)"
)

# Hits in files this change could not edit, to be reworded by the owner: (path, the line's
# text, stripped). Each entry must still occur (test_allowed_hits_still_exist), so an entry
# is removed once its line is reworded, and a new reference anywhere fails the scan.
ALLOWED: frozenset[tuple[str, str]] = frozenset()


def _tracked_files() -> list[str]:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip(f"not a git checkout ({ROOT}): the tracked files cannot be listed")
    listing = subprocess.run(["git", "-C", str(ROOT), "ls-files", "-z", "--", "*.py", "*.md"],
                             check=True, capture_output=True).stdout.decode()
    return sorted(path for path in listing.split("\0")
                  if path and path not in EXCLUDED and (ROOT / path).is_file())


def _hits() -> list[tuple[str, int, str]]:
    hits = []
    for path in _tracked_files():
        text = (ROOT / path).read_text(encoding="utf-8", errors="replace")
        for number, line in enumerate(text.splitlines(), start=1):
            if any(pattern.search(line) for pattern in TRACKER_REFERENCES):
                hits.append((path, number, line.strip()))
    return hits


def test_patterns_catch_tracker_references():
    for line in ("(memory, issue 20)", "Issue 6: within 1e-6", "issue 6 part 2",
                 "(issue 16 §2)", "see issues 19 and 20", "fixed in (#12)", "issue #7"):
        assert any(p.search(line) for p in TRACKER_REFERENCES), line
    for line in ("the LASA demonstration `Angle` #0", "an issue with the plant",
                 "demonstration 0 of each shape"):
        assert not any(p.search(line) for p in TRACKER_REFERENCES), line


def test_no_reference_to_the_issue_tracker():
    new = [f"{path}:{number}: {line}" for path, number, line in _hits()
           if (path, line) not in ALLOWED]
    assert not new, ("references to the issue tracker, which is not in the repository (state "
                     "the present fact; history goes to CHANGELOG.md):\n" + "\n".join(new))


def test_allowed_hits_still_exist():
    found = {(path, line) for path, _, line in _hits()}
    stale = sorted(ALLOWED - found)
    assert not stale, f"ALLOWED entries no longer found (remove them): {stale}"
