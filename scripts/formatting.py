"""Numbers in reports (a ratio to a limit never hides a violation in its rounding) and the
command line's progress lines."""

from __future__ import annotations

import math
import sys

from telesmooth.smoothing.metrics import VIOLATION_RTOL

__all__ = ["figures_table", "limit_ratio", "log", "mean_worst_cell"]


def log(message: str) -> None:
    """A progress or status line on stderr, flushed at once (stdout is for results)."""
    print(message, file=sys.stderr, flush=True)


def limit_ratio(value, digits: int = 2) -> str:
    """A max/limit ratio for a table: ``digits`` decimals, but a value over the limit (beyond
    the round-off tolerance :data:`~telesmooth.smoothing.metrics.VIOLATION_RTOL`) gets as many
    decimals as it takes to show it above 1 (1.0021, not 1.00) and a ``!``.

    >>> limit_ratio(0.999), limit_ratio(1.0000001), limit_ratio(1.0021), limit_ratio(2.456)
    ('1.00', '1.00', '1.0021!', '2.46!')
    """
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    value = float(value)
    if value <= 1.0 + VIOLATION_RTOL:
        return f"{value:.{digits}f}"
    places = digits
    while float(f"{value:.{places}f}") <= 1.0 and places < 12:
        places += 1
    text = f"{value:.{places}f}"
    # One more significant place than it took to leave 1.00…, so the excess reads clearly.
    if places > digits:
        text = f"{value:.{places + 1}f}"
    return text + "!"


def _format(value, fmt: str) -> str:
    return limit_ratio(value) if fmt == "ratio" else fmt.format(value)


def mean_worst_cell(stats: dict | None, scale: float, fmt: str,
                    figures: dict | None = None) -> str:
    """"mean (worst)" of a figure over the demonstrations (``stats``: its ``mean`` and
    ``worst``), times ``scale``, in ``fmt`` (a format, or ``"ratio"``: :func:`limit_ratio`;
    ``"settling"``: a time that counts the runs still moving at their end, from
    ``figures["settled"]``); "n/a" without a value, "—" without the figure."""
    if stats is None:
        return "—"
    unsettled = ""
    if fmt == "settling":
        # Runs still moving at their end have no settling time: counted, not averaged.
        settled = (figures or {}).get("settled")
        if settled and settled["mean"] is not None and settled["mean"] < 1.0:
            unsettled = f"; {round((1 - settled['mean']) * settled['n'])} not settled"
        fmt = "{:.1f}"
    mean, worst = stats["mean"], stats["worst"]
    if mean is None:
        return "n/a" + unsettled
    return f"{_format(scale * mean, fmt)} ({_format(scale * worst, fmt)}){unsettled}"


def figures_table(rows: dict, columns, extra=None) -> str:
    """A markdown table of figures, one row per method of ``rows`` ({label: {figure: stats}}),
    one column per (title, figure, scale, fmt) of ``columns``, each cell
    :func:`mean_worst_cell`; ``extra``: (title, label → cell) appended."""
    titles = [title for title, *_ in columns] + ([extra[0]] if extra else [])
    lines = ["| method | " + " | ".join(titles) + " |", "|---|" + "---|" * len(titles)]
    for label, figures in rows.items():
        cells = [mean_worst_cell(figures.get(key), scale, fmt, figures)
                 for _, key, scale, fmt in columns]
        if extra:
            cells.append(extra[1](label))
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)
