"""``cirl-study show RUN``: what a run is and how far it got, from its logs alone; and RUN
given as a pipeline's name for its run in data/runs, as ``cirl-study run NAME`` puts it."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cirl_study.cli import app
from cirl_study.logs.format import log_files

SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"


def invoke(*args: object):
    return CliRunner().invoke(app, [str(arg) for arg in args])


def test_a_complete_run_is_shown_with_its_counts(smoke_run: Path) -> None:
    result = invoke("show", smoke_run)
    assert result.exit_code == 0, result.output
    first, status, trials = result.stdout.splitlines()
    assert first.startswith("run smoke-") and first.endswith("log format 10")
    assert status == "status: complete"
    assert trials.startswith("trials: 82 of 82 planned, in ")
    assert trials.endswith("eta_cv 18 of 18, main 16 of 16, lambda_sweep 48 of 48")


def test_an_incomplete_run_is_shown_with_what_it_lacks_and_how_to_complete_it(
    smoke_run: Path, tmp_path: Path
) -> None:
    run = tmp_path / "run"
    shutil.copytree(smoke_run, run, ignore=shutil.ignore_patterns("report"))
    for path in log_files(run):
        if path.name.startswith("main-"):
            path.unlink()
    lines = invoke("show", run).stdout.splitlines()
    assert lines[1].startswith("status: incomplete (main: 16 of 16 trials missing); resume with ")
    assert "main 0 of 16" in lines[2]


def test_the_pipeline_shown_is_the_text_the_run_was_made_from(smoke_run: Path) -> None:
    result = invoke("show", smoke_run, "--pipeline")
    assert result.exit_code == 0, result.output
    assert result.stdout == SMOKE.read_text()


def test_a_directory_without_a_run_is_one_line(tmp_path: Path) -> None:
    result = invoke("show", tmp_path)
    assert result.exit_code == 2 and result.stderr.startswith("error: ")
    assert result.stderr.count("\n") == 1


@pytest.mark.parametrize("command", ["show", "validate", "analyze"])
def test_run_may_be_a_pipelines_name_for_its_run_in_data_runs(
    smoke_run: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, command: str
) -> None:
    monkeypatch.chdir(tmp_path)
    shutil.copytree(smoke_run, tmp_path / "data" / "runs" / "smoke")
    result = invoke(command, "smoke")
    assert result.exit_code == 0, result.output
    assert "no such run directory" not in result.output
