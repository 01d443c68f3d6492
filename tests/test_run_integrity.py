"""A run is exactly what its logs prove; no input ends in a traceback.

Every case asserts the exit code, a one-line message on stderr without a traceback, and that
no logged trial is lost: bad input is refused before anything is written; a mixed, incomplete
or corrupted run is refused by ``analyze`` and resume, reported by ``validate``, and, for an
incomplete one, completed by resuming into the records of an uninterrupted run.
"""

from __future__ import annotations

import io
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from cirl_study.cli import app
from cirl_study.errors import UserError
from cirl_study.logs.contents import read_file_contents
from cirl_study.logs.format import log_files
from cirl_study.logs.provenance import RunIdentity
from cirl_study.logs.reader import logged_run, read_run
from cirl_study.logs.scan import scan_file
from cirl_study.record import encode
from cirl_study.study.pipeline_file import logged_pipeline

SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"


def invoke(*args: str):
    return CliRunner().invoke(app, [str(arg) for arg in args])


def one_line(result, code: int, contains: str) -> str:
    """Assert the exit code and a single ``error:`` line on stderr holding ``contains``."""
    assert result.exit_code == code, result.output
    assert result.stderr.startswith("error: "), result.stderr
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr, result.stderr
    assert contains in result.stderr, result.stderr
    return result.stderr


def payloads(run: Path) -> dict[str, bytes]:
    """Every record a run's files hold (their intact chunks), by trial id, as logged."""
    return {
        record.trial_id: encode(record)
        for path in log_files(run)
        for record in read_file_contents(path).records
    }


@pytest.fixture
def run(tmp_path: Path, smoke_run: Path) -> Path:
    copy = tmp_path / "run"
    shutil.copytree(smoke_run, copy)
    return copy


def smoke_variant(tmp_path: Path, old: str, new: str) -> Path:
    text = SMOKE.read_text()
    assert old in text, old
    path = tmp_path / "variant.toml"
    path.write_text(text.replace(old, new, 1))
    return path


# --- bad input: refused before anything is written ------------------------------------------

OUT_OF_RANGE = {
    "lambda 1e308": ("rationalities = [0.1, 1.0, 10.0]", "rationalities = [1e308, 1.0]",
                     "lambda_sweep.rationalities must be a non-empty list of numbers in [0.0001"),
    "lambda tiny": ("rationality = 1.0\nhumans", "rationality = 1e-300\nhumans",
                    "main.rationality must be a number in [0.0001, 10000]"),
    "eta 1e308": ("etas = [0.1, 1.0, 10.0]", "etas = [0.1, 1e308]",
                  "eta_cv.etas must be a non-empty list of numbers in [1e-06, 1e+06]"),
    "sigma 1e155": ("sigma = 0.75", "sigma = 1e155", "game.sigma must be a number in [0.02, "),
    "sigma 1e-300": ("sigma = 0.75", "sigma = 1e-300", "game.sigma must be a number in [0.02, "),
    "sigma inf": ("sigma = 0.75", "sigma = inf", "game.sigma must be a number in [0.02, "),
    "features > cells": ("feature_levels = [3, 10]", "feature_levels = [3, 26]",
                         "game.feature_levels must be at most the 25 cells of the grid"),
    "huge grid": ("width = 5\nheight = 5", "width = 10000\nheight = 10000",
                  "one batch of trials would need about"),
    "too many trials": ("subjects = 4\nrationality", "subjects = 10000000\nrationality",
                        "more than the 2000000 one run may hold"),
}  # fmt: skip


@pytest.mark.parametrize("case", OUT_OF_RANGE)
def test_out_of_range_input_is_refused_before_anything_is_written(
    tmp_path: Path, case: str
) -> None:
    old, new, message = OUT_OF_RANGE[case]
    pipeline = smoke_variant(tmp_path, old, new)
    result = invoke("run", pipeline, "--out", tmp_path / "out")
    one_line(result, 2, message)
    assert not (tmp_path / "out").exists()


def test_a_byte_order_mark_a_directory_and_a_file_are_named_for_what_they_are(
    tmp_path: Path, run: Path
) -> None:
    bom = tmp_path / "bom.toml"
    bom.write_bytes(b"\xef\xbb\xbf" + SMOKE.read_bytes())
    one_line(
        invoke("run", bom, "--out", tmp_path / "out"), 2, "starts with a UTF-8 byte-order mark"
    )
    one_line(
        invoke("run", tmp_path, "--out", tmp_path / "out"), 2, "is a directory, not a pipeline"
    )
    assert not (tmp_path / "out").exists()
    a_file = next(run.glob("*.mcap"))
    one_line(invoke("validate", a_file), 2, "is a file, not a run directory")
    one_line(invoke("analyze", a_file), 2, "is a file, not a run directory")


