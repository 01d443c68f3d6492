"""Writing a report directory: one function for the paper report and the multiverse report.

Every file is written with ``\\n`` line ends and UTF-8, so identical results give identical
bytes on every platform; ``provenance.json`` (what made the report, which differs from machine
to machine by design) is apart from the numbers. A report replaces another by being written
into a fresh directory, swapped in whole (:mod:`cirl_study.analysis.report.replacement`).
"""

from __future__ import annotations

import io
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pandas as pd

from cirl_study.errors import UserError
from cirl_study.files import open_for_writing, write_file

CSV_FORMAT: dict[str, Any] = {"index": False, "lineterminator": "\n"}
"""How every table of a report is written as CSV (``DataFrame.to_csv``): no index, ``\\n``."""


FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")
"""First characters that make a spreadsheet read a cell as a formula (OWASP, CSV injection)."""


def spreadsheet_safe(frame: pd.DataFrame) -> pd.DataFrame:
    """``frame`` with every text cell and column name that starts with one of
    :data:`FORMULA_STARTS` prefixed by ``'``, so a spreadsheet shows it as text instead of
    running it (the OWASP rule for CSV injection). Numbers are left as they are: ``-0.5`` in
    a number column is a number to a spreadsheet too.

    >>> frame = pd.DataFrame({"human": ["=cmd()", "expert"], "x": [-0.5, 1.0]})
    >>> spreadsheet_safe(frame).to_dict("list")
    {'human': ["'=cmd()", 'expert'], 'x': [-0.5, 1.0]}
    """
    risky = {name: _formula_cells(frame[name]) for name in frame.columns}
    risky = {name: starts for name, starts in risky.items() if starts.any()}
    renamed = {name: f"'{name}" for name in frame.columns if _is_formula(name)}
    if not risky and not renamed:
        return frame
    safe = frame.copy()
    for name, starts in risky.items():
        safe[name] = safe[name].astype(object)
        safe.loc[starts, name] = "'" + safe.loc[starts, name].astype(str)
    return safe.rename(columns=renamed)


def _formula_cells(column: pd.Series) -> pd.Series:
    """Which cells of ``column`` are text a spreadsheet would run (all false for numbers)."""
    if not (pd.api.types.is_object_dtype(column) or pd.api.types.is_string_dtype(column)):
        return pd.Series(False, index=column.index)
    try:
        return column.str.startswith(FORMULA_STARTS, na=False).astype(bool)
    except AttributeError:  # text mixed with other values: cell by cell
        return column.map(_is_formula).astype(bool)


def _is_formula(value: object) -> bool:
    return isinstance(value, str) and value.startswith(FORMULA_STARTS)


def csv_file(frame: pd.DataFrame) -> bytes:
    """``frame`` as the CSV file :func:`write_report_directory` writes of it (spreadsheet
    safe: :func:`spreadsheet_safe`)."""
    return spreadsheet_safe(frame).to_csv(**CSV_FORMAT).encode("utf-8")


def write_report_directory(
    out_dir: Path | str,
    *,
    markdown: str,
    results: Mapping[str, Any],
    tables: Mapping[str, pd.DataFrame | bytes],
    figures: Mapping[str, bytes | None],
    provenance: Mapping[str, Any] | None,
) -> None:
    """Write ``report.md``, ``results.json``, the ``tables`` (CSV by file name: a frame, or
    its file as :func:`csv_file` made it), the ``figures`` (by file name; ``None``: a figure
    the run has no data for, not written) and ``provenance.json`` (if given) into
    ``out_dir``, created if needed. It writes in place: to replace a report, write it into
    the stage of :func:`~cirl_study.analysis.report.replacement.replacing_report`.

    Every file is written by :func:`cirl_study.files.write_file`: a link or anything but a
    regular file in a file's place is refused, never written through.

    Raises:
        UserError: the directory or a file cannot be written (one line, the OS's reason).
    """
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        write_file(out / "report.md", markdown.encode("utf-8"))
        text = json.dumps(results, indent=2, ensure_ascii=False, allow_nan=False)
        write_file(out / "results.json", (text + "\n").encode("utf-8"))
        for name, table in tables.items():
            if isinstance(table, bytes):
                write_file(out / name, table)
                continue
            with (
                open_for_writing(out / name) as stream,
                io.TextIOWrapper(stream, encoding="utf-8", newline="") as text_stream,
            ):
                # row by row: a large table is not held twice as text
                spreadsheet_safe(table).to_csv(text_stream, **CSV_FORMAT)
        if provenance is not None:
            text = json.dumps(provenance, indent=2, sort_keys=True, ensure_ascii=False)
            write_file(out / "provenance.json", (text + "\n").encode("utf-8"))
        for name, data in figures.items():
            if data is not None:
                write_file(out / name, data)
    except OSError as error:
        raise UserError(f"cannot write the report to {out}: {error.strerror}") from None
