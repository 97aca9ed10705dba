"""Renders the teleoperation diagram as SVG (``docs/teleoperation_diagram.svg`` by default).

The in-process chain of :func:`~telesmooth.diagrams.teleoperation.MakeTeleoperationDiagram`
for a scenario (default: the built-in ``Defaults``), drawn by Graphviz with ``max_depth = 1``
so each stage (haptic source, inverse kinematics, collision checker, delay FIFO, smoother,
uplink, robot) is one box. Needs the Graphviz ``dot`` program.

Usage: ``python -m telesmooth.scripts.render_diagram [--scenario-name NAME]
[--scenario-text YAML] [--max-depth 1] [--out docs/teleoperation_diagram.svg]``
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from telesmooth.diagrams.scenario import load_scenario
from telesmooth.diagrams.teleoperation import MakeTeleoperationDiagram
from telesmooth.diagrams.visualization import diagram_svg

DEFAULT_OUT = Path(__file__).resolve().parents[1] / "docs" / "teleoperation_diagram.svg"
"""The committed figure, in the repository's ``docs/`` folder."""


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario-name", default="Defaults")
    parser.add_argument("--scenario-text", default=None,
                        help="YAML mapping merged on top, e.g. '{arm: space_arm}'")
    parser.add_argument("--max-depth", type=int, default=1,
                        help="depth of nested diagrams to expand (1 = stages as boxes)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    try:
        scenario = load_scenario(scenario_name=args.scenario_name,
                                 scenario_text=args.scenario_text)
        svg = diagram_svg(MakeTeleoperationDiagram(scenario).diagram, max_depth=args.max_depth)
    except (ValueError, RuntimeError) as error:
        print(f"render_diagram: {error}", file=sys.stderr)
        return 2
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(svg, encoding="utf-8")
    print(f"wrote {args.out} ({len(svg.encode('utf-8'))} bytes)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