# --- a run is what its logs prove ------------------------------------------------------------


def test_a_file_of_another_run_is_refused_everywhere(tmp_path: Path, run: Path) -> None:
    other = tmp_path / "other"
    variant = smoke_variant(tmp_path, "seed = 7", "seed = 8")
    assert invoke("run", variant, "--out", other).exit_code == 0
    before = payloads(run)
    shutil.copy(next(other.glob("main-*.mcap")), run / "zz-foreign.mcap")
    one_line(invoke("analyze", run, "--out", tmp_path / "report"), 2, "log files of 2 runs")
    one_line(invoke("analyze", run, "--partial", "--out", tmp_path / "r"), 2, "log files of 2 runs")
    one_line(invoke("run", SMOKE, "--out", run), 2, "log files of 2 runs")
    result = invoke("validate", run)
    assert result.exit_code == 1 and "files of 2 runs" in result.output
    assert not (tmp_path / "report").exists()
    (run / "zz-foreign.mcap").unlink()
    assert payloads(run) == before


@pytest.mark.parametrize("block", ["eta_cv", "main", "lambda_sweep"])
def test_a_missing_file_is_named_per_block_and_resumed(
    tmp_path: Path, run: Path, smoke_run: Path, block: str
) -> None:
    victim = sorted(run.glob(f"{block}-*.mcap"))[0]
    victim.unlink()
    kept = len(read_run(run, logged_pipeline).rows)
    missing = 82 - kept
    result = invoke("validate", run)
    assert result.exit_code == 1
    planned = {"eta_cv": 18, "main": 16, "lambda_sweep": 48}[block]
    unchecked = " (the study blocks are checked trial by trial once eta_cv is complete)"
    note = unchecked if block == "eta_cv" else ""
    expected = f"{block}: {missing} of {planned} trials missing{note}; resume with `cirl-study run "
    assert expected in result.output
    one_line(invoke("analyze", run, "--out", tmp_path / "report"), 2, expected)
    assert not (tmp_path / "report").exists()
    partial = invoke("analyze", run, "--partial", "--out", tmp_path / "partial")
    # The smoke run's main file holds a whole feature level: a design of one level is analysed.
    _check_partial_report(partial, tmp_path / "partial", kept, block, missing, planned)
    assert invoke("run", SMOKE, "--out", run).exit_code == 0
    assert payloads(run) == payloads(smoke_run)


def _check_partial_report(result, report: Path, kept, block, missing, planned) -> None:
    assert result.exit_code == 0, result.output
    assert result.output.startswith(f"partial report of {kept} trials written to ")
    first = (report / "report.md").read_text().splitlines()[0]
    assert first.startswith(
        f"**PARTIAL RUN: {kept} of 82 planned trials logged; {block}: {missing} of {planned} "
        "trials missing"
    )


def _flip(path: Path, offset: int) -> None:
    data = bytearray(path.read_bytes())
    data[offset] ^= 0x01
    path.write_bytes(bytes(data))


def _metadata_offset(path: Path) -> int:
    data = path.read_bytes()
    return data.index(b"pipeline_toml") + 20  # inside the provenance's pipeline text


def _summary_offset(path: Path) -> int:
    """A byte inside the summary's first record (the footer, 29 bytes before the closing
    8-byte magic, starts with opcode and length, then the summary's offset)."""
    data = path.read_bytes()
    return int.from_bytes(data[-28:-20], "little") + 20


SECTIONS = {
    "chunk": lambda path: scan_file(path).chunk_offsets[0] + 200,
    "provenance metadata": _metadata_offset,
    "summary": _summary_offset,
}


@pytest.mark.parametrize("section", SECTIONS)
def test_a_flipped_bit_is_caught_by_every_reader(
    tmp_path: Path, run: Path, smoke_run: Path, section: str
) -> None:
    victim = sorted(run.glob("main-*.mcap"))[0]
    _flip(victim, SECTIONS[section](victim))
    message = f"{victim}"
    one_line(invoke("analyze", run, "--out", tmp_path / "report"), 2, message)
    one_line(invoke("run", SMOKE, "--out", run), 2, message)
    result = invoke("validate", run)
    assert result.exit_code == 1 and f"FAIL {victim}" in result.output
    assert victim.exists() and not (tmp_path / "report").exists()
    victim.unlink()  # what the message advises: its trials are played again
    assert invoke("run", SMOKE, "--out", run).exit_code == 0
    assert payloads(run) == payloads(smoke_run)


