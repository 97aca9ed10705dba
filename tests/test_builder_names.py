"""One naming rule for builders (Drake's): a function that adds systems to a DiagramBuilder is
``Add…`` (or ``Connect…`` when it only wires them), one that returns a built diagram or
simulator is ``Make…``; checked from the sources of diagrams/ and systems/."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MODULES = sorted([*ROOT.joinpath("diagrams").glob("*.py"), *ROOT.joinpath("systems").glob("*.py")])


def _functions():
    for path in MODULES:
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.FunctionDef) and not node.name.startswith("_"):
                yield path, node


@pytest.mark.parametrize("path, node", list(_functions()),
                         ids=lambda value: getattr(value, "name", getattr(value, "stem", "")))
def test_a_function_given_the_builder_is_add_or_connect(path, node):
    args = node.args.posonlyargs + node.args.args
    if args and args[0].arg == "builder":
        assert node.name.startswith(("Add", "Connect")), f"{path.name}: {node.name}"


def test_no_builder_or_loader_keeps_the_other_style():
    names = {node.name for _, node in _functions()}
    assert not {name for name in names if name.startswith(("add_", "connect_", "load_"))}
    assert "MakeSimulator" in names and "LoadScenario" in names
