"""Reading a run directory: the trial records every analysis starts from.

Only complete files (``*.mcap``) are read; temporary files of an interrupted run are
ignored with a warning. An intact file is read through its summary index with every CRC
checked (data section, summary and each chunk holding a trial), taking only the
``/cirl/trial`` messages (fast). A file that does not read cleanly that way is scanned record
by record instead, which says what is wrong with it.

A run is what its logs prove. Every file must name the same run (its provenance's
:class:`~cirl_study.logs.provenance.RunIdentity`: run id and pipeline file) and every record
that run's id; a damaged file (truncated, a bad CRC anywhere) is refused, or, when the caller
asks to ``salvage``, the trials of its intact chunks are kept with a warning naming the file
and what was recovered. Content that cannot be trusted (a malformed or inconsistent record, a
trial logged twice, files or records of another run) is always refused with a
:class:`~cirl_study.errors.UserError`. ``cirl-study validate`` checks every record of every
file in full.
"""

from __future__ import annotations

import io
from dataclasses import dataclass, field
from pathlib import Path

from mcap.reader import make_reader

from cirl_study.errors import UserError
from cirl_study.logs.contents import FileContents, read_file_contents
from cirl_study.logs.format import (
    PROVENANCE_METADATA_NAME,
    TRIAL_TOPIC,
    log_files,
    temp_files,
)
from cirl_study.logs.provenance import RunIdentity
from cirl_study.logs.record_checks import decode_trial
from cirl_study.logs.scan import section_crcs_hold
from cirl_study.record import TrialRecord


@dataclass(frozen=True)
class RunContents:
    """The trial records of a run (sorted by ``trial_id``), each file's provenance, the run's
    identity, the damaged files salvaged and the warnings raised while reading."""

    records: list[TrialRecord]
    provenance: list[dict[str, str]]
    identity: RunIdentity
    damaged: list[Path]
    warnings: list[str]


@dataclass
class _IntactFile:
    """The trial records and provenance of a file that read cleanly through its index."""

    path: Path
    records: list[TrialRecord]
    provenance: dict[str, str]
    damage: list[str] = field(default_factory=list)
    content_faults: list[str] = field(default_factory=list)

    @property
    def faults(self) -> list[str]:
        return []


def _read_intact(path: Path) -> _IntactFile | None:
    """The file's content through its summary index, or ``None`` if it does not read cleanly.

    Every CRC of the file holds (:func:`~cirl_study.logs.scan.section_crcs_hold`: data section
    and summary; every chunk holding a trial is decompressed with its own CRC checked); the
    number of trial records must equal the summary's count, there must be one ``provenance``
    record stating a run identity, and every record must be complete and consistent
    (:func:`~cirl_study.logs.record_checks.decode_trial`).
    """
    try:
        data = path.read_bytes()
        if not section_crcs_hold(data):
            return None
        reader = make_reader(io.BytesIO(data), validate_crcs=True)
        summary = reader.get_summary()
        if summary is None or summary.statistics is None:
            return None
        provenance = [m for m in reader.iter_metadata() if m.name == PROVENANCE_METADATA_NAME]
        decoded = [
            decode_trial(message.data)
            for _, _, message in reader.iter_messages(topics=[TRIAL_TOPIC])
        ]
    except Exception:  # any damage: the record-by-record scan will say what and salvage
        return None
    trial_channels = [c.id for c in summary.channels.values() if c.topic == TRIAL_TOPIC]
    announced = sum(summary.statistics.channel_message_counts.get(c, 0) for c in trial_channels)
    records = [record for record, faults in decoded if record is not None and not faults]
    sound = (
        len(provenance) == 1
        and _states_identity(provenance[0].metadata)
        and len(decoded) == announced
        and len(records) == announced
    )
    return _IntactFile(path, records, dict(provenance[0].metadata)) if sound else None


def _states_identity(provenance: dict[str, str]) -> bool:
    try:
        RunIdentity.of(provenance)
    except ValueError:
        return False
    return True


def _read_file(path: Path) -> _IntactFile | FileContents:
    """Fast indexed read of an intact file, else the salvaging record-by-record scan."""
    intact = _read_intact(path)
    return intact if intact is not None else _readable(read_file_contents(path))


def read_run(run_dir: str | Path, *, salvage: bool = False) -> RunContents:
    """Read every complete log file of ``run_dir`` (see the module docstring).

    Args:
        run_dir: the run directory.
        salvage: keep the intact chunks of a damaged file (with a warning) instead of
            refusing it.
    """
    run_dir = Path(run_dir)
    files = [_read_file(path) for path in _complete_files(run_dir)]
    for contents in files:
        if contents.content_faults:
            damage = f"damaged ({contents.damage[0]}) and " if contents.damage else ""
            raise UserError(
                f"{contents.path}: {damage}unusable ({contents.content_faults[0]}); "
                f"`cirl-study validate {run_dir}` lists every fault"
            )
        if contents.damage and not salvage:
            raise UserError(
                f"{contents.path}: damaged ({contents.damage[0]}); move it out of {run_dir} "
                "and run the pipeline again to replay its trials, or analyze with --partial "
                "to keep what its intact chunks hold"
            )
    warnings = [_salvage_warning(contents) for contents in files if contents.damage]
    unfinished = temp_files(run_dir)
    if unfinished:
        warnings.append(
            f"{run_dir}: {len(unfinished)} unfinished temporary file(s) of an interrupted run "
            "ignored; run the pipeline again to complete the run"
        )
    identity = _one_identity(run_dir, files)
    records = _without_duplicates(files)
    return RunContents(
        records=sorted(records, key=lambda record: record.trial_id),
        provenance=[contents.provenance for contents in files if contents.provenance is not None],
        identity=identity,
        damaged=[contents.path for contents in files if contents.damage],
        warnings=warnings,
    )


