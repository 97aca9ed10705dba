"""Regenerates the Python LCM classes from the ``*.lcm`` definitions with ``lcm-gen``.

Usage: ``python -m telesmooth.lcm_types.generate [--out DIR]`` (default: this folder, which
rewrites ``telesmooth_lcmt/``).
"""

from __future__ import annotations

import argparse
import pathlib
import shutil
import subprocess
import sys

__all__ = ["DEFINITIONS_DIRECTORY", "generate", "lcm_gen_executable"]

DEFINITIONS_DIRECTORY = pathlib.Path(__file__).resolve().parent


def lcm_gen_executable() -> str:
    """The ``lcm-gen`` next to this interpreter (the ``lcm`` wheel's), else one on PATH."""
    candidate = pathlib.Path(sys.executable).with_name("lcm-gen")
    if candidate.is_file():
        return str(candidate)
    found = shutil.which("lcm-gen")
    if found is None:
        raise FileNotFoundError(
            "lcm-gen not found: install the `lcm` package (pip install lcm==1.5.*)")
    return found


def generate(out_directory: pathlib.Path | None = None) -> pathlib.Path:
    """Runs lcm-gen -p on every definition; returns the generated package directory."""
    out = pathlib.Path(out_directory) if out_directory is not None else DEFINITIONS_DIRECTORY
    definitions = sorted(DEFINITIONS_DIRECTORY.glob("*.lcm"))
    subprocess.run([lcm_gen_executable(), "-p", "--ppath", str(out), *map(str, definitions)],
                   check=True, capture_output=True, text=True)
    return out / "telesmooth_lcmt"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=pathlib.Path, default=None)
    args = parser.parse_args(argv)
    print(generate(args.out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
