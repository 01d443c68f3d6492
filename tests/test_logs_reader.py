"""`read_run` and `logged_run`: what analysis and resume read from a run."""

from __future__ import annotations

from pathlib import Path

import msgspec
import pytest
from test_logs_helpers import RUN_ID, make_record, make_study, provenance_for

from cirl_study.errors import UserError
from cirl_study.logs.provenance import RunIdentity
from cirl_study.logs.reader import logged_run, read_run, read_trials
from cirl_study.logs.scan import scan_file
from cirl_study.logs.writer import TrialLogWriter
from cirl_study.record import TrialRecord, TrialRow
from cirl_study.study.pipeline_file import logged_pipeline

PROVENANCE = {**provenance_for(), "git_commit": "abc"}
IDENTITY = RunIdentity.of(PROVENANCE)


def write(path: Path, records: list[TrialRecord], provenance: dict | None = None) -> Path:
    with TrialLogWriter(path, provenance or PROVENANCE, chunk_size=2500) as log:
        for record in records:
            log.write(record)
    return path


@pytest.fixture
def run(tmp_path: Path) -> Path:
    directory = tmp_path / "run"
    directory.mkdir()
    return directory


def rows(records: list[TrialRecord], file: str) -> list[TrialRow]:
    """The rows of ``records`` as read from the log file named ``file``."""
    return [TrialRow.of(record, file) for record in records]


def test_the_rows_of_every_file_sorted_by_trial_id(run: Path) -> None:
    study = make_study(subjects=2)
    write(run / "b.mcap", study[:5])
    write(run / "a.mcap", study[5:])
    contents = read_run(run, logged_pipeline)
    read = [*rows(study[:5], "b.mcap"), *rows(study[5:], "a.mcap")]
    assert contents.rows == sorted(read, key=lambda r: r.trial_id)  # each names its file
    assert contents.provenance == [PROVENANCE, PROVENANCE]
    assert contents.identity == IDENTITY and contents.identity.pipeline_name == "test"
    assert contents.warnings == [] and contents.damaged == []
    assert logged_run(run, IDENTITY, logged_pipeline).trial_ids == {r.trial_id for r in study}


def test_whole_records_are_fetched_from_the_files_that_log_them(run: Path) -> None:
    study = make_study(subjects=2)
    write(run / "b.mcap", study[:5])
    write(run / "a.mcap", study[5:])
    contents = read_run(run, logged_pipeline)
    assert contents.files == [
        (run / "a.mcap", [r.trial_id for r in study[5:]]),
        (run / "b.mcap", [r.trial_id for r in study[:5]]),
    ]
    wanted = {study[1].trial_id, study[7].trial_id}
    fetched = contents.records(wanted)
    assert sorted(fetched, key=lambda r: r.trial_id) == sorted(
        [study[1], study[7]], key=lambda r: r.trial_id
    )
    assert fetched == read_trials(run, IDENTITY, logged_pipeline, wanted)
    other = {**PROVENANCE, **provenance_for(name="paper")}
    (run / "b.mcap").unlink()
    replaced = [msgspec.structs.replace(r, run_id=other["run_id"]) for r in study[:5]]
    write(run / "b.mcap", replaced, other)  # replaced since it was read
    with pytest.raises(UserError, match="b.mcap: now holds the logs of another run"):
        contents.records(wanted)


def test_temporary_files_are_ignored(run: Path) -> None:
    study = make_study(subjects=1)
    write(run / "a.mcap", study[:2])
    with pytest.raises(KeyboardInterrupt), TrialLogWriter(run / "b.mcap", PROVENANCE) as log:
        log.write(study[2])
        raise KeyboardInterrupt
    assert (run / "b.mcap.tmp").exists()
    assert logged_run(run, IDENTITY, logged_pipeline).trial_ids == {r.trial_id for r in study[:2]}
    contents = read_run(run, logged_pipeline)
    assert contents.rows == rows(sorted(study[:2], key=lambda r: r.trial_id), "a.mcap")
    assert contents.warnings == [
        f"{run}: 1 unfinished temporary file(s) of an interrupted run ignored; "
        "run the pipeline again to complete the run"
    ]


def test_a_truncated_file_is_salvaged_with_a_warning(run: Path) -> None:
    study = make_study(subjects=3)
    path = write(run / "a.mcap", study)
    chunks = scan_file(path).chunk_offsets
    assert len(chunks) >= 4
    data = path.read_bytes()
    path.write_bytes(data[: chunks[3] + 50])  # cut inside the fourth chunk
    with pytest.raises(UserError, match=f"{path}: damaged \\(truncated: .*--partial"):
        read_run(run, logged_pipeline)
    contents = read_run(run, logged_pipeline, salvage=True)
    assert contents.damaged == [path]
    recovered = contents.rows
    assert 0 < len(recovered) < len(study)
    by_position = {r.trial_id: i for i, r in enumerate(study)}
    assert sorted(by_position[r.trial_id] for r in recovered) == list(range(len(recovered)))
    (warning,) = contents.warnings
    assert warning.startswith(f"{path}: damaged (truncated: the chunk record at byte {chunks[3]} ")
    assert warning.endswith(
        f"recovered {len(recovered)} trial(s) (how many were lost is unknown) "
        "from 3 intact chunk(s) of 3 read"
    )


