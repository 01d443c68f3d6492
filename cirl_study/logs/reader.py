"""Reading a run directory: the trial records every analysis starts from.

Only complete files (``*.mcap``) are read; temporary files of an interrupted run are
ignored with a warning. An intact file is read through its summary index, with every chunk's
CRC checked, taking only the ``/cirl/trial`` messages (fast). A file that does not read
cleanly that way is scanned record by record instead: a damaged file (truncated, a bad CRC)
is salvaged, the trials of its intact chunks kept and a warning naming the file and what was
recovered; content that cannot be trusted (a malformed or inconsistent record, a trial
logged twice, files of different pipelines) is refused with a
:class:`~cirl_study.errors.UserError`. ``cirl-study validate`` checks every record of every
file in full.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from mcap.reader import make_reader

from cirl_study.errors import UserError
from cirl_study.logs.contents import FileContents, read_file_contents
from cirl_study.logs.format import (
    PIPELINE_NAME_KEY,
    PROVENANCE_METADATA_NAME,
    TRIAL_TOPIC,
    log_files,
    temp_files,
)
from cirl_study.logs.record_checks import decode_trial
from cirl_study.record import TrialRecord


@dataclass(frozen=True)
class RunContents:
    """The trial records of a run (sorted by ``trial_id``), each file's provenance, the
    pipeline's name and the warnings raised while reading."""

    records: list[TrialRecord]
    provenance: list[dict[str, str]]
    pipeline_name: str
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

    Every chunk holding a trial is decompressed with its CRC checked; the number of trial
    records must equal the summary's count, there must be one ``provenance`` record naming the
    pipeline, and every record must be complete and consistent
    (:func:`~cirl_study.logs.record_checks.decode_trial`).
    """
    try:
        with path.open("rb") as stream:
            reader = make_reader(stream, validate_crcs=True)
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
        and PIPELINE_NAME_KEY in provenance[0].metadata
        and len(decoded) == announced
        and len(records) == announced
    )
    return _IntactFile(path, records, dict(provenance[0].metadata)) if sound else None


def _read_file(path: Path) -> _IntactFile | FileContents:
    """Fast indexed read of an intact file, else the salvaging record-by-record scan."""
    intact = _read_intact(path)
    return intact if intact is not None else _readable(read_file_contents(path))


def read_run(run_dir: str | Path) -> RunContents:
    """Read every complete log file of ``run_dir`` (see the module docstring)."""
    run_dir = Path(run_dir)
    files = [_read_file(path) for path in _complete_files(run_dir)]
    warnings = [_salvage_warning(contents) for contents in files if contents.damage]
    for contents in files:
        if contents.content_faults:
            damage = f"damaged ({contents.damage[0]}) and " if contents.damage else ""
            raise UserError(
                f"{contents.path}: {damage}unusable ({contents.content_faults[0]}); "
                f"`cirl-study validate {run_dir}` lists every fault"
            )
    unfinished = temp_files(run_dir)
    if unfinished:
        warnings.append(
            f"{run_dir}: {len(unfinished)} unfinished temporary file(s) of an interrupted run "
            "ignored; run the pipeline again to complete the run"
        )
    records = _without_duplicates(files)
    provenance = [contents.provenance for contents in files if contents.provenance is not None]
    names = sorted({p[PIPELINE_NAME_KEY] for p in provenance})
    if len(names) != 1:
        raise UserError(f"{run_dir}: log files of {len(names)} pipelines ({', '.join(names)})")
    return RunContents(
        records=sorted(records, key=lambda record: record.trial_id),
        provenance=provenance,
        pipeline_name=names[0],
        warnings=warnings,
    )


@dataclass(frozen=True)
class LoggedTrials:
    """What a run directory already holds, for resuming: trial ids and each file's provenance."""

    trial_ids: set[str]
    provenance: dict[Path, dict[str, str]]


def logged_trials(run_dir: str | Path) -> LoggedTrials:
    """The trials already logged in complete files of ``run_dir``, reading each file once.

    An absent directory has none. A damaged or faulty file is refused rather than guessed
    at, so that a resumed run neither loses nor duplicates a trial.
    """
    run_dir = Path(run_dir)
    if not run_dir.exists():
        return LoggedTrials(set(), {})
    files = []
    for path in _complete_files(run_dir, require_any=False):
        contents = _read_file(path)
        if contents.faults:
            raise UserError(
                f"{path} is damaged ({contents.faults[0]}); move it out of {run_dir} "
                "to run its trials again"
            )
        files.append(contents)
    return LoggedTrials(
        trial_ids={record.trial_id for record in _without_duplicates(files)},
        provenance={contents.path: contents.provenance or {} for contents in files},
    )


def _complete_files(run_dir: Path, *, require_any: bool = True) -> list[Path]:
    if not run_dir.is_dir():
        raise UserError(f"{run_dir}: no such run directory")
    files = log_files(run_dir)
    if require_any and not files:
        raise UserError(f"{run_dir}: no complete log files (*.mcap)")
    return files


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
