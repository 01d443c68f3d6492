"""`validate`: sound files pass; every kind of damage or inconsistency fails, with a reason."""

from __future__ import annotations

import shutil
from pathlib import Path

import msgspec
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_logs_helpers import make_record, make_study, provenance_for
from typer.testing import CliRunner

from cirl_study.cli import app
from cirl_study.errors import UserError
from cirl_study.logs.scan import scan_file
from cirl_study.logs.validate import validate_file, validate_run
from cirl_study.logs.writer import TrialLogWriter
from cirl_study.record import TrialRecord
from cirl_study.study.pipeline_file import logged_pipeline

PROVENANCE = provenance_for()


def write(path: Path, records: list[TrialRecord], chunk_size: int = 3000) -> Path:
    with TrialLogWriter(path, PROVENANCE, chunk_size=chunk_size) as log:
        for record in records:
            log.write(record)
    return path


@pytest.fixture(scope="module")
def good_bytes(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    path = tmp_path_factory.mktemp("good") / "good.mcap"
    return write(path, make_study(subjects=2)).read_bytes()


@pytest.fixture
def run(tmp_path: Path) -> Path:
    directory = tmp_path / "run"
    directory.mkdir()
    return directory


def test_a_sound_file_is_ok(tmp_path: Path, good_bytes: bytes) -> None:
    path = tmp_path / "good.mcap"
    path.write_bytes(good_bytes)
    verdict = validate_file(path, logged_pipeline)
    assert verdict.faults == ()
    assert verdict.line() == f"OK {path}: 8 trials"


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(cut=st.integers(min_value=0))
def test_every_truncation_fails(tmp_path: Path, good_bytes: bytes, cut: int) -> None:
    path = tmp_path / "cut.mcap"
    path.write_bytes(good_bytes[: cut % len(good_bytes)])
    verdict = validate_file(path, logged_pipeline)
    assert not verdict.ok
    assert verdict.line().startswith(f"FAIL {path}: ")


@settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(position=st.integers(min_value=0), mask=st.integers(min_value=1, max_value=255))
def test_every_corrupted_byte_fails(
    tmp_path: Path, good_bytes: bytes, position: int, mask: int
) -> None:
    damaged = bytearray(good_bytes)
    damaged[position % len(damaged)] ^= mask
    path = tmp_path / "flipped.mcap"
    path.write_bytes(bytes(damaged))
    assert not validate_file(path, logged_pipeline).ok


def test_a_flipped_byte_in_a_chunk_names_the_chunk(tmp_path: Path, good_bytes: bytes) -> None:
    path = tmp_path / "a.mcap"
    path.write_bytes(good_bytes)
    chunk = scan_file(path).chunk_offsets[1]
    damaged = bytearray(good_bytes)
    damaged[chunk + 200] ^= 0x10
    path.write_bytes(bytes(damaged))
    verdict = validate_file(path, logged_pipeline)
    assert f"damaged chunk at byte {chunk}" in verdict.faults[0]
    assert "data-section CRC mismatch" in verdict.faults
    assert verdict.trials < 8


def test_a_truncated_file_says_so(tmp_path: Path, good_bytes: bytes) -> None:
    path = tmp_path / "a.mcap"
    path.write_bytes(good_bytes[: len(good_bytes) // 2])
    assert validate_file(path, logged_pipeline).faults[0].startswith("truncated: ")


def test_not_an_mcap_file(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    path.write_text("hello")
    assert (
        validate_file(path, logged_pipeline).line()
        == f"FAIL {path}: not an MCAP file (bad magic bytes at the start)"
    )


def test_a_record_missing_a_field_fails(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    record = msgspec.structs.replace(make_record(1), measures=None)
    # A log written by some other tool: our writer refuses a record it could not read back.
    monkeypatch.setattr("cirl_study.logs.writer.decode", lambda data: None)
    verdict = validate_file(write(tmp_path / "a.mcap", [make_record(2), record]), logged_pipeline)
    assert verdict.faults == (
        f"trial {record.trial_id}: not a trial record: "
        "Expected `object`, got `null` - at `$.measures`",
    )
    assert verdict.trials == 1


def test_an_inconsistent_record_fails(tmp_path: Path) -> None:
    record = msgspec.structs.replace(make_record(1), eta=2.0)
    verdict = validate_file(write(tmp_path / "a.mcap", [record]), logged_pipeline)
    assert verdict.faults == (
        f"trial {record.trial_id}: eta is 2.0 for human expert "
        "(null exactly for a human without a trade-off)",
    )


def test_a_trial_twice_in_one_file_fails(tmp_path: Path) -> None:
    record = make_record(1)
    verdict = validate_file(write(tmp_path / "a.mcap", [record, record]), logged_pipeline)
    assert verdict.faults == (f"trial {record.trial_id}: logged twice in this file",)


def test_a_sound_run(run: Path) -> None:
    study = make_study(subjects=2)
    write(run / "a.mcap", study[:3])
    write(run / "b.mcap", study[3:])
    verdict = validate_run(run, logged_pipeline)
    assert verdict.ok
    assert [v.line() for v in verdict.files] == [
        f"OK {run / 'a.mcap'}: 3 trials",
        f"OK {run / 'b.mcap'}: 5 trials",
    ]
    assert verdict.line() == f"OK run {run}: 2 file(s), 8 trials, design complete"


def test_a_duplicate_trial_across_files_fails(run: Path) -> None:
    study = make_study(subjects=1)
    write(run / "a.mcap", study)
    write(run / "b.mcap", study[:1])
    verdict = validate_run(run, logged_pipeline)
    assert all(v.ok for v in verdict.files)
    assert verdict.faults == (
        f"1 trial id(s) logged in two files: {study[0].trial_id} in a.mcap and b.mcap",
    )
    assert verdict.line().startswith(f"FAIL run {run}: 2 file(s), 5 trials; 1 trial id(s)")


def test_an_incomplete_design_fails(run: Path) -> None:
    study = make_study(subjects=2)
    write(run / "a.mcap", [r for r in study if r.subject != "k3-s0001" or r.human == "expert"])
    (fault,) = validate_run(run, logged_pipeline).faults
    assert fault == (
        "main block incomplete: 1 subject(s) without exactly one trial of each of "
        "best_response/map, expert/map: k3-s0001 has {'expert/map': 1}"
    )


def test_a_subject_is_one_reward_draw(run: Path) -> None:
    expert, best = make_record(1), make_record(1, "best_response")
    best = msgspec.structs.replace(
        best,
        theta=tuple(-w for w in best.theta),
        theta_hat=tuple(-w for w in best.theta_hat),
    )
    write(run / "a.mcap", [expert, best])
    (fault,) = validate_run(run, logged_pipeline).faults
    assert fault.startswith(
        "1 record(s) disagree with their subject's draw: k3-s0001 (the reward draw of "
    )


def test_cross_validation_draws_are_not_test_draws(run: Path) -> None:
    study = make_study(subjects=1, num_features=(3,))
    cv = make_record(0, "best_response", block="eta_cv")
    write(run / "a.mcap", [*study, cv])
    assert validate_run(run, logged_pipeline).faults == (
        "1 eta_cv subject(s) also used in the test blocks: k3-s0000",
    )


def test_runs_and_pipelines_are_not_mixed(run: Path) -> None:
    with TrialLogWriter(run / "a.mcap", PROVENANCE) as log:
        log.write(make_record(1))
        log.run_id = "r2"  # past the writer's own check, as a hand-made file would be
        log.write(make_record(1, "best_response", run_id="r2"))
    other = provenance_for(variant="# another text of the same pipeline\n")
    with TrialLogWriter(run / "b.mcap", other):
        pass
    first, second = PROVENANCE, other
    assert validate_run(run, logged_pipeline).faults == (
        "a.mcap holds records of run(s) r2",
        f"files of 2 runs: {first['run_id']} (pipeline sha256 {first['pipeline_sha256']}) in "
        f"a.mcap; {second['run_id']} (pipeline sha256 {second['pipeline_sha256']}) in b.mcap",
    )


def test_an_unfinished_temporary_file_fails_the_run(run: Path) -> None:
    write(run / "a.mcap", make_study(subjects=1))
    (run / "b.mcap.tmp").write_bytes(b"\x89MCAP0\r\n")
    verdict = validate_run(run, logged_pipeline)
    assert [v.path.name for v in verdict.files] == ["a.mcap"]
    assert "unfinished temporary file" in verdict.faults[0]


def test_an_empty_run_fails(run: Path) -> None:
    assert validate_run(run, logged_pipeline).faults == ("no complete log files (*.mcap)",)


def test_a_missing_run_directory_is_a_user_error(tmp_path: Path) -> None:
    with pytest.raises(UserError, match="no such run directory"):
        validate_run(tmp_path / "nowhere", logged_pipeline)


def test_command_line(tmp_path: Path, smoke_run: Path, good_bytes: bytes) -> None:
    cli = CliRunner()
    run = tmp_path / "run"
    shutil.copytree(smoke_run, run)
    files = sorted(run.glob("*.mcap"))
    result = cli.invoke(app, ["validate", str(run)])
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert len(lines) == len(files) + 1
    assert lines[-1] == f"OK run {run}: {len(files)} file(s), 82 trials, design complete"
    (run / "zz.mcap").write_bytes(good_bytes[:-100])
    result = cli.invoke(app, ["validate", str(run)])
    assert result.exit_code == 1
    lines = result.output.splitlines()
    assert lines[-2].startswith(f"FAIL {run / 'zz.mcap'}: ")
    assert lines[-1].startswith(f"FAIL run {run}: {len(files) + 1} file(s), ")
    assert len(lines) == len(files) + 2
    result = cli.invoke(app, ["validate", str(run / "missing")])
    assert result.exit_code == 2
    assert result.output.strip() == f"error: {run / 'missing'}: no such run directory"
