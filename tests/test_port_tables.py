"""docs/architecture.md's port tables are the systems' own ports.

The table between the markers is what :func:`telesmooth.scripts.port_tables.port_tables` reads
from the diagrams the builders make; every system class defined in ``telesmooth.systems`` is
in it (none left out because no builder was walked that adds it); the sizes in the arm's
joints J come out right for hand-made sizes.
"""

import importlib
import inspect
import pkgutil

import pytest
from pydrake.systems.framework import System

import telesmooth.systems
from telesmooth.scripts.port_tables import DOC, _size_text, documented_tables, port_tables


@pytest.fixture(scope="module")
def generated():
    return port_tables()


def test_the_documented_tables_are_the_systems_ports(generated):
    assert documented_tables(DOC.read_text()) == generated, (
        "docs/architecture.md's port tables differ from the code: run "
        "`.venv/bin/python -m telesmooth.scripts.port_tables --write`")


def test_every_system_class_is_listed(generated):
    listed = {line.split("`")[1] for line in generated.splitlines()[2:]}
    defined = set()
    for module_info in pkgutil.iter_modules(telesmooth.systems.__path__):
        module = importlib.import_module(f"telesmooth.systems.{module_info.name}")
        for name, cls in inspect.getmembers(module, inspect.isclass):
            if cls.__module__ == module.__name__ and issubclass(cls, System):
                defined.add(f"{module_info.name}.{name}")
    assert defined - listed == set()
    assert listed - defined == set()


@pytest.mark.parametrize(("sizes", "text"), [
    ({3: 3, 6: 6}, "J"),
    ({3: 12, 6: 24}, "4J"),
    ({3: 7, 6: 13}, "2J + 1"),
    ({3: 17, 6: 26}, "3J + 8"),
    ({3: 1, 6: 1}, "1"),
    ({3: None, 6: None}, "abstract"),
    ({3: 5, 6: 6}, "5 (J = 3) / 6 (J = 6)"),     # not a whole number of joints
    ({3: 2, 6: 0}, "2 (J = 3) / 0 (J = 6)"),      # a fractional slope: listed
])
def test_sizes_in_joints(sizes, text):
    assert _size_text(sizes) == text
