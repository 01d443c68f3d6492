"""The Python API (cirl_study.api): the numbers of ``cirl-study analyze``, typed, without the
report; the same refusals, as one-line errors."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

import cirl_study
from cirl_study.analysis.results.types import StudyResults, checked
from cirl_study.cli import app
from cirl_study.errors import UserError
from cirl_study.logs.contents import read_file_contents


def test_analyze_returns_the_reports_results_typed(smoke_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "report"
    assert CliRunner().invoke(app, ["analyze", str(smoke_run), "--out", str(out)]).exit_code == 0
    written = checked(json.loads((out / "results.json").read_text()), StudyResults)
    assert cirl_study.analyze(smoke_run) == written
    table = cirl_study.load_trials(smoke_run)
    assert list(table["trial_id"]) == list(pd.read_csv(out / "trials.csv")["trial_id"])


def test_the_trial_table_names_the_log_file_of_each_trial(smoke_run: Path, tmp_path: Path) -> None:
    """Each row names the file of the run directory that holds its record, as trials.csv
    does: open it to find the trial."""
    table = cirl_study.load_trials(smoke_run)
    assert table.columns[-1] == "file"
    assert set(table["file"]) == {path.name for path in smoke_run.glob("*.mcap")}
    for name, trials in table.groupby("file")["trial_id"]:
        records = read_file_contents(smoke_run / name).records
        assert sorted(record.trial_id for record in records) == sorted(trials)
    out = tmp_path / "report"
    assert CliRunner().invoke(app, ["analyze", str(smoke_run), "--out", str(out)]).exit_code == 0
    written = pd.read_csv(out / "trials.csv")
    assert written["file"].tolist() == table["file"].tolist()


def test_an_incomplete_run_is_refused_unless_partial(smoke_run: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    shutil.copytree(smoke_run, run)
    next(iter(sorted(run.glob("lambda_sweep-*.mcap")))).unlink()
    with pytest.raises(UserError, match=r"not a complete run: lambda_sweep: .* missing"):
        cirl_study.analyze(run)
    results = cirl_study.analyze(run, partial=True)
    assert results.partial is not None and results.partial.logged < results.partial.planned


def test_the_package_exports_only_its_api() -> None:
    assert cirl_study.API == ("run", "load_trials", "analyze")
    with pytest.raises(AttributeError, match="has no attribute 'play'"):
        _ = cirl_study.play


def test_run_uses_every_core_by_default_as_the_command_does(monkeypatch, tmp_path: Path) -> None:
    from cirl_study.study import runner

    engines = []
    monkeypatch.setattr(runner, "run_pipeline", lambda spec, out, engine: engines.append(engine))
    monkeypatch.setattr("cirl_study.study.engines.cores", lambda: 7)
    cirl_study.run("smoke", tmp_path / "run")
    cirl_study.run("smoke", tmp_path / "run", workers=1)
    assert [engine.workers for engine in engines] == [7, 1]
