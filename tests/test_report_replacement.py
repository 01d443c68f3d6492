"""A report is replaced atomically and by one writer (cirl_study.analysis.report.replacement): a
failure anywhere leaves the old report byte for byte and no temporary directory; a second
writer, a link as the report or its lock, and another run's report are refused in one line;
``reproduce`` keeps a report equal by value and judges ``git_dirty`` without its outputs."""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from cli_results import one_line_error
from typer.testing import CliRunner

from cirl_study.analysis.report import output, replacement
from cirl_study.analysis.report.replacement import replacing_report
from cirl_study.cli import app
from cirl_study.errors import UserError
from cirl_study.logs.provenance import git_state

VICTIM = "do not touch\n"


def snapshot(directory: Path) -> dict[str, bytes | str]:
    """Every entry under ``directory`` by relative path: a file's bytes, a link's target."""
    entries: dict[str, bytes | str] = {}
    for path in sorted(directory.rglob("*")):
        name = str(path.relative_to(directory))
        if path.is_symlink():
            entries[name] = f"-> {os.readlink(path)}"
        elif path.is_file():
            entries[name] = path.read_bytes()
    return entries


def temporaries(report: Path) -> list[Path]:
    return sorted(report.parent.glob(f".{report.name}.tmp-*"))


def analyze(run: Path, report: Path, *options: str):
    return CliRunner().invoke(app, ["analyze", str(run), "--out", str(report), *options])


