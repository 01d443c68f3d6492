"""Nothing the project writes goes through a link or into anything but a regular file
(cirl_study.files): the lock file, a log's temporary file and every file of a report (a
link in an old report leaves with it: cirl_study.analysis.report.replacement). Each
case plants the hostile entry, runs the command, and checks one line, a non-zero exit and
the target outside untouched."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from cli_results import one_line_error
from test_logs_helpers import provenance_for
from typer.testing import CliRunner

from cirl_study.cli import app
from cirl_study.errors import UserError
from cirl_study.files import open_for_writing, write_file
from cirl_study.logs.lock import LOCK_NAME

SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"
VICTIM = "do not touch\n"


def victim(tmp_path: Path) -> Path:
    path = tmp_path / "victim.txt"
    path.write_text(VICTIM)
    return path


def test_a_link_in_place_of_the_lock_file_is_refused(tmp_path: Path) -> None:
    target = victim(tmp_path)
    run = tmp_path / "run"
    run.mkdir()
    (run / LOCK_NAME).symlink_to(target)
    result = CliRunner().invoke(app, ["run", str(SMOKE), "--out", str(run)])
    one_line_error(result, LOCK_NAME, "symbolic link")
    assert target.read_text() == VICTIM and not list(run.glob("*.mcap"))


def test_a_link_in_place_of_a_logs_temporary_file_is_refused(tmp_path: Path) -> None:
    from cirl_study.logs.format import temp_path
    from cirl_study.logs.writer import TrialLogWriter

    target = victim(tmp_path)
    path = tmp_path / "main-0000.mcap"
    temp_path(path).symlink_to(target)
    with pytest.raises(UserError, match="symbolic link"):
        TrialLogWriter(path, provenance=provenance_for()).__enter__()
    assert target.read_text() == VICTIM


@pytest.mark.parametrize("name", ["report.md", "results.json", "trials.csv", "eta_cv.png"])
def test_a_link_in_a_report_directory_is_replaced_not_written_through(
    smoke_run: Path, tmp_path: Path, name: str
) -> None:
    """The new report is written into a fresh directory: a link in the old one in place of
    a file of the report leaves with the old report, and what it points to stays."""
    target = victim(tmp_path)
    report = tmp_path / "report"
    report.mkdir()
    (report / name).symlink_to(target)
    result = CliRunner().invoke(app, ["analyze", str(smoke_run), "--out", str(report), "--force"])
    assert result.exit_code == 0, result.output
    assert (report / name).is_file() and not (report / name).is_symlink()
    assert target.read_text() == VICTIM


def test_a_stale_figure_that_is_a_link_is_removed_not_followed(
    smoke_run: Path, tmp_path: Path
) -> None:
    """A report without a robots comparison leaves a stale robots figure with the old report:
    a link there is removed itself, and what it points to stays."""
    target = victim(tmp_path)
    report = tmp_path / "report"
    report.mkdir()
    (report / "robots_lambda.png").symlink_to(target)
    result = CliRunner().invoke(app, ["analyze", str(smoke_run), "--out", str(report), "--force"])
    assert result.exit_code == 0, result.output
    assert not (report / "robots_lambda.png").is_symlink() and target.read_text() == VICTIM


def test_a_fifo_or_a_directory_in_a_files_place_is_refused_without_hanging(
    tmp_path: Path,
) -> None:
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(UserError, match="is not a regular file"):
        write_file(fifo, b"x")
    (tmp_path / "directory").mkdir()
    with pytest.raises(UserError, match="is not a regular file"):
        open_for_writing(tmp_path / "directory")


def test_a_regular_file_is_replaced_whole(tmp_path: Path) -> None:
    path = tmp_path / "file"
    path.write_text("a longer old content\n")
    write_file(path, b"new\n")
    assert path.read_bytes() == b"new\n"
