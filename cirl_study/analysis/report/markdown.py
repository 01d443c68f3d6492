"""Small helpers to write GitHub-flavoured Markdown: numbers, tables, heading anchors."""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from typing import Any

from cirl_study.measure_registry import MEASURES

HIGHER_IS_BETTER = "↑"
"""The mark after the name of a measure of which a higher value is better, in tables and texts
(every other measure is a loss)."""


def measure_name(measure: str) -> str:
    """A registered measure as tables and measurement texts name it: its short name
    (:attr:`~cirl_study.measure_registry.Measure.short`), marked with
    :data:`HIGHER_IS_BETTER` where a higher value is better.

    Examples:
        >>> measure_name("kl")
        'KL'
    """
    registered = MEASURES[measure]
    return registered.short + ("" if registered.lower_is_better else f" {HIGHER_IS_BETTER}")


P_VALUES = ("p", "p_holm", "p_tukey")
"""Fields of the results shown as p-values."""

Column = str | Callable[[Any], str]
"""A column of a statistics table: a field of the rows (an attribute of the typed results,
:mod:`cirl_study.analysis.results.types`), or a function of the row."""


def number(value: float | int | None, digits: int = 4) -> str:
    """``value`` with ``digits`` significant digits; an undefined number as an en dash."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if isinstance(value, int):
        return str(value)
    return f"{value:.{digits}g}"


def p_value(value: float | None) -> str:
    """A p-value with three significant digits; 0 as the bound ``< 1e-300``.

    Every p-value of the study is accurate down to the smallest normal double (t and F tails
    by scipy's regularised incomplete beta, the Tukey tail by
    :func:`cirl_study.analysis.statistics.studentized_range.studentized_range_sf`), so a p of 0
    means the true value is below ``2.2e-308``: the bound printed holds.
    """
    if value is None:
        return "–"
    return "< 1e-300" if value == 0 else f"{value:.3g}"


def p_text(log10_p: float | None) -> str:
    """A p-value from its common logarithm, three significant digits, at any size:
    ``-545.52`` is ``3.02e-546``, where the double ``p`` itself is 0.

    Examples:
        >>> p_text(-545.52), p_text(-1.3010299956639813), p_text(None)
        ('3.02e-546', '0.05', '–')
    """
    if log10_p is None or not math.isfinite(log10_p):
        return "–"
    if log10_p > -300:
        return f"{10.0**log10_p:.3g}"
    exponent = math.floor(log10_p)
    mantissa = 10.0 ** (log10_p - exponent)
    if round(mantissa, 2) >= 10.0:
        mantissa, exponent = mantissa / 10.0, exponent + 1
    return f"{mantissa:.3g}e{exponent}"


def interval(low: float | None, high: float | None, digits: int = 4) -> str:
    """A confidence interval as ``[low, high]``."""
    return f"[{number(low, digits)}, {number(high, digits)}]"


def table(header: Sequence[str], rows: Sequence[Sequence[str]], numeric: Sequence[bool]) -> str:
    """A Markdown table; ``numeric`` columns are right-aligned. ``|`` in a cell is escaped."""
    align = ["---:" if flag else ":---" for flag in numeric]

    def line(cells: Sequence[str]) -> str:
        return "| " + " | ".join(str(cell).replace("|", "\\|") for cell in cells) + " |"

    return "\n".join([line(header), line(align), *(line(row) for row in rows)])


def svg_name(png_name: str) -> str:
    """The file name of a figure's SVG twin, beside its PNG ``png_name``."""
    return png_name.removesuffix(".png") + ".svg"


def image(alt: str, png_name: str) -> str:
    """A figure embedded by its PNG, with a link to its SVG twin."""
    return f"![{alt}]({png_name}) ([SVG]({svg_name(png_name)}))"


def document(sections: Sequence[Sequence[str]]) -> str:
    """A report's text: its non-empty sections (each a list of lines), a blank line apart."""
    return "\n\n".join("\n".join(section) for section in sections if section) + "\n"


def anchor(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped, spaces as ``-``."""
    return re.sub(r"[^a-z0-9 _-]", "", heading.strip().lower()).replace(" ", "-")


def formatted(rows: Sequence[Any], columns: Sequence[Column]) -> list[list[str]]:
    """The cells of ``rows``: a measure by its short name, a p-value (from its ``log10_``
    field where the row has one, so an underflowed p shows its value), a text, or a number
    (every report's tables; a column is a field of the rows or a function of a row)."""

    def cell(row: Any, column: Column) -> str:
        if callable(column):
            return column(row)
        value = getattr(row, column)
        if column == "measure":
            return measure_name(value)
        if column in P_VALUES:
            log10_p = getattr(row, f"log10_{column}", None)
            return p_value(value) if log10_p is None else p_text(log10_p)
        return value if isinstance(value, str) else number(value)

    return [[cell(row, column) for column in columns] for row in rows]


def ci(row: Any) -> str:
    """A row's 95% confidence interval, ``[ci95_low, ci95_high]``."""
    return interval(row.ci95_low, row.ci95_high)


def name(identifier: str) -> str:
    """A human's or robot's registered name as text: ``best_response`` is ``best response``."""
    return identifier.replace("_", " ")
