"""Writing a report directory: one function for the paper report and the multiverse report.

Every file is written with ``\\n`` line ends and UTF-8, so identical results give identical
bytes on every platform; ``provenance.json`` (what made the report, which differs from machine
to machine by design) is apart from the numbers.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pandas as pd

from cirl_study.errors import UserError

CSV_FORMAT: dict[str, Any] = {"index": False, "lineterminator": "\n"}
"""How every table of a report is written as CSV (``DataFrame.to_csv``): no index, ``\\n``."""


def csv_file(frame: pd.DataFrame) -> bytes:
    """``frame`` as the CSV file :func:`write_report_directory` writes of it."""
    return frame.to_csv(**CSV_FORMAT).encode("utf-8")


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
    its file as :func:`csv_file` made it), the
    ``figures`` (by file name; ``None`` removes a stale copy of a figure the run has no data
    for) and ``provenance.json`` (if given) into ``out_dir``, created if needed.

    Raises:
        UserError: the directory or a file cannot be written (one line, the OS's reason).
    """
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        (out / "report.md").write_text(markdown, encoding="utf-8", newline="\n")
        text = json.dumps(results, indent=2, ensure_ascii=False, allow_nan=False)
        (out / "results.json").write_text(text + "\n", encoding="utf-8", newline="\n")
        for name, table in tables.items():
            if isinstance(table, bytes):
                (out / name).write_bytes(table)
            else:
                table.to_csv(out / name, **CSV_FORMAT)
        if provenance is not None:
            text = json.dumps(provenance, indent=2, sort_keys=True, ensure_ascii=False)
            (out / "provenance.json").write_text(text + "\n", encoding="utf-8", newline="\n")
        for name, data in figures.items():
            if data is None:
                (out / name).unlink(missing_ok=True)
            else:
                (out / name).write_bytes(data)
    except OSError as error:
        raise UserError(f"cannot write the report to {out}: {error.strerror}") from None
