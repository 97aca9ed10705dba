"""The layout tells the architecture: the package import graph, built from the sources.

Every ``import telesmooth.X…`` and ``from telesmooth.X… import …`` counts, function-local
imports included (a cycle hidden in a function is still a cycle). The layers, low to high:

    top-level modules (user_input, atomic_files, typed_yaml, compiled, labelled_enum)
    lcm_types → arms → smoothing, safety (pure: no pydrake.systems), console (no Drake)
    → datasets
    → link (pure Python: no Drake) → systems → diagrams → studies → scripts

A package may import its own layer's or lower ones, never a higher one, and the packages'
graph has no cycle (nor has the modules' graph).
"""

from __future__ import annotations

import ast
import tomllib
from collections import defaultdict
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

LAYERS = (
    ("user_input", "atomic_files", "typed_yaml", "compiled", "labelled_enum"),
    ("lcm_types",),
    ("arms",),
    ("smoothing", "safety", "console"),
    ("datasets",),
    ("link",),
    ("systems",),
    ("diagrams",),
    ("studies",),
    ("scripts",),
)
RANK = {unit: rank for rank, units in enumerate(LAYERS) for unit in units}

PURE = {"smoothing": ("pydrake.systems",), "safety": ("pydrake.systems",), "link": ("pydrake",),
        "console": ("pydrake",)}
"""Packages and the imports they must not have (at all, function-local ones included)."""


def _sources():
    """(module name, path) of every module of the package (tests and generated code aside)."""
    for path in sorted(ROOT.rglob("*.py")):
        relative = path.relative_to(ROOT)
        if relative.parts[0] in ("tests", ".venv", "docs") or "telesmooth_lcmt" in relative.parts:
            continue
        if any(part.startswith(".") for part in relative.parts):
            continue
        parts = ("telesmooth",) + relative.with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        yield ".".join(parts), path


def _imports(path: Path):
    """Every module name ``path`` imports (absolute names; ``from a import b`` gives a and
    a.b), function-local imports included."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            yield node.module
            for alias in node.names:
                yield f"{node.module}.{alias.name}"


MODULES = dict(_sources())
IMPORTS = {module: set(_imports(path)) for module, path in MODULES.items()}


def _unit(module: str) -> str | None:
    """The package (or top-level module) a ``telesmooth.…`` module belongs to."""
    parts = module.split(".")
    if parts[0] != "telesmooth" or len(parts) < 2:
        return None
    return parts[1]


def _package_graph():
    edges = defaultdict(set)
    where = defaultdict(set)
    for module, imported in IMPORTS.items():
        source = _unit(module)
        for name in imported:
            target = _unit(name)
            if source and target and target != source and (target in RANK or target in MODULES):
                edges[source].add(target)
                where[source, target].add(module)
    return edges, where


def _cycles(edges) -> list[list[str]]:
    """The strongly connected components with more than one node (Tarjan)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []

    def visit(node):
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(edges.get(node, ())):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(set(edges) | {n for targets in edges.values() for n in targets}):
        if node not in index:
            visit(node)
    return found


def test_the_graph_is_built_from_every_package():
    units = {_unit(module) for module in MODULES} - {None}
    assert set(RANK) <= units, set(RANK) - units
    assert units <= set(RANK), f"a package with no layer: {units - set(RANK)}"
    edges, _ = _package_graph()
    assert "systems" in edges["diagrams"]       # the walker sees imports at all


def test_no_cycle_between_packages():
    edges, where = _package_graph()
    cycles = _cycles(edges)
    detail = {f"{a} -> {b}": sorted(where[a, b])[:3]
              for cycle in cycles for a in cycle for b in cycle if (a, b) in where}
    assert not cycles, detail


def test_no_cycle_between_modules():
    edges = {module: {name for name in imported if name in MODULES and name != module}
             for module, imported in IMPORTS.items()}
    assert not _cycles(edges)


def test_no_package_imports_a_higher_layer():
    edges, where = _package_graph()
    upward = {f"{source} -> {target}": sorted(where[source, target])[:3]
              for source, targets in edges.items() for target in targets
              if RANK[target] > RANK[source]}
    assert not upward, upward


@pytest.mark.parametrize("package", sorted(PURE))
def test_the_pure_packages_import_no_drake_systems(package):
    banned = PURE[package]
    found = {module: sorted(name for name in imported
                            if any(name == b or name.startswith(b + ".") for b in banned))
             for module, imported in IMPORTS.items() if _unit(module) == package}
    found = {module: names for module, names in found.items() if names}
    assert not found, found


def test_every_package_folder_is_installed():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    folders = {"telesmooth." + ".".join(path.parent.relative_to(ROOT).parts)
               for path in ROOT.rglob("__init__.py")
               if path.parent != ROOT and not any(part.startswith(".") or part == "tests"
                                                  for part in path.relative_to(ROOT).parts)}
    assert folders <= set(config["packages"]), folders - set(config["packages"])
    assert folders <= set(config["package-dir"]), folders - set(config["package-dir"])
