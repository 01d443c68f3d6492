"""A run directory from someone else: every entry and every size in it is checked, not believed.

Each case builds the hostile input in a copy of the smoke run (a FIFO, a directory or a link
named like a log, decompression bombs of every compression with their sizes declared or lied
about, a record or a pipeline nested thousands deep, counts and indexes that lie) and runs
the command line on it: ``validate`` fails the file with what is wrong and reads the others,
``analyze`` and resuming ``run`` refuse in one line naming the file, and ``analyze --partial``
reports it and reads the rest of the run. Small bounds are patched in where a real-size input
would be slow to build; the real bounds are checked on real-size bombs too.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import struct
import time
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path

import lz4.frame
import mcap.writer
import pytest
import zstandard
from typer.testing import CliRunner

import cirl_study.logs.writer as log_writer
from cirl_study.cli import app
from cirl_study.logs import bounds
from cirl_study.logs.contents import read_file_contents
from cirl_study.logs.writer import TrialLogWriter
from cirl_study.record import TrialRecord, encode

SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"
TRIALS = 82
"""Trials of the smoke run."""
GiB = 1 << 30


@pytest.fixture(autouse=True)
def no_hang() -> Iterator[None]:
    """Fail a case that blocks (on a FIFO, say) instead of hanging the suite."""

    def stop(signum: int, frame: object) -> None:
        raise TimeoutError("the command hung")

    previous = signal.signal(signal.SIGALRM, stop)
    signal.alarm(60)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, previous)


@pytest.fixture
def run(tmp_path: Path, smoke_run: Path) -> Path:
    copy = tmp_path / "run"
    shutil.copytree(smoke_run, copy)
    return copy


def invoke(*args: object):
    return CliRunner().invoke(app, [str(arg) for arg in args])


def one_line(result, *fragments: str) -> str:
    """Exit code 2 and a single ``error:`` line holding every fragment, no traceback."""
    assert result.exit_code == 2, result.output
    assert result.stderr.startswith("error: "), result.stderr
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr, result.stderr
    for fragment in fragments:
        assert fragment in result.stderr, result.stderr
    return result.stderr


def refused_by_every_reader(run: Path, victim: Path, fault: str, report: Path) -> None:
    """``validate`` fails ``victim`` with ``fault`` and passes every other file; ``analyze``
    and a resumed ``run`` refuse in one line; nothing is written or lost."""
    before = entries(run)
    result = invoke("validate", run)
    assert result.exit_code == 1 and "Traceback" not in result.output, result.output
    lines = result.output.splitlines()
    (failed,) = [line for line in lines[:-1] if line.startswith("FAIL ")]
    assert failed.startswith(f"FAIL {victim}: ") and fault in failed, failed
    assert sum(line.startswith("OK ") for line in lines) == len(lines) - 2
    one_line(invoke("analyze", run, "--out", report), str(victim), fault)
    one_line(invoke("run", SMOKE, "--out", run), str(victim), fault)
    assert not report.exists()
    assert entries(run) == before


def entries(run: Path) -> dict[str, tuple[int, int, int]]:
    """Every entry of ``run`` (the lock file aside) by name: its mode, size and time."""
    return {
        entry.name: (status.st_mode, status.st_size, status.st_mtime_ns)
        for entry in run.iterdir()
        if entry.name != ".cirl-study.lock"
        for status in [entry.lstat()]
    }


def partial_reads_the_rest(run: Path, report: Path, kept: int, *warnings: str) -> None:
    """``analyze --partial`` warns of each fragment and reports on at least ``kept`` trials
    (every trial of the files not refused)."""
    result = invoke("analyze", run, "--partial", "--out", report)
    assert result.exit_code == 0, result.output
    assert "Traceback" not in result.output
    reported = result.stdout.removeprefix("partial report of ").split(" ")[0]
    assert int(reported) >= kept, result.stdout
    for warning in warnings:
        assert warning in result.stderr, result.stderr


def victim_of(run: Path) -> Path:
    """The first log file of the main block (8 trials)."""
    return sorted(run.glob("main-*.mcap"))[0]


# --- building hostile files -------------------------------------------------------------------


def rewrite(path: Path, *, tweak: Callable[[TrialLogWriter], None] = lambda log: None) -> None:
    """Write the log ``path`` again from its records and provenance, ``tweak`` applied to the
    writer before it closes the file (the file is sound unless a patch or ``tweak`` says)."""
    contents = read_file_contents(path)
    path.unlink()
    with TrialLogWriter(path, contents.provenance, chunk_size=3000) as log:
        for record in contents.records:
            log.write(record)
        tweak(log)


def inflating(head: bytes, pad: int, compression: str, one_record: bool) -> tuple[bytes, int, int]:
    """``head`` then ``pad`` more bytes, compressed without a content size, streamed (never
    held whole): zero bytes (empty records of opcode 0), or with ``one_record`` a single
    record of unknown opcode holding them. Returns the data, its size and its CRC."""
    tail = struct.pack("<BQ", 0x80, pad - 9) if one_record else b""
    first = head + tail
    if compression == "zstd":
        compressor = zstandard.ZstdCompressor(write_content_size=False).compressobj()
        out = [compressor.compress(first)]
    else:
        compressor = lz4.frame.LZ4FrameCompressor()
        out = [compressor.begin(), compressor.compress(first)]
    crc, left, zeros = zlib.crc32(first), pad - len(tail), bytes(1 << 20)
    while left:
        piece = zeros[: min(left, len(zeros))]
        out.append(compressor.compress(piece))
        crc = zlib.crc32(piece, crc)
        left -= len(piece)
    out.append(compressor.flush())
    return b"".join(out), len(first) + pad - len(tail), crc


@contextlib.contextmanager
def bombs(
    pad: int, compression: str, *, lie: bool = False, every: bool = False, one_record: bool = False
) -> Iterator[None]:
    """Make the writer's first chunk (every chunk with ``every``) inflate by ``pad`` bytes more;
    with ``lie`` the chunk announces only its records' size and CRC."""
    original = mcap.writer.Chunk
    made: list[int] = []

    def chunk(**fields):
        if made and not every:
            return original(**fields)
        made.append(1)
        head = zstandard.decompress(fields["data"])
        data, size, crc = inflating(head, pad, compression, one_record)
        if lie:
            size, crc = len(head), zlib.crc32(head)
        return original(
            **{
                **fields,
                "compression": compression,
                "data": data,
                "uncompressed_size": size,
                "uncompressed_crc": crc,
            }
        )

    mcap.writer.Chunk = chunk
    try:
        yield
    finally:
        mcap.writer.Chunk = original


