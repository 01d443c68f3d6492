"""Two report directories compared by value, within stated tolerances.

A report is reproduced when its numbers are, not its bytes: the last bits of a float depend on
the CPU's and the BLAS kernels' rounding. :func:`compare_reports` compares

* ``results.json`` (every number of the report, recursively) and every ``*.csv`` table
  (``trials.csv``: every measure of every trial; a multiverse's ``universes.csv``: every
  universe's verdicts and effects): two numbers ``a`` (expected) and ``b`` agree when
  ``|a - b| <= atol + rtol * |a|``; strings, booleans, nulls, keys and row identities must be
  equal; the columns of :data:`UNCOMPARED` are passed over;
* ``report.md``: the text must be identical (it prints numbers to four significant digits);
* every figure ``*.png`` of the expected directory: the same size, and at most
  :data:`PIXEL_SHARE` of the pixels differing by more than :data:`PIXEL_TOLERANCE` in a
  channel (anti-aliasing may move with the last bits of a coordinate); its vector twin
  ``*.svg`` must exist (its path coordinates carry the same last bits, so it is not compared
  byte by byte).

``provenance.json`` says what made the report: it differs by design and is not compared, but
for the runs it names: two reports of different runs (another pipeline, or another version of
it) are said to be so first, before the differences that follow from it.

Either directory may come from someone else. Every name and value a difference quotes from
them (a file name, a key, a column, a row's id, a cell, a line of text) is escaped and bounded
by :func:`~cirl_study.escape.terminal`, so the differences print as they are; a file that
cannot be read as what it should be (JSON, UTF-8 CSV or text, PNG) is a
:class:`~cirl_study.errors.UserError`, never a traceback.
"""

from __future__ import annotations

import csv
import io
import itertools
import json
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cirl_study.errors import UserError
from cirl_study.escape import terminal
from cirl_study.files import UnreadableFile, read_regular_file

RELATIVE_TOLERANCE = 1e-9
"""Default ``rtol``: far above the rounding of one CPU's run against another's where the
computation is well-conditioned, far below any difference a reader of the report could see."""

ABSOLUTE_TOLERANCE = 1e-12
"""Default ``atol``, for numbers that are zero in exact arithmetic."""

PIXEL_TOLERANCE = 8 / 255
"""Largest difference of a channel (on a 0..1 scale) at which two pixels count as equal."""

PIXEL_SHARE = 1e-3
"""Largest share of a figure's pixels that may differ beyond :data:`PIXEL_TOLERANCE`."""

UNCOMPARED = {"trials.csv": frozenset({"file"})}
"""Columns of a table that two reproductions of a report may differ in, by table: the log
file that holds a trial depends on how its run was cut into batches (on the number of workers
that played it), not on the trial (:data:`cirl_study.analysis.table.FILE`)."""

MAX_REPORT_FILE_BYTES = 1 << 29
"""Largest file of a report read (512 MiB: a trial table of over a million trials); a report
directory may come from someone else. A file is read whole as bytes; a table is then
decoded and compared row by row, never held as text or rows, so it costs about its size."""

MAX_JSON_VALUES = 4_000_000
"""Most values (objects, arrays, numbers, strings, ...) a ``results.json`` may hold, counted
from its bytes before it is parsed (every ``{``, ``[``, ``,`` and ``:`` may start one, so
the count bounds them from above): a parsed value costs Python 50 to 100 bytes, so the
largest accepted file parses into well under a gigabyte. A multiverse of 53 universes
holds about 10^5."""

MAX_FIGURE_PIXELS = 16_000_000
"""Most pixels of a figure compared (e.g. 4000 x 4000), read from the PNG's header before it
is decoded: decoded, a pixel is four 32-bit floats. The report's figures have about 10^6."""


@dataclass(frozen=True)
class Tolerance:
    """``|expected - got| <= atol + rtol * |expected|``."""

    rtol: float = RELATIVE_TOLERANCE
    atol: float = ABSOLUTE_TOLERANCE

    def agree(self, expected: float, got: float) -> bool:
        """Whether ``got`` equals ``expected`` within the tolerance: NaN agrees with NaN, an
        infinity only with the same infinity. A tolerance may be infinite: ``atol = inf``
        agrees any two finite numbers, ``rtol = inf`` any two with ``expected`` non-zero
        (``rtol |expected|`` is 0 at ``expected = 0``, whatever ``rtol``).

        Examples:
            >>> Tolerance().agree(math.inf, math.inf), Tolerance().agree(math.inf, 1e308)
            (True, False)
            >>> loose = Tolerance(rtol=math.inf)
            >>> loose.agree(0.0, 0.0), loose.agree(2.0, 1e300), loose.agree(0.0, 1.0)
            (True, True, False)
        """
        if math.isnan(expected) or math.isnan(got):
            return math.isnan(expected) and math.isnan(got)
        if math.isinf(expected) or math.isinf(got):
            return expected == got
        # rtol scales |expected|: an expected 0 is matched within atol alone, also at rtol = inf.
        relative = self.rtol * abs(expected) if expected != 0 else 0.0
        return abs(expected - got) <= self.atol + relative


