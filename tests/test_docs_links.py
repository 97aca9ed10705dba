"""The documentation hangs together: every relative link in README.md and docs/*.md points to a
file (or folder) of the repository, and a link's #anchor, when it names a Markdown page, to one
of that page's headings."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
# [text](target) or [text](target "title"); images ![alt](target) too. Not inside code spans.
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
EXTERNAL = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")     # http:, https:, mailto:, …


def _without_code(text: str) -> str:
    text = re.sub(r"^```.*?^```", "", text, flags=re.M | re.S)
    return re.sub(r"`[^`\n]*`", "", text)


def _links(page: Path):
    for match in LINK.finditer(_without_code(page.read_text(encoding="utf-8"))):
        target = match.group(1)
        if not EXTERNAL.match(target):
            yield target


def _anchor(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    heading = re.sub(r"`", "", heading.strip()).lower()
    heading = re.sub(r"[^\w\- ]", "", heading)
    return heading.replace(" ", "-")


def _anchors(page: Path) -> set[str]:
    text = _without_code(page.read_text(encoding="utf-8"))
    return {_anchor(h) for h in re.findall(r"^#{1,6} (.+?)\s*#*$", text, flags=re.M)}


def test_the_docs_pages_are_found():
    names = {p.name for p in PAGES}
    assert {"README.md", "method.md", "architecture.md", "commands.md", "experiments.md",
            "numerics.md"} <= names


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page):
    broken = []
    for target in _links(page):
        path_part, _, anchor = target.partition("#")
        destination = (page.parent / path_part).resolve() if path_part else page
        if not destination.exists():
            broken.append(f"{target} (no such file)")
        elif anchor and destination.suffix == ".md" and anchor not in _anchors(destination):
            broken.append(f"{target} (no heading #{anchor} in {destination.name})")
        elif ROOT not in destination.parents and destination != ROOT:
            broken.append(f"{target} (outside the repository)")
    assert not broken, f"{page.relative_to(ROOT)}: " + "; ".join(broken)


def test_the_readme_links_every_docs_page():
    readme = set(_links(ROOT / "README.md"))
    linked = {t.partition("#")[0] for t in readme}
    missing = [f"docs/{p.name}" for p in PAGES[1:] if f"docs/{p.name}" not in linked]
    assert not missing