def test_a_damaged_chunk_is_skipped_and_counted(run: Path) -> None:
    study = make_study(subjects=3)
    path = write(run / "a.mcap", study)
    chunk = scan_file(path).chunk_offsets[2]
    data = bytearray(path.read_bytes())
    data[chunk + 100] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(UserError, match=f"{path}: damaged \\(damaged chunk"):
        read_run(run, logged_pipeline)
    contents = read_run(run, logged_pipeline, salvage=True)
    assert 0 < len(contents.rows) < len(study)
    assert all(r in rows(study, "a.mcap") for r in contents.rows)
    (warning,) = contents.warnings
    assert warning.startswith(f"{path}: damaged (damaged chunk at byte {chunk}: ")
    assert f"recovered {len(contents.rows)} trial(s) of {len(study)} from " in warning
    with pytest.raises(UserError, match=f"{path} is damaged"):
        logged_run(run, IDENTITY, logged_pipeline)


def test_a_trial_in_two_files_is_refused(run: Path) -> None:
    record = make_record(1)
    write(run / "a.mcap", [record])
    write(run / "b.mcap", [record])
    message = (
        f"trial {record.trial_id} is logged twice: in {run / 'a.mcap'} and in {run / 'b.mcap'}"
    )
    with pytest.raises(UserError) as error:
        read_run(run, logged_pipeline)
    assert str(error.value) == message
    with pytest.raises(UserError, match="logged twice"):
        logged_run(run, IDENTITY, logged_pipeline)


def test_a_faulty_record_is_refused(run: Path) -> None:
    record = msgspec.structs.replace(make_record(1), human="oracle")
    write(run / "a.mcap", [record])
    with pytest.raises(UserError, match=r"unusable \(trial .*'oracle' is not a known human"):
        read_run(run, logged_pipeline)


def test_files_of_two_runs_are_refused(run: Path) -> None:
    write(run / "a.mcap", [make_record(1)])
    other = {**PROVENANCE, **provenance_for(name="paper")}
    paper = RunIdentity.of(other).run_id
    write(run / "b.mcap", [make_record(2, run_id=paper)], other)
    expected = (
        f"{run}: log files of 2 runs: a.mcap and b.mcap differ (run {RUN_ID} against {paper})"
    )
    with pytest.raises(UserError) as error:
        read_run(run, logged_pipeline)
    assert str(error.value) == expected
    with pytest.raises(UserError, match="log files of 2 runs"):
        logged_run(run, RunIdentity.of(other), logged_pipeline)
    (run / "a.mcap").unlink()
    with pytest.raises(UserError, match="holds the logs of another run .*use another --out"):
        logged_run(run, IDENTITY, logged_pipeline)


def test_a_record_of_another_run_is_refused(run: Path) -> None:
    other = provenance_for("other")
    other_run = other["run_id"]
    path = write(run / "a.mcap", [make_record(1, run_id=other_run)], other)
    write(run / "b.mcap", [make_record(2)])
    with pytest.raises(UserError, match=f"log files of 2 runs: .*run {other_run} against {RUN_ID}"):
        read_run(run, logged_pipeline)
    path.unlink()
    foreign = make_record(3, run_id=other_run)
    with TrialLogWriter(run / "c.mcap", PROVENANCE) as log:
        log.run_id = other_run  # past the writer's own check, as a hand-made file would be
        log.write(foreign)
    expected = f"trial {foreign.trial_id} belongs to run {other_run}, the file to run {RUN_ID}"
    with pytest.raises(UserError, match=expected):
        read_run(run, logged_pipeline)
    # Resuming decides from the records, not from the file's own trial index.
    with pytest.raises(UserError, match=expected):
        logged_run(run, IDENTITY, logged_pipeline)


def test_the_writer_refuses_a_record_of_another_run(run: Path) -> None:
    with (
        TrialLogWriter(run / "a.mcap", PROVENANCE) as log,
        pytest.raises(ValueError, match=f"belongs to run other-run, the file to {RUN_ID}"),
    ):
        log.write(make_record(1, run_id="other-run"))


@pytest.mark.parametrize(
    ("setup", "message"),
    [
        (lambda run: run.rmdir(), "no such run directory"),
        (lambda run: None, "no complete log files"),
        (lambda run: (run / "a.mcap").write_bytes(b"PK\x03\x04"), "not an MCAP file"),
    ],
)
def test_unreadable_runs_are_user_errors(run: Path, setup, message: str) -> None:
    setup(run)
    with pytest.raises(UserError, match=message):
        read_run(run, logged_pipeline)


def test_resume_of_a_fresh_run(tmp_path: Path) -> None:
    assert logged_run(tmp_path / "not-yet", IDENTITY, logged_pipeline).trial_ids == set()
    assert logged_run(tmp_path, IDENTITY, logged_pipeline).trial_ids == set()
