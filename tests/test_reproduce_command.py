"""``cirl-study reproduce``: run then analyze, resumable, byte-identical reports."""

import re
from pathlib import Path

from typer.testing import CliRunner

from cirl_study.cli import app

runner = CliRunner()


def _report_bytes(report: Path) -> dict[str, bytes]:
    """Every file of the report but provenance.json, which records when it was made."""
    return {
        path.name: path.read_bytes()
        for path in sorted(report.iterdir())
        if path.name != "provenance.json"
    }


def test_reproduce_runs_then_reports_and_a_second_call_changes_nothing(tmp_path: Path) -> None:
    run_dir, report = tmp_path / "run", tmp_path / "report"
    arguments = ["reproduce", "smoke", "--out", str(run_dir), "--report", str(report)]
    arguments += ["--workers", "1"]
    first = runner.invoke(app, arguments)
    assert first.exit_code == 0, first.output
    assert sorted(run_dir.glob("*.mcap")), "no log files written"
    assert {"report.md", "results.json", "trials.csv"} <= {p.name for p in report.iterdir()}
    written = _report_bytes(report)
    second = runner.invoke(app, arguments)
    assert second.exit_code == 0, second.output
    assert "0 played now" in second.output
    assert first.output.rstrip().endswith("a new report (there was none to compare with)")
    assert second.output.rstrip().endswith(
        f"{report}: equals the report there, number by number; its files are kept"
    )
    assert _report_bytes(report) == written
    timing = re.compile(r"^run [\d.]+ s, analysis [\d.]+ s \([\d.]+ x the run\)$", re.MULTILINE)
    assert timing.search(first.output) and timing.search(second.output)


def test_reproduce_refuses_an_unknown_pipeline_in_one_line(tmp_path: Path) -> None:
    result = runner.invoke(app, ["reproduce", "no-such-pipeline", "--out", str(tmp_path)])
    assert result.exit_code == 2
    assert result.output.count("\n") == 1 and result.output.startswith("error: ")