def compare_reports(expected: Path, got: Path, tolerance: Tolerance | None = None) -> list[str]:
    """Every difference between the report directories ``expected`` and ``got`` (empty if none).

    Raises:
        UserError: a directory lacks ``results.json``, the expected one any ``*.csv`` table,
            or the other a table the expected one has.
    """
    tolerance = tolerance or Tolerance()
    differences = _run_difference(expected, got)
    differences += _json_differences(
        _load_json(expected), _load_json(got), "results.json", tolerance
    )
    tables = sorted(path.name for path in expected.glob("*.csv"))
    if not tables:
        raise UserError(f"{expected}: no table (*.csv) to compare")
    for name in tables:
        differences += _table_differences(name, expected / name, got / name, tolerance)
    differences += _text_differences(expected / "report.md", got / "report.md")
    for figure in sorted(expected.glob("*.png")):
        differences += _figure_differences(figure, got / figure.name)
    differences += [
        f"{terminal(vector.name)}: missing"
        for vector in sorted(expected.glob("*.svg"))
        if not (got / vector.name).is_file()
    ]
    return differences


def _run_difference(expected: Path, got: Path) -> list[str]:
    """``["provenance.json: ..."]`` when both reports say which runs made them and the runs
    differ, else ``[]`` (a report without a readable provenance is compared by its numbers
    alone)."""
    runs = [_runs_of(expected), _runs_of(got)]
    if None in runs or runs[0] == runs[1]:
        return []
    shown = [", ".join(terminal(run) for run in sorted(r or ())) or "none" for r in runs]
    return [
        f"provenance.json: the reports are of different runs (expected: {shown[0]}; got: "
        f"{shown[1]}), made from different pipelines or versions of one: the differences "
        "below follow from that"
    ]


def _runs_of(directory: Path) -> frozenset[str] | None:
    """The run ids ``provenance.json`` of ``directory`` names, or ``None`` without one."""
    path = directory / "provenance.json"
    if not path.is_file():
        return None
    try:
        provenance = json.loads(_read(path).decode("utf-8"))
    except (ValueError, RecursionError, UserError):
        return None
    runs = provenance.get("run") if isinstance(provenance, dict) else None
    if not isinstance(runs, list):
        return None
    return frozenset(
        str(run["run_id"]) for run in runs if isinstance(run, dict) and "run_id" in run
    )


def _read(path: Path) -> bytes:
    """The bytes of a report's file, which must be a regular file (not a link, a FIFO or a
    device) of at most :data:`MAX_REPORT_FILE_BYTES`."""
    try:
        return read_regular_file(path, MAX_REPORT_FILE_BYTES)
    except UnreadableFile as error:
        raise UserError(str(error)) from None


def _load_json(directory: Path) -> Any:
    path = directory / "results.json"
    data = _read(path)
    values = sum(data.count(mark) for mark in (b"{", b"[", b",", b":"))
    if values > MAX_JSON_VALUES:
        raise UserError(
            f"{path}: cannot read: up to {values} values, more than the {MAX_JSON_VALUES} a "
            "report's results hold"
        )
    try:
        return json.loads(data.decode("utf-8"))
    except (ValueError, RecursionError) as error:
        raise UserError(f"{path}: cannot read: {_reason(error)}") from None


def _csv_rows(path: Path) -> Iterator[list[str]]:
    """The rows of a table, its header first, one at a time, decoded as they are read: the
    table costs its bytes, not a decoded copy of them."""
    text = io.TextIOWrapper(io.BytesIO(_read(path)), encoding="utf-8", newline="")
    rows = csv.reader(text)
    while True:
        try:
            row = next(rows, None)
        except (ValueError, csv.Error) as error:
            raise UserError(f"{path}: cannot read: {_reason(error)}") from None
        if row is None:
            return
        yield row


def _read_lines(path: Path) -> list[str]:
    try:
        return _read(path).decode("utf-8").splitlines()
    except ValueError as error:
        raise UserError(f"{path}: cannot read: {_reason(error)}") from None


def _reason(error: BaseException) -> str:
    """Why a file could not be read: an OS error's reason, else the error's message."""
    return (error.strerror if isinstance(error, OSError) else None) or str(error)


def _shown(value: Any) -> str:
    """A value of a report as a difference quotes it: its ``repr``, bounded."""
    return terminal(repr(value))


