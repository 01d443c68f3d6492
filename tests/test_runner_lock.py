"""One writer per run directory: a second `run` is refused in one line and touches nothing."""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cirl_study.cli import app
from cirl_study.logs.lock import LOCK_NAME, writer_pid
from cirl_study.logs.reader import read_run
from cirl_study.logs.validate import validate_run
from cirl_study.study.pipeline_file import logged_pipeline

SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"

pytestmark = pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs SIGKILL")

_HOLD = (
    "import sys, time; from pathlib import Path; from cirl_study.logs.lock import writer_lock\n"
    "with writer_lock(Path(sys.argv[1])):\n"
    "    print('locked', flush=True); time.sleep(120)\n"
)

_HOLD_AND_FORK = (
    "import os, sys, time; from pathlib import Path; from cirl_study.logs.lock import writer_lock\n"
    "with writer_lock(Path(sys.argv[1])):\n"
    "    child = os.fork()\n"
    "    if child == 0:\n"  # the child speaks once its fork hooks have run
    "        print(os.getpid(), flush=True); time.sleep(120); os._exit(0)\n"
    "    time.sleep(120)\n"
)


def run(out: Path, workers: int) -> subprocess.Popen:
    command = [sys.executable, "-m", "cirl_study", "run", str(SMOKE), "--out", str(out)]
    return subprocess.Popen(
        [*command, "--workers", str(workers)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_a_held_directory_is_refused_until_its_holder_dies(tmp_path: Path) -> None:
    out = tmp_path / "run"
    out.mkdir()
    (out / "left-by-the-holder.mcap.tmp").write_bytes(b"in progress")
    holder = subprocess.Popen(
        [sys.executable, "-c", _HOLD, str(out)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline() == "locked\n"
        refused = run(out, 1)
        stdout, stderr = refused.communicate(timeout=120)
        assert refused.returncode == 2 and stdout == ""
        assert stderr == (
            f"error: {out}: another cirl-study run (pid {holder.pid}) is writing to it; "
            "wait for it to end, or use another --out directory\n"
        )
        # Nothing was played, and the holder's temporary file is untouched.
        assert sorted(p.name for p in out.iterdir()) == [
            LOCK_NAME,
            "left-by-the-holder.mcap.tmp",
        ]
    finally:
        os.kill(holder.pid, signal.SIGKILL)
        holder.wait()
    # kill -9 released the lock: the run goes ahead.
    resumed = run(out, 1)
    _, stderr = resumed.communicate(timeout=300)
    assert resumed.returncode == 0, stderr
    assert len(read_run(out, logged_pipeline).rows) == 82


@pytest.mark.parametrize("writers", [2, 3])
def test_concurrent_writers_one_proceeds_nothing_duplicated(tmp_path: Path, writers: int) -> None:
    out = tmp_path / "run"
    processes = [run(out, workers) for workers in range(1, writers + 1)]
    outcomes = [(p.wait(timeout=300), p.communicate()[1]) for p in processes]
    succeeded = [code for code, _ in outcomes if code == 0]
    refused = [err for code, err in outcomes if code == 2]
    # The first to take the lock plays; a later one either waits in line (the first already
    # finished) or is refused in one line; nobody fails otherwise.
    assert len(succeeded) >= 1 and len(succeeded) + len(refused) == writers
    assert all(err.count("\n") == 1 and "another cirl-study run (pid " in err for err in refused)
    verdict = validate_run(out, logged_pipeline)
    assert verdict.ok and verdict.trials == 82


def test_the_lock_ends_with_its_holder_not_with_the_children_it_forked(tmp_path: Path) -> None:
    out = tmp_path / "run"
    out.mkdir()
    holder = subprocess.Popen(
        [sys.executable, "-c", _HOLD_AND_FORK, str(out)], stdout=subprocess.PIPE, text=True
    )
    assert holder.stdout is not None
    child = int(holder.stdout.readline())
    try:
        assert writer_pid(out) == str(holder.pid)
        os.kill(holder.pid, signal.SIGKILL)
        holder.wait(timeout=10)
        os.kill(child, 0)  # the child is still there, and holds no lock
        assert writer_pid(out) is None
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(holder.pid, signal.SIGKILL)
        with contextlib.suppress(ProcessLookupError):
            os.kill(child, signal.SIGKILL)
        holder.wait(timeout=10)


def full_disk(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every ``os.pwrite`` fails as on a full disk: the first is the lock file's."""

    def pwrite(descriptor: int, data: bytes, offset: int) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "pwrite", pwrite)


def one_line(result) -> str:
    assert result.exit_code == 2, result.output
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.output, result.output
    return result.stderr


def test_a_full_disk_while_locking_a_run_is_one_line_and_keeps_everything(
    tmp_path: Path, smoke_run: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A new run directory is left as it was, that is not at all; a run there keeps every
    log file as it was."""
    full_disk(monkeypatch)
    new = tmp_path / "new" / "run"
    assert one_line(CliRunner().invoke(app, ["run", str(SMOKE), "--out", str(new)])) == (
        f"error: {new}: cannot lock the run directory: {new / LOCK_NAME}: No space left on "
        "device; no trial was played, and every log file there is kept\n"
    )
    assert not (tmp_path / "new").exists()
    old = tmp_path / "old"
    shutil.copytree(smoke_run, old)
    before = files(old)
    line = one_line(CliRunner().invoke(app, ["run", str(SMOKE), "--out", str(old)]))
    assert line.startswith(f"error: {old}: cannot lock the run directory: {old / LOCK_NAME}: ")
    assert files(old) == before


def test_a_full_disk_while_locking_a_report_is_one_line_and_keeps_it(
    tmp_path: Path, smoke_run: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    report = tmp_path / "report"
    report.mkdir()
    (report / "report.md").write_text("the report there\n")
    full_disk(monkeypatch)
    result = CliRunner().invoke(app, ["analyze", str(smoke_run), "--out", str(report)])
    assert one_line(result) == (
        f"error: {report}: cannot lock the report directory: {tmp_path / '.report.lock'}: No "
        "space left on device; the report there is unchanged\n"
    )
    assert files(report) == {"report.md": b"the report there\n"}


def files(directory: Path) -> dict[str, bytes]:
    """Every file of ``directory`` (the run's lock file aside) by name, with its bytes."""
    return {path.name: path.read_bytes() for path in directory.iterdir() if path.name != LOCK_NAME}