@pytest.fixture(scope="module")
def old_report(smoke_run: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The smoke run's report, with a file of the user's, a subdirectory, a link of the
    user's and a stale figure no smoke report draws. Read-only: copy it first."""
    report = tmp_path_factory.mktemp("old") / "report"
    result = analyze(smoke_run, report)
    assert result.exit_code == 0, result.output
    (report / "README.md").write_text("kept by the user\n")
    (report / "notes").mkdir()
    (report / "notes" / "todo.txt").write_text("mine\n")
    (report / "elsewhere").symlink_to("../somewhere")
    (report / "robots_lambda.png").write_bytes(b"a figure of an older report")
    return report


@pytest.fixture
def report(old_report: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "report"
    shutil.copytree(old_report, copy, symlinks=True)
    return copy


@pytest.mark.parametrize("exchange", [True, False], ids=["renameat2", "two renames"])
def test_the_new_report_replaces_the_old_whole_and_the_users_files_stay(
    smoke_run: Path, report: Path, monkeypatch: pytest.MonkeyPatch, exchange: bool
) -> None:
    if not exchange:
        monkeypatch.setattr(replacement, "_renameat2", lambda: None)
    elif replacement._renameat2() is None:
        pytest.skip("no renameat2 here")
    users = {name: (report / name).stat().st_ino for name in ("README.md", "notes/todo.txt")}
    (report / "report.md").write_text("an old report\n")
    result = analyze(smoke_run, report)
    assert result.exit_code == 0, result.output
    assert "report of 82 trials written to" in result.output
    assert (report / "report.md").read_text().startswith("# ")
    assert not (report / "robots_lambda.png").exists()  # the report's: gone with the old one
    assert {name: (report / name).stat().st_ino for name in users} == users  # the user's
    assert os.readlink(report / "elsewhere") == "../somewhere"
    assert temporaries(report) == []


def test_a_full_disk_mid_write_leaves_the_old_report_whole(
    smoke_run: Path, report: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    before = snapshot(report)
    written: list[str] = []
    real_write = output.write_file

    def fills_up(path: Path, data: bytes) -> None:
        if len(written) == 2:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real_write(path, data[: len(data) // 2] if written else data)
        written.append(path.name)

    monkeypatch.setattr(output, "write_file", fills_up)
    message = one_line_error(analyze(smoke_run, report), "No space left on device")
    assert f"{report}:" in message and ".tmp-" not in message  # names the report, not the stage
    assert snapshot(report) == before
    assert temporaries(report) == []


@pytest.mark.parametrize("failure", [KeyboardInterrupt, RuntimeError])
def test_an_interruption_or_a_bug_mid_write_leaves_the_old_report_whole(
    report: Path, failure: type[BaseException]
) -> None:
    before = snapshot(report)
    with pytest.raises(failure), replacing_report(report, run_id="smoke-x", force=True) as new:
        (new.stage / "report.md").write_text("half")
        raise failure
    assert snapshot(report) == before and temporaries(report) == []


def test_a_failed_swap_leaves_the_old_report_whole(
    report: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    before = snapshot(report)

    def refused(*_: object) -> bool:
        raise OSError(errno.EIO, os.strerror(errno.EIO))

    monkeypatch.setattr(replacement, "_exchange", refused)
    with (
        pytest.raises(UserError, match="cannot write the report: Input/output error"),
        replacing_report(report, run_id="smoke-x", force=True) as new,
    ):
        (new.stage / "report.md").write_text("new")
    assert snapshot(report) == before and temporaries(report) == []


def test_the_temporary_directory_of_a_killed_writer_is_removed_by_the_next(
    report: Path,
) -> None:
    left = report.parent / f".{report.name}.tmp-killed"
    left.mkdir()
    (left / "report.md").write_text("half")
    with replacing_report(report, run_id="smoke-x", force=True) as new:
        (new.stage / "report.md").write_text("new\n")
    assert (report / "report.md").read_text() == "new\n" and temporaries(report) == []


_HOLD = (
    "import sys, time; from pathlib import Path\n"
    "from cirl_study.analysis.report.replacement import replacing_report\n"
    "with replacing_report(Path(sys.argv[1]), run_id='smoke-x', force=True):\n"
    "    print('writing', flush=True); time.sleep(120)\n"
)


def test_a_second_writer_is_refused_in_one_line_naming_the_first(
    smoke_run: Path, report: Path
) -> None:
    before = snapshot(report)
    holder = subprocess.Popen([sys.executable, "-c", _HOLD, str(report)], stdout=subprocess.PIPE)
    try:
        assert holder.stdout is not None and holder.stdout.readline() == b"writing\n"
        message = one_line_error(analyze(smoke_run, report), f"(pid {holder.pid})")
        assert message == (
            f"error: {report}: another cirl-study process (pid {holder.pid}) is writing this "
            "report; wait for it to end, or choose another report directory"
        )
        assert snapshot(report) == before
    finally:
        holder.kill()
        holder.wait()


def test_a_link_as_the_report_directory_or_its_lock_is_refused(
    smoke_run: Path, report: Path, tmp_path: Path
) -> None:
    linked = tmp_path / "linked"
    linked.symlink_to(report)
    before = snapshot(report)
    one_line_error(analyze(smoke_run, linked), str(linked), "symbolic link")
    assert linked.is_symlink() and snapshot(report) == before
    victim = tmp_path / "victim.txt"
    victim.write_text(VICTIM)
    (tmp_path / ".report.lock").unlink(missing_ok=True)
    (tmp_path / ".report.lock").symlink_to(victim)
    one_line_error(analyze(smoke_run, report), ".report.lock", "symbolic link")
    assert victim.read_text() == VICTIM and snapshot(report) == before
    assert temporaries(report) == [] and temporaries(linked) == []


def test_report_files_of_no_known_run_are_replaced_only_with_force(
    smoke_run: Path, tmp_path: Path
) -> None:
    report = tmp_path / "pictures"
    report.mkdir()
    (report / "holiday.png").write_bytes(b"not a figure of a report")
    one_line_error(analyze(smoke_run, report), "1 report file(s) but no report", "--force")
    assert (report / "holiday.png").read_bytes() == b"not a figure of a report"
    forced = analyze(smoke_run, report, "--force")
    assert forced.exit_code == 0, forced.output
    assert not (report / "holiday.png").exists()


def reproduce(run: Path, report: Path, *options: str):
    arguments = ["reproduce", "smoke", "--out", str(run), "--report", str(report)]
    return CliRunner().invoke(app, [*arguments, "--workers", "1", *options])


def test_reproduce_refuses_another_runs_report_before_running_unless_forced(
    smoke_run: Path, tmp_path: Path
) -> None:
    run, report = tmp_path / "run", tmp_path / "report"
    report.mkdir()
    (report / "results.json").write_text('{"run_id": "paper-0123456789ab"}')
    one_line_error(reproduce(run, report), "holds the report of paper-0123456789ab", "--force")
    assert not run.exists() and [p.name for p in report.iterdir()] == ["results.json"]
    shutil.copytree(smoke_run, run)
    forced = reproduce(run, report, "--force")
    assert forced.exit_code == 0, forced.output
    assert json.loads((report / "results.json").read_text())["run_id"].startswith("smoke-")


def _nudge(report: Path, factor: float) -> None:
    """Scale one number of ``results.json`` by ``factor``."""
    results = json.loads((report / "results.json").read_text())
    results["anova"][0]["F"] *= factor
    (report / "results.json").write_text(json.dumps(results, indent=1))


def test_reproduce_keeps_a_report_equal_by_value_byte_for_byte(
    smoke_run: Path, tmp_path: Path
) -> None:
    run, report = tmp_path / "run", tmp_path / "report"
    shutil.copytree(smoke_run, run)
    first = reproduce(run, report)
    assert first.exit_code == 0, first.output
    _nudge(report, 1 + 1e-12)  # a last-digit change, within the comparison's tolerance
    before = snapshot(report)
    mtimes = {path.name: path.stat().st_mtime_ns for path in report.iterdir()}
    kept = reproduce(run, report)
    assert kept.exit_code == 0, kept.output
    assert kept.output.rstrip().endswith(
        f"{report}: equals the report there, number by number; its files are kept"
    )
    assert snapshot(report) == before  # provenance.json too
    assert {path.name: path.stat().st_mtime_ns for path in report.iterdir()} == mtimes
    assert temporaries(report) == []
    _nudge(report, 1.01)
    replaced = reproduce(run, report)
    assert replaced.exit_code == 0, replaced.output
    assert "DIFFERS from the report it replaced in 1 place(s), e.g. results.json.anova[0].F" in (
        replaced.output
    )
    assert (report / "results.json").read_bytes() != before["results.json"]
    assert snapshot(report).keys() == before.keys() and temporaries(report) == []


def test_git_dirty_ignores_the_directories_a_command_writes(tmp_path: Path) -> None:
    checkout = tmp_path / "checkout"
    (checkout / "reports" / "paper").mkdir(parents=True)
    (checkout / "data" / "run").mkdir(parents=True)
    for name in ("code.py", "reports/paper/results.json", "data/run/main.mcap"):
        (checkout / name).write_text("committed\n")

    def git(*arguments: str) -> None:
        subprocess.run(["git", "-C", str(checkout), *arguments], check=True, capture_output=True)

    git("init", "-q")
    git("add", ".")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", "initial")
    outputs = (checkout / "reports" / "paper", checkout / "data" / "run")
    assert git_state(checkout, outputs)["git_dirty"] == "false"
    for name in ("reports/paper/results.json", "data/run/main.mcap"):
        (checkout / name).write_text("written again\n")
    assert git_state(checkout, ())["git_dirty"] == "true"
    assert git_state(checkout / "reports", outputs)["git_dirty"] == "false"
    assert git_state(checkout, (*outputs, tmp_path / "outside"))["git_dirty"] == "false"
    (checkout / "code.py").write_text("changed\n")
    assert git_state(checkout, outputs)["git_dirty"] == "true"


@pytest.mark.parametrize("where", ["the run itself", "around the run"])
def test_a_report_is_never_written_over_a_run(smoke_run: Path, tmp_path: Path, where: str) -> None:
    """``analyze RUN --out RUN`` (or a directory holding RUN) is refused before anything is
    written: the swap would take the files a live run makes meanwhile."""
    run = tmp_path / "around" / "run"
    shutil.copytree(smoke_run, run, ignore=shutil.ignore_patterns("report"))
    before = snapshot(run.parent)
    target = run if where == "the run itself" else run.parent
    message = one_line_error(analyze(run, target), "a run directory", "never written over a run")
    assert message.startswith(f"error: {target}: ")
    assert snapshot(run.parent) == before
    assert temporaries(target) == []


def test_a_report_inside_its_run_is_written(smoke_run: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    shutil.copytree(smoke_run, run, ignore=shutil.ignore_patterns("report"))
    result = CliRunner().invoke(app, ["analyze", str(run)])
    assert result.exit_code == 0, result.output
    assert (run / "report" / "report.md").is_file()


def test_a_file_made_in_the_old_report_during_the_swap_is_kept(
    report: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A file of the user's that appears after the user's files were linked, before the
    swap, moves into the new report, not out with the old one."""
    real_swap = replacement._swap

    def late(stage: Path, target: Path, *, present: bool) -> None:
        (target / "late.txt").write_text("written while the report was replaced\n")
        real_swap(stage, target, present=present)

    monkeypatch.setattr(replacement, "_swap", late)
    with replacing_report(report, run_id="smoke-x", force=True) as new:
        (new.stage / "report.md").write_text("new\n")
    assert (report / "late.txt").read_text() == "written while the report was replaced\n"
    assert (report / "report.md").read_text() == "new\n"
    assert (report / "README.md").read_text() == "kept by the user\n"
    assert temporaries(report) == []


def test_a_subdirectory_of_the_users_moves_whole_with_its_owner(
    smoke_run: Path, report: Path
) -> None:
    """The user's subdirectory is moved into the new report, not re-created: its inode, and
    its owner where this process may give it another, stay."""
    notes = report / "notes"
    if os.geteuid() == 0:
        os.chown(notes, 65534, 65534)
    before = notes.stat()
    result = analyze(smoke_run, report)
    assert result.exit_code == 0, result.output
    after = notes.stat()
    assert (after.st_ino, after.st_uid, after.st_gid) == (
        before.st_ino, before.st_uid, before.st_gid,
    )  # fmt: skip
    assert (notes / "todo.txt").read_text() == "mine\n"