@contextlib.contextmanager
def tampered_trials(change: Callable[[bytes], bytes]) -> Iterator[None]:
    """Make the writer log every trial payload as ``change(payload)``, past its own check."""
    saved = log_writer.encode, log_writer.decode

    def tampering(value: object) -> bytes:
        data = encode(value)
        return change(data) if isinstance(value, TrialRecord) else data

    log_writer.encode, log_writer.decode = tampering, lambda data: None
    try:
        yield
    finally:
        log_writer.encode, log_writer.decode = saved


# --- entries that are no regular file ---------------------------------------------------------

ENTRIES = {
    "a FIFO": (lambda path: os.mkfifo(path), "is a FIFO, not a regular file"),
    "a directory": (lambda path: path.mkdir(), "is a directory, not a regular file"),
    "a link to a device": (
        lambda path: path.symlink_to("/dev/null"),
        "is a symbolic link, not a regular file",
    ),
    "a link to a log file": (
        lambda path: path.symlink_to(victim_of(path.parent).resolve()),
        "is a symbolic link, not a regular file",
    ),
}


@pytest.mark.parametrize("entry", ENTRIES)
def test_an_entry_named_like_a_log_that_is_no_regular_file_is_refused(
    tmp_path: Path, run: Path, entry: str
) -> None:
    make, what = ENTRIES[entry]
    victim = run / "main-0000000000000000.mcap"
    make(victim)
    refused_by_every_reader(run, victim, what, tmp_path / "report")


def test_under_partial_entries_that_are_no_regular_file_are_reported_and_the_rest_read(
    tmp_path: Path, run: Path
) -> None:
    os.mkfifo(run / "a.mcap")
    (run / "b.mcap").mkdir()
    (run / "c.mcap").symlink_to("/dev/null")
    os.mkfifo(run / "d.mcap.tmp")
    partial_reads_the_rest(
        run,
        tmp_path / "report",
        TRIALS,
        f"{run / 'a.mcap'}: is a FIFO, not a regular file; passed over",
        f"{run / 'b.mcap'}: is a directory, not a regular file; passed over",
        f"{run / 'c.mcap'}: is a symbolic link, not a regular file; passed over",
        f"{run / 'd.mcap.tmp'}: is a FIFO, not a regular file; passed over",
    )


def test_a_temporary_name_that_is_no_regular_file_is_refused_not_deleted(
    tmp_path: Path, run: Path
) -> None:
    temporary = run / "main-0000000000000000.mcap.tmp"
    os.mkfifo(temporary)
    result = invoke("validate", run)
    assert result.exit_code == 1
    assert (
        f"{temporary}: is a FIFO, not a regular file, not a temporary log file"
        in (result.output.splitlines()[-1])
    )
    one_line(invoke("analyze", run, "--out", tmp_path / "report"), str(temporary), "FIFO")
    one_line(invoke("run", SMOKE, "--out", run), str(temporary), "FIFO", "move it out")
    assert temporary.exists()


