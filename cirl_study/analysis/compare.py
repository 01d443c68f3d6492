"""Two report directories compared number by number, within a stated tolerance.

A report is reproduced when its numbers are, not its bytes: the last bits of a float depend on
the CPU's and the BLAS kernels' rounding. :func:`compare_reports` compares ``results.json``
(every number of the report, recursively) and ``trials.csv`` (every measure of every trial)
of two report directories. Two numbers ``a`` (expected) and ``b`` agree when
``|a - b| <= atol + rtol * |a|``; strings, booleans, nulls, keys and row identities must be
equal. The figures and ``report.md`` are rendered from ``results.json``, so they are not
compared separately.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cirl_study.errors import UserError

RELATIVE_TOLERANCE = 1e-9
"""Default ``rtol``: far above the rounding of one CPU's run against another's where the
computation is well-conditioned, far below any difference a reader of the report could see."""

ABSOLUTE_TOLERANCE = 1e-12
"""Default ``atol``, for numbers that are zero in exact arithmetic."""


@dataclass(frozen=True)
class Tolerance:
    """``|expected - got| <= atol + rtol * |expected|``."""

    rtol: float = RELATIVE_TOLERANCE
    atol: float = ABSOLUTE_TOLERANCE

    def agree(self, expected: float, got: float) -> bool:
        if math.isnan(expected) or math.isnan(got):
            return math.isnan(expected) and math.isnan(got)
        return abs(expected - got) <= self.atol + self.rtol * abs(expected)


def compare_reports(expected: Path, got: Path, tolerance: Tolerance | None = None) -> list[str]:
    """Every difference between the report directories ``expected`` and ``got`` (empty if none).

    Raises:
        UserError: a directory lacks ``results.json`` or ``trials.csv``.
    """
    tolerance = tolerance or Tolerance()
    differences = list(
        _json_differences(_load_json(expected), _load_json(got), "results.json", tolerance)
    )
    differences += _table_differences(_load_csv(expected), _load_csv(got), tolerance)
    return differences


def _load_json(directory: Path) -> Any:
    path = directory / "results.json"
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise UserError(f"{path}: cannot read: {error}") from None


def _load_csv(directory: Path) -> list[dict[str, str]]:
    path = directory / "trials.csv"
    try:
        with path.open(newline="") as stream:
            return list(csv.DictReader(stream))
    except OSError as error:
        raise UserError(f"{path}: cannot read: {error.strerror}") from None


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _json_differences(a: Any, b: Any, where: str, tolerance: Tolerance) -> Iterator[str]:
    if _is_number(a) and _is_number(b):
        if not tolerance.agree(float(a), float(b)):
            yield f"{where}: {a!r} != {b!r}"
    elif isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            yield f"{where}: keys {sorted(set(a) ^ set(b))} are in only one report"
        for key in sorted(set(a) & set(b)):
            yield from _json_differences(a[key], b[key], f"{where}.{key}", tolerance)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            yield f"{where}: {len(a)} items != {len(b)} items"
        for index, (x, y) in enumerate(zip(a, b, strict=False)):
            yield from _json_differences(x, y, f"{where}[{index}]", tolerance)
    elif a != b or type(a) is not type(b):
        yield f"{where}: {a!r} != {b!r}"


def _table_differences(
    a: list[dict[str, str]], b: list[dict[str, str]], tolerance: Tolerance
) -> Iterator[str]:
    if len(a) != len(b):
        yield f"trials.csv: {len(a)} rows != {len(b)} rows"
    for index, (x, y) in enumerate(zip(a, b, strict=False)):
        where = f"trials.csv row {index + 2} ({x.get('trial_id')})"
        if list(x) != list(y):
            yield f"{where}: columns differ"
            continue
        for column, value in x.items():
            other = y[column]
            try:
                same = tolerance.agree(float(value), float(other))
            except ValueError:
                same = value == other
            if not same:
                yield f"{where}: {column} {value} != {other}"
