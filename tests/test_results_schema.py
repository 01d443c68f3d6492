"""``results.json`` against its types (cirl_study.analysis.results.types) and the JSON Schemas
kept in ``docs/``: the schemas are the types', and every report's results decode under them
(CI runs this again on the reports it regenerates)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import msgspec
import pytest

from cirl_study.analysis.results.types import (
    SCHEMAS,
    MultiverseResults,
    StudyResults,
    checked,
    json_schema,
)
from cirl_study.errors import UserError

ROOT = Path(__file__).resolve().parent.parent
REPORTS = sorted(path.parent for path in (ROOT / "reports").glob("*/results.json"))


@pytest.mark.parametrize("name", sorted(SCHEMAS))
def test_the_committed_schemas_are_the_types(name: str) -> None:
    committed = json.loads((ROOT / "docs" / name).read_text(encoding="utf-8"))
    assert committed == json_schema(SCHEMAS[name]), (
        f"docs/{name} is stale: regenerate it with result_types.write_schemas('docs')"
    )


def test_every_report_directory_is_checked() -> None:
    assert {path.name for path in REPORTS} >= {
        "paper", "robots", "teaching", "teaching-small", "multiverse", "multiverse-small",
    }  # fmt: skip


def _p_values(value: object, path: str = "") -> list[tuple[str, dict]]:
    """Every object of ``value`` that holds a ``p`` (or ``p_tukey``), with its path."""
    found = []
    if isinstance(value, dict):
        if "p" in value or "p_tukey" in value:
            found.append((path, value))
        for key, item in value.items():
            found += _p_values(item, f"{path}.{key}")
    elif isinstance(value, list):
        for index, item in enumerate(value):
            found += _p_values(item, f"{path}[{index}]")
    return found


@pytest.mark.parametrize("report", REPORTS, ids=lambda path: path.name)
def test_every_results_json_decodes_under_its_type(report: Path) -> None:
    data = (report / "results.json").read_bytes()
    kind = MultiverseResults if report.name.startswith("multiverse") else StudyResults
    msgspec.json.decode(data, type=kind)
    for path, row in _p_values(json.loads(data)):
        key = "p_tukey" if "p_tukey" in row else "p"
        log10_key = "log10_p_tukey" if key == "p_tukey" else "log10_p"
        assert log10_key in row, f"{report.name}{path}: a p without its log10"
        if row[key] is not None and row[key] > 0:
            assert math.isclose(row[log10_key], math.log10(row[key]), rel_tol=1e-9, abs_tol=1e-9)
        if row[key] == 0.0:
            assert row[log10_key] < -307, f"{report.name}{path}: p = 0 stored without its bound"


def test_results_of_another_shape_are_refused_in_one_line() -> None:
    results = json.loads((ROOT / "reports" / "paper" / "results.json").read_text())
    results["cells"][0]["stray"] = 1.0
    with pytest.raises(UserError, match=r"unknown field `stray` - at `\$\.cells\[0\]`"):
        checked(results, StudyResults)
