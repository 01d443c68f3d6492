"""``cirl-study analyze RUN``: from MCAP logs to the report directory."""

from __future__ import annotations

import json
from pathlib import Path

from analysis_fixtures import synthetic_records
from typer.testing import CliRunner

from cirl_study.cli import app
from cirl_study.logs import TrialLogWriter

PROVENANCE = {"pipeline_name": "synthetic", "git_commit": "abc"}


def _run_directory(path: Path, records: list[dict]) -> Path:
    path.mkdir()
    halves = records[: len(records) // 2], records[len(records) // 2 :]
    for name, part in zip(("a.mcap", "b.mcap"), halves, strict=True):
        with TrialLogWriter(path / name, PROVENANCE) as log:
            for record in part:
                log.write(record)
    return path


def test_analyze_writes_the_report_under_reports_by_default(tmp_path, monkeypatch):
    records = synthetic_records(subjects_per_level=4, lambdas=(0.1, 1.0, 10.0), etas=(1.0,))
    run = _run_directory(tmp_path / "run", records)
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(app, ["analyze", str(run)])
    assert result.exit_code == 0, result.output
    out = tmp_path / "reports" / "synthetic"
    assert f"report of {len(records)} trials written to reports/synthetic: 10 claims" in (
        result.output
    )
    results = json.loads((out / "results.json").read_text(encoding="utf-8"))
    assert results["pipeline"] == "synthetic"
    assert results["trials"]["total"] == len(records)
    assert (out / "report.md").is_file() and (out / "figure1_reward_maps.png").is_file()


def test_analyze_of_a_missing_run_is_a_one_line_error(tmp_path):
    result = CliRunner().invoke(app, ["analyze", str(tmp_path / "nothing")])
    assert result.exit_code == 2
    assert result.output.strip().startswith("error: ") and "no such run directory" in result.output
    assert len(result.output.strip().splitlines()) == 1
