"""Renders the teleoperation diagram as SVG (``docs/teleoperation_diagram.svg`` by default).

The in-process chain of :func:`~telesmooth.diagrams.teleoperation.MakeTeleoperationDiagram`
for a scenario (default: the built-in ``Defaults``), drawn by Graphviz with ``max_depth = 1``
so each stage (haptic source, inverse kinematics, collision checker, delay FIFO, smoother,
uplink, robot) is one box. Needs the Graphviz ``dot`` program.

Usage: ``python -m telesmooth.scripts.render_diagram [--scenario FILE] [--scenario-name NAME]
[--scenario-text YAML] [--max-depth 1] [--out docs/teleoperation_diagram.svg]`` (the scenario
flags are those of the ``telesmooth`` command line).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from telesmooth.diagrams.teleoperation import MakeTeleoperationDiagram
from telesmooth.diagrams.visualization import diagram_svg
from telesmooth.scripts.cli import _add_scenario_arguments, _load_scenario

DEFAULT_OUT = Path(__file__).resolve().parents[1] / "docs" / "teleoperation_diagram.svg"
"""The committed figure, in the repository's ``docs/`` folder."""


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    _add_scenario_arguments(parser)
    parser.add_argument("--max-depth", type=int, default=1,
                        help="depth of nested diagrams to expand (1 = stages as boxes)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    try:
        scenario = _load_scenario(args)
        svg = diagram_svg(MakeTeleoperationDiagram(scenario).diagram, max_depth=args.max_depth)
    except (ValueError, RuntimeError) as error:
        print(f"render_diagram: {error}", file=sys.stderr)
        return 2
    args.out.parent.mkdir(parents=True, exist_ok=True)
    from telesmooth.atomic_files import write_text

    write_text(args.out, svg)
    print(f"wrote {args.out} ({len(svg.encode('utf-8'))} bytes)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
