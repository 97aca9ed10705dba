"""docs/commands.md's table of `telesmooth experiment`'s options is the parser's: every option
the command takes (besides the scenario options and --out, documented with every command) is
in the table, and the table names no option the command does not take."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from telesmooth.scripts.cli import build_parser

DOC = Path(__file__).resolve().parents[1] / "docs" / "commands.md"
COMMON = {"--scenario", "--scenario-name", "--scenario-text", "--on-collision", "--out", "--help"}


def _experiment_options() -> set[str]:
    parser = build_parser()
    subparsers = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    command = subparsers.choices["experiment"]
    return {option for action in command._actions for option in action.option_strings
            if option.startswith("--")} - COMMON


def _documented_options() -> set[str]:
    text = DOC.read_text()
    start = text.index("`telesmooth experiment [scenario options]")
    section = text[start:text.index("\n## ", start)]
    return {match for line in section.splitlines() if line.startswith("| `--")
            for match in re.findall(r"`(--[a-z0-9-]+)", line.split("|")[1])}


def test_the_experiment_table_is_the_parsers_options():
    assert _documented_options() == _experiment_options()