def logged_trials(run_dir: str | Path, identity: RunIdentity) -> set[str]:
    """The ids of the trials already logged in complete files of ``run_dir``, for resuming.

    An absent directory has none. A damaged or faulty file, or one of another run than
    ``identity``'s, is refused rather than guessed at, so that a resumed run neither loses
    nor duplicates a trial, nor mixes runs.
    """
    run_dir = Path(run_dir)
    if not run_dir.exists():
        return set()
    files = []
    for path in _complete_files(run_dir, require_any=False):
        contents = _read_file(path)
        if contents.faults:
            raise UserError(
                f"{path} is damaged ({contents.faults[0]}); move it out of {run_dir} "
                "to run its trials again"
            )
        files.append(contents)
    if files:
        found = _one_identity(run_dir, files)
        if found != identity:
            raise UserError(
                f"{run_dir}: holds the logs of another run ({_difference(found, identity)}); "
                "use another --out directory"
            )
    return {record.trial_id for record in _without_duplicates(files)}


def _one_identity(run_dir: Path, files: list[_IntactFile | FileContents]) -> RunIdentity:
    """The run identity every file states and every record carries, or a refusal."""
    identities: dict[RunIdentity, Path] = {}
    for contents in files:
        try:
            identity = RunIdentity.of(contents.provenance or {})
        except ValueError as error:
            raise UserError(f"{contents.path}: not a log of a cirl-study run: {error}") from None
        identities.setdefault(identity, contents.path)
        foreign = next((r for r in contents.records if r.run_id != identity.run_id), None)
        if foreign is not None:
            raise UserError(
                f"{contents.path}: trial {foreign.trial_id} belongs to run {foreign.run_id}, "
                f"the file to run {identity.run_id}"
            )
    if len(identities) > 1:
        (first, first_path), (second, second_path) = list(identities.items())[:2]
        raise UserError(
            f"{run_dir}: log files of {len(identities)} runs: {first_path.name} and "
            f"{second_path.name} differ ({_difference(first, second)})"
        )
    return next(iter(identities))


def _difference(first: RunIdentity, second: RunIdentity) -> str:
    """What tells two run identities apart, in a few words."""
    if first.run_id != second.run_id:
        return f"run {first.run_id} against {second.run_id}"
    a, b = first.pipeline_sha256, second.pipeline_sha256
    if a == b:
        return f"pipeline {first.pipeline_file} against {second.pipeline_file}"
    shown = max(12, next((i for i, (x, y) in enumerate(zip(a, b, strict=True)) if x != y), 0) + 1)
    return f"pipeline sha256 {a[:shown]} against {b[:shown]}"


def _complete_files(run_dir: Path, *, require_any: bool = True) -> list[Path]:
    check_run_directory(run_dir)
    files = log_files(run_dir)
    if require_any and not files:
        raise UserError(f"{run_dir}: no complete log files (*.mcap)")
    return files


def check_run_directory(run_dir: Path) -> None:
    """Refuse, in one line, a ``run_dir`` that is not a directory."""
    if run_dir.is_file():
        raise UserError(f"{run_dir}: is a file, not a run directory (give the directory)")
    if not run_dir.is_dir():
        raise UserError(f"{run_dir}: no such run directory")


def _readable(contents: FileContents) -> FileContents:
    if not contents.scan.readable:
        raise UserError(f"{contents.path}: {contents.damage[0]}")
    return contents


def _salvage_warning(contents: FileContents) -> str:
    scan = contents.scan
    announced = scan.summary_message_count(TRIAL_TOPIC)
    recovered = f"{len(contents.records)} trial(s)"
    recovered += f" of {announced}" if announced is not None else " (how many were lost is unknown)"
    more = f" and {len(contents.damage) - 1} more fault(s)" if len(contents.damage) > 1 else ""
    return (
        f"{contents.path}: damaged ({contents.damage[0]}{more}); recovered {recovered} "
        f"from {scan.chunks - scan.damaged_chunks} intact chunk(s) of {scan.chunks} read"
    )


def _without_duplicates(files: list[_IntactFile | FileContents]) -> list[TrialRecord]:
    """All records of ``files``; a trial id logged in two files is refused."""
    first_file: dict[str, Path] = {}
    records = []
    for contents in files:
        for record in contents.records:
            trial_id = record.trial_id
            if trial_id in first_file:
                raise UserError(
                    f"trial {trial_id} is logged twice: in {first_file[trial_id]} "
                    f"and in {contents.path}"
                )
            first_file[trial_id] = contents.path
            records.append(record)
    return records
