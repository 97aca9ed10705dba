"""Saving report figures: one place for the format every report uses."""

from __future__ import annotations

from pathlib import Path

__all__ = ["FigureWriter"]


class FigureWriter:
    """Writes figures into a report folder and remembers (title, file name) in order.

    ``prefix`` goes in front of every file name and ``title_suffix`` after every title (one
    report with several sets of the same figures, e.g. one per experiment cell)."""

    def __init__(self, out: Path, *, dpi: int = 110, prefix: str = "",
                 title_suffix: str = ""):
        self.out = Path(out)
        self.dpi = dpi
        self.prefix = prefix
        self.title_suffix = title_suffix
        self.figures: list[tuple[str, str]] = []

    def save(self, fig, name: str, title: str) -> None:
        """Lays out, writes ``out/<prefix><name>`` and closes ``fig``."""
        import matplotlib.pyplot as plt

        from telesmooth.atomic_files import atomic_write

        name = self.prefix + name
        fig.tight_layout()
        try:
            with atomic_write(self.out / name, "wb") as handle:
                fig.savefig(handle, dpi=self.dpi, format=Path(name).suffix[1:] or None)
        finally:
            plt.close(fig)
        self.figures.append((title + self.title_suffix, name))
