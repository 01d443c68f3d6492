"""``cirl-study analyze RUN``: from MCAP logs to the report directory."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from cirl_study.cli import app


def test_analyze_writes_the_report_under_reports_by_default(tmp_path, monkeypatch, smoke_run):
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(app, ["analyze", str(smoke_run)])
    assert result.exit_code == 0, result.output
    out = tmp_path / "reports" / "smoke"
    assert result.output.startswith("report of 82 trials written to reports/smoke: 10 claims")
    results = json.loads((out / "results.json").read_text(encoding="utf-8"))
    assert results["pipeline"] == "smoke" and results["partial"] is None
    assert results["trials"]["total"] == 82
    assert (out / "report.md").is_file() and (out / "figure1_reward_maps.png").is_file()


def test_analyze_of_a_missing_run_is_a_one_line_error(tmp_path):
    result = CliRunner().invoke(app, ["analyze", str(tmp_path / "nothing")])
    assert result.exit_code == 2
    assert result.output.strip().startswith("error: ") and "no such run directory" in result.output
    assert len(result.output.strip().splitlines()) == 1