def test_a_file_longer_than_a_reader_takes_is_refused_unread(tmp_path: Path, run: Path) -> None:
    victim = run / "main-0000000000000000.mcap"
    with victim.open("wb") as stream:  # sparse: takes no disk
        stream.truncate(bounds.MAX_LOG_FILE_BYTES + 1)
    fault = f"is {bounds.MAX_LOG_FILE_BYTES + 1} bytes, longer than the"
    refused_by_every_reader(run, victim, fault, tmp_path / "report")
    partial_reads_the_rest(run, tmp_path / "report", TRIALS, f"{victim}: {fault}")


# --- decompression bombs ----------------------------------------------------------------------

SMALL_CHUNK = 1 << 20  # the chunk bound patched in for the bombs of this section


@pytest.fixture
def small_bounds(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(bounds, "MAX_CHUNK_BYTES", SMALL_CHUNK)
    monkeypatch.setattr(bounds, "MAX_INFLATED_BYTES", 4 * SMALL_CHUNK)
    monkeypatch.setattr(bounds, "MAX_FILE_RECORDS", 20_000)


BOMBS = {
    "zstd, size declared": (
        dict(pad=2 * SMALL_CHUNK, compression="zstd"),
        "a chunk may hold",
    ),
    "lz4, size declared": (dict(pad=2 * SMALL_CHUNK, compression="lz4"), "a chunk may hold"),
    "zstd, size lied about": (
        dict(pad=2 * SMALL_CHUNK, compression="zstd", lie=True),
        "inflates past the ",
    ),
    "lz4, size lied about": (
        dict(pad=2 * SMALL_CHUNK, compression="lz4", lie=True),
        "inflates past the ",
    ),
    "every chunk within the chunk bound, too much together": (
        dict(pad=SMALL_CHUNK // 2, compression="zstd", every=True, one_record=True),
        "inflates the file's chunks past the",
    ),
}


@pytest.mark.parametrize("bomb", BOMBS)
@pytest.mark.usefixtures("small_bounds")
def test_a_decompression_bomb_is_refused_uninflated(tmp_path: Path, run: Path, bomb: str) -> None:
    options, fault = BOMBS[bomb]
    victim = victim_of(run)
    with bombs(**options):
        rewrite(victim)
    refused_by_every_reader(run, victim, fault, tmp_path / "report")


@pytest.mark.usefixtures("small_bounds")
def test_a_chunk_of_more_records_than_a_file_may_hold_stops_the_scan(run: Path) -> None:
    """Half a MiB of zero bytes is 58,000 empty records: the record-by-record scan stops at
    the bound (analyze and resume take the trial messages through the file's indexes, and
    never parse the rest)."""
    victim = victim_of(run)
    with bombs(pad=SMALL_CHUNK // 2, compression="lz4"):
        rewrite(victim)
    result = invoke("validate", run)
    assert result.exit_code == 1, result.output
    (failed,) = [line for line in result.output.splitlines() if line.startswith("FAIL /")]
    assert failed.startswith(f"FAIL {victim}: damaged chunk at byte ")
    assert "more than the 20000 records a log file may hold" in failed


@pytest.mark.usefixtures("small_bounds")
def test_under_partial_a_bomb_is_passed_over_and_the_rest_read(tmp_path: Path, run: Path) -> None:
    victim = victim_of(run)
    with bombs(pad=2 * SMALL_CHUNK, compression="lz4", lie=True):
        rewrite(victim)
    kept = len(read_file_contents(victim).records)  # those of its other chunks
    assert 0 < kept < 8
    partial_reads_the_rest(
        run,
        tmp_path / "report",
        TRIALS - 8,
        f"{victim}: damaged (damaged chunk at byte ",
        f"recovered {kept} trial(s) of 8 ",
    )


@pytest.mark.parametrize("compression", ["zstd", "lz4"])
def test_a_real_size_bomb_is_refused_at_once(tmp_path: Path, run: Path, compression: str) -> None:
    """A chunk of the file's own records and zero bytes up to 1 GiB (40 KB compressed with
    zstd, 4 MB with lz4), announced (zstd) or lied about (lz4): refused in well under a
    second, uninflated."""
    victim = victim_of(run)
    lie = compression == "lz4"
    with bombs(pad=GiB - (1 << 20), compression=compression, lie=lie):
        rewrite(victim)
    began = time.perf_counter()
    result = invoke("validate", run)
    assert time.perf_counter() - began < 5
    fault = "inflates past the " if lie else f"more than the {bounds.MAX_CHUNK_BYTES} a chunk"
    assert result.exit_code == 1 and f"FAIL {victim}: damaged chunk at byte " in result.output
    assert fault in result.output


# --- nesting, grids, counts and indexes -------------------------------------------------------


def deep(data: bytes) -> bytes:
    """The record with one more field nested 1000 deep (2 KB)."""
    return b'{"aaa":' + b"[" * 1000 + b"]" * 1000 + b"," + data[1:]


def huge_grid(data: bytes) -> bytes:
    """The record on a grid of 10^10 cells."""
    return data.replace(b'"height":5,"width":5', b'"height":100000,"width":100000')


RECORDS = {
    "nested 1000 deep": (deep, "JSON nested deeper than a trial record can be read"),
    "a grid of 10^10 cells": (huge_grid, "more than the 262144 a record may"),
}


@pytest.mark.parametrize("record", RECORDS)
def test_a_record_past_a_bound_is_one_line_and_partial_reads_the_rest(
    tmp_path: Path, run: Path, record: str
) -> None:
    change, fault = RECORDS[record]
    victim = victim_of(run)
    with tampered_trials(change):
        rewrite(victim)
    refused_by_every_reader(run, victim, fault, tmp_path / "report")
    partial_reads_the_rest(run, tmp_path / "report", TRIALS - 8, f"{victim}: damaged (trial ")


@pytest.mark.parametrize("depth", [300, 5000])
def test_a_pipeline_nested_deep_is_one_line(tmp_path: Path, depth: int) -> None:
    pipeline = tmp_path / "deep.toml"
    text = SMOKE.read_text()
    pipeline.write_text(text.replace("seed = 7", "seed = " + "[" * depth + "]" * depth, 1))
    one_line(
        invoke("run", pipeline, "--out", tmp_path / "out"),
        "deep.toml: ",
        "nests deeper than 8 levels of tables and arrays",
    )
    assert not (tmp_path / "out").exists()


def lying_counts(log: TrialLogWriter) -> None:
    statistics = log._writer._Writer__statistics  # type: ignore[union-attr]
    statistics.message_count = 2**64 - 1
    statistics.chunk_count = 2**32 - 2  # one more chunk is closed as the file is
    statistics.channel_message_counts = dict.fromkeys(statistics.channel_message_counts, 2**64 - 1)


def test_huge_counts_in_the_summary_are_one_line(tmp_path: Path, run: Path) -> None:
    victim = victim_of(run)
    rewrite(victim, tweak=lying_counts)
    refused_by_every_reader(run, victim, f"the summary counts {2**64 - 1} messages", tmp_path / "r")
    partial_reads_the_rest(
        run, tmp_path / "report", TRIALS, f"{victim}: damaged (the summary counts ", "unknown"
    )


def test_a_trial_index_of_a_million_ids_is_one_line(tmp_path: Path, run: Path) -> None:
    victim = victim_of(run)
    rewrite(victim, tweak=lambda log: setattr(log, "_trial_ids", [""] * 1_000_000))
    refused_by_every_reader(run, victim, "listing at most 250 trials", tmp_path / "report")


def test_resume_decides_from_the_records_not_the_files_index(tmp_path: Path, run: Path) -> None:
    """A file whose ``trial_index`` names other trials than its records: resuming believed
    the index and played the file's trials again, logging them twice."""
    victim = victim_of(run)

    def renamed(log: TrialLogWriter) -> None:
        log._trial_ids = [f"renamed-{trial_id}" for trial_id in log._trial_ids]

    rewrite(victim, tweak=renamed)
    before = entries(run)
    one_line(invoke("run", SMOKE, "--out", run), str(victim), "trial_index")
    assert entries(run) == before


def test_more_trials_in_a_file_than_a_batch_is_damage(
    tmp_path: Path, run: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr("cirl_study.logs.contents.MAX_FILE_TRIALS", 4)
    monkeypatch.setattr("cirl_study.logs.reader.MAX_FILE_TRIALS", 4)
    result = invoke("validate", run)
    assert result.exit_code == 1
    assert "8 trial messages, more than the 4 a log file may hold" in result.output


def test_a_pipeline_whose_log_files_readers_would_refuse_is_refused_before_playing(
    tmp_path: Path,
) -> None:
    """A 2x2 grid with horizons of 1000 fits the batch memory budget, but its files would hold
    more messages than a reader takes of one: refused before anything is written."""
    text = SMOKE.read_text()
    for old, new in [
        ("width = 5\nheight = 5", "width = 2\nheight = 2"),
        ("start = [2, 2]", "start = [0, 0]"),
        ("learning_steps = 4", "learning_steps = 1000"),
        ("deployment_steps = 4", "deployment_steps = 1000"),
        ("feature_levels = [3, 10]", "feature_levels = [1, 2]"),
    ]:
        assert old in text, old
        text = text.replace(old, new)
    pipeline = tmp_path / "long.toml"
    pipeline.write_text(text)
    one_line(
        invoke("run", pipeline, "--out", tmp_path / "out"),
        "one batch's log file would hold 501250 messages, more than the 500000",
    )
    assert not (tmp_path / "out").exists()