def _numbers_agree(a: float, b: float, tolerance: Tolerance) -> bool:
    try:
        return tolerance.agree(float(a), float(b))
    except OverflowError:  # an integer beyond every float
        return a == b


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _json_differences(a: Any, b: Any, where: str, tolerance: Tolerance) -> Iterator[str]:
    """The differences between the JSON values ``a`` and ``b`` at ``where`` (the path of keys
    and indices to them, raw: it is escaped where a difference quotes it)."""
    if _is_number(a) and _is_number(b):
        if not _numbers_agree(a, b, tolerance):
            yield f"{terminal(where)}: {_shown(a)} != {_shown(b)}"
    elif isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            only = _shown(sorted(set(a) ^ set(b)))
            yield f"{terminal(where)}: keys {only} are in only one report"
        for key in sorted(set(a) & set(b)):
            yield from _json_differences(a[key], b[key], f"{where}.{key}", tolerance)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            yield f"{terminal(where)}: {len(a)} items != {len(b)} items"
        for index, (x, y) in enumerate(zip(a, b, strict=False)):
            yield from _json_differences(x, y, f"{where}[{index}]", tolerance)
    elif a != b or type(a) is not type(b):
        yield f"{terminal(where)}: {_shown(a)} != {_shown(b)}"


def _table_differences(name: str, expected: Path, got: Path, tolerance: Tolerance) -> Iterator[str]:
    """The differences between the tables ``expected`` and ``got``, row by row: the same
    columns, then each cell (numbers within ``tolerance``, text equal), then the same number
    of rows."""
    ours, theirs = _csv_rows(expected), _csv_rows(got)
    header, other = next(ours, []), next(theirs, [])
    for path, names in ((expected, header), (got, other)):
        repeated = [name for position, name in enumerate(names) if name in names[:position]]
        if repeated:  # a row would keep only its last cell of that name
            raise UserError(f"{path}: cannot read: names the column {terminal(repeated[0])} twice")
    if header != other:
        for _ in itertools.chain(ours, theirs):  # each table is still read whole
            pass
        yield f"{terminal(name)}: columns {_shown(header)} != {_shown(other)}"
        return
    rows = 0
    for rows, (x, y) in enumerate(itertools.zip_longest(ours, theirs), start=1):
        if x is None or y is None:
            a, b = rows - 1 + sum(1 for _ in ours), rows - 1 + sum(1 for _ in theirs)
            yield f"{terminal(name)}: {a + (x is not None)} rows != {b + (y is not None)} rows"
            return
        yield from _row_differences(name, header, rows + 1, x, y, tolerance)


def _row_differences(
    name: str, header: list[str], line: int, x: list[str], y: list[str], tolerance: Tolerance
) -> Iterator[str]:
    """The differences between the rows ``x`` and ``y`` at ``line`` of a table (but in its
    columns of :data:`UNCOMPARED`)."""
    cells = dict(zip(header, x, strict=False))
    where = (
        f"{terminal(name)} row {line} ({terminal(cells.get('trial_id', cells.get('universe')))})"
    )
    if len(x) != len(header) or len(y) != len(header):
        yield f"{where}: {len(x)} and {len(y)} cells where the header has {len(header)}"
        return
    passed_over = UNCOMPARED.get(name, frozenset())
    for column, value, other in zip(header, x, y, strict=True):
        if column in passed_over:
            continue
        try:
            same = tolerance.agree(float(value), float(other))
        except ValueError:  # text
            same = value == other
        if not same:
            yield f"{where}: {terminal(column)} {terminal(value)} != {terminal(other)}"


def _text_differences(expected: Path, got: Path) -> list[str]:
    if not expected.exists():
        return [f"{expected.name}: missing from the expected report"]
    if not got.exists():
        return [f"{got.name}: missing"]
    lines, others = _read_lines(expected), _read_lines(got)
    for number, (line, other) in enumerate(zip(lines, others, strict=False), start=1):
        if line != other:
            return [f"{got.name} line {number}: {_shown(line[:80])} != {_shown(other[:80])}"]
    if len(lines) != len(others):
        return [f"{got.name}: {len(lines)} lines != {len(others)} lines"]
    return []


def _figure_differences(expected: Path, got: Path) -> list[str]:
    name = terminal(got.name)
    if not got.exists():
        return [f"{name}: missing"]
    a, b = _read_image(expected), _read_image(got)
    if a.shape != b.shape:
        return [f"{name}: {a.shape} pixels != {b.shape}"]
    share = float((np.abs(a - b) > PIXEL_TOLERANCE).any(axis=-1).mean())
    if share > PIXEL_SHARE:
        return [f"{name}: {share:.2%} of the pixels differ (at most {PIXEL_SHARE:.2%})"]
    return []


def _read_image(path: Path) -> np.ndarray:
    """A PNG's pixels; Pillow, which reads it, reports a file that is not one as a syntax
    error and an image too large to decode safely as a decompression bomb."""
    from matplotlib.image import imread
    from PIL.Image import DecompressionBombError

    data = _read(path)
    if data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR":
        width, height = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
        if width * height > MAX_FIGURE_PIXELS:
            raise UserError(
                f"{path}: cannot read: {width} x {height} pixels, more than the "
                f"{MAX_FIGURE_PIXELS} a report's figure has"
            )
    try:
        return imread(io.BytesIO(data), format="png")
    except (OSError, ValueError, SyntaxError, DecompressionBombError) as error:
        raise UserError(f"{path}: cannot read: {_reason(error)}") from None
