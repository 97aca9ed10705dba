"""The repository documents itself: every reference to the method points to a section that
exists in ``docs/method.md``, and nothing points outside the repository."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SUFFIXES = {".py", ".md", ".toml", ".yaml", ".yml", ".txt", ".cfg"}
SKIP = {".venv", ".git", "out", "build", ".hypothesis", ".pytest_cache"}


def _sources():
    for path in ROOT.rglob("*"):
        parts = path.relative_to(ROOT).parts
        if path.is_file() and path.suffix in SUFFIXES and not (set(parts) & SKIP) \
                and not any(p.endswith(".egg-info") for p in parts):
            yield path


def _method_sections() -> set[str]:
    text = (ROOT / "docs" / "method.md").read_text(encoding="utf-8")
    return set(re.findall(r"^#{2,3} (\d+(?:\.\d+)?)\.? ", text, flags=re.M))


def test_the_method_has_numbered_sections():
    sections = _method_sections()
    assert {"0", "1", "1.2", "2.6", "5.1", "6", "7", "8"} <= sections


def test_every_method_reference_names_an_existing_section():
    sections = _method_sections()
    missing = []
    for path in _sources():
        text = path.read_text(encoding="utf-8", errors="replace")
        for match in re.finditer(r"method\.md §(\d+(?:\.\d+)?)((?:/§\d+(?:\.\d+)?)*)", text):
            for number in [match.group(1)] + re.findall(r"§(\d+(?:\.\d+)?)", match.group(2)):
                if number not in sections:
                    missing.append(f"{path.relative_to(ROOT)}: §{number}")
    assert not missing


def test_nothing_points_outside_the_repository():
    outside = [str(p.relative_to(ROOT)) for p in _sources()
               if p.name != Path(__file__).name
               and re.search(r"\.\./shared|SPEC\.md|SPEC §",
                             p.read_text(encoding="utf-8", errors="replace"))]
    assert not outside