@pytest.fixture(scope="module")
def one_file(tmp_path_factory: pytest.TempPathFactory, smoke_run: Path) -> Path:
    """A run directory holding one smoke log file (its pristine copy lies beside the run)."""
    base = tmp_path_factory.mktemp("one")
    (base / "run").mkdir()
    source = sorted(smoke_run.glob("main-*.mcap"))[0]
    shutil.copy(source, base / "pristine.mcap")
    shutil.copy(source, base / "run" / source.name)
    return base / "run" / source.name


@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_any_flipped_bit_anywhere_is_refused(one_file: Path, data) -> None:
    """Every byte of a log file is covered by a CRC or checked against one: magic, framing,
    chunks, metadata, summary and footer alike."""
    good = (one_file.parent.parent / "pristine.mcap").read_bytes()
    offset = data.draw(st.integers(0, len(good) - 1), label="offset")
    bit = data.draw(st.integers(0, 7), label="bit")
    damaged = bytearray(good)
    damaged[offset] ^= 1 << bit
    one_file.write_bytes(bytes(damaged))
    try:
        with pytest.raises(UserError, match=str(one_file)):
            read_run(one_file.parent, logged_pipeline)
        with pytest.raises(UserError, match=str(one_file)):
            logged_run(one_file.parent, identity_of(good), logged_pipeline)
    finally:
        one_file.write_bytes(good)


def identity_of(data: bytes) -> RunIdentity:
    from mcap.reader import make_reader

    (record,) = [m for m in make_reader(io.BytesIO(data)).iter_metadata() if m.name == "provenance"]
    return RunIdentity.of(record.metadata)


# --- unwritable outputs ----------------------------------------------------------------------


def test_an_output_below_a_regular_file_is_one_line(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    one_line(invoke("run", SMOKE, "--out", blocker / "run"), 2, "cannot create the run directory")
    one_line(invoke("run", SMOKE, "--out", blocker), 2, "exists and is not a directory")
    one_line(invoke("analyze", tmp_path / "nothing"), 2, "no such run directory")


def test_a_lock_that_cannot_be_taken_is_one_line(tmp_path: Path) -> None:
    out = tmp_path / "run"
    (out / ".cirl-study.lock").mkdir(parents=True)
    one_line(invoke("run", SMOKE, "--out", out), 2, "cannot lock the run directory")


def test_a_full_disk_ends_the_run_in_one_line_and_loses_nothing(tmp_path: Path) -> None:
    out = tmp_path / "run"
    limit = (
        "import resource, signal, sys\n"
        "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
        "resource.setrlimit(resource.RLIMIT_FSIZE, (18_000, 18_000))\n"
        "from cirl_study.cli import app\n"
        "sys.argv = ['cirl-study', 'run', sys.argv[1], '--out', sys.argv[2], '--workers', '1']\n"
        "app(prog_name='cirl-study')\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", limit, str(SMOKE), str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 2, done.stderr
    *progress, error = done.stderr.splitlines()  # plain progress lines, then the error
    assert "Traceback" not in done.stderr
    assert all(
        line.startswith(("trials: ", "preparing ", "numerical kernels ready in "))
        for line in progress
    ), progress
    assert error.startswith("error: ") and "cannot write the log (File too large)" in error
    assert error.endswith("trial(s) logged before are kept: fix the cause and run again to resume")
    logged = payloads(out) if list(out.glob("*.mcap")) else {}
    assert invoke("run", SMOKE, "--out", out).exit_code == 0
    after = payloads(out)
    assert all(after[trial] == payload for trial, payload in logged.items())
    assert len(after) == 82


def test_the_same_pipeline_under_another_name_is_the_same_run(tmp_path: Path, run: Path) -> None:
    copy = tmp_path / "renamed.toml"
    copy.write_bytes(SMOKE.read_bytes())
    before = payloads(run)
    result = invoke("run", copy, "--out", run)
    assert result.exit_code == 0, result.output
    assert "0 played now, 82 were already logged" in result.output
    assert payloads(run) == before
