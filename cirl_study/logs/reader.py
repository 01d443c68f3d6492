"""Reading a run directory: the trials every analysis starts from, file by file.

Only complete files (``*.mcap``) are read; temporary files of an interrupted run are
ignored with a warning. Every file is read whole once (:func:`~cirl_study.logs.bounds.read_log`:
a regular file only, within the bounds of :mod:`cirl_study.logs.bounds`). An intact file is
read through its summary index with every CRC checked (data section, summary and each chunk
holding a trial), taking only the ``/cirl/trial`` messages (fast). A file that does not read
cleanly that way is scanned record by record instead, which says what is wrong with it.

A run is what its logs prove. Every file must name the same run (its provenance's
:class:`~cirl_study.logs.provenance.RunIdentity`: run id and pipeline file, whose pipeline the
reader's :data:`~cirl_study.logs.provenance.PipelineOf` accepts) and every record that run's
id; a damaged file (truncated, a bad CRC anywhere, a bound passed) is refused, or,
when the caller asks to ``salvage``, the trials of its intact chunks are kept with a warning
naming the file and what was recovered. An entry named like a log that is no regular file (a
link, a FIFO, a device, a directory), or a file too long to read, is refused the same way, or
reported and passed over when salvaging. Content that cannot be trusted (a malformed or
inconsistent record, a trial logged twice, files or records of another run) is always refused
with a :class:`~cirl_study.errors.UserError`. ``cirl-study validate`` checks every record of every
file in full.
"""

from __future__ import annotations

import io
import struct
from collections.abc import Callable, Collection, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.summary import Summary

from cirl_study.errors import UserError
from cirl_study.escape import terminal
from cirl_study.files import UnreadableFile, non_regular
from cirl_study.logs.bounds import MAX_FILE_TRIALS, Budget, framed_records, read_log
from cirl_study.logs.contents import FileContents, contents_of, trial_index
from cirl_study.logs.format import (
    LOG_FORMAT_KEY,
    PROVENANCE_METADATA_NAME,
    TRIAL_TOPIC,
    log_files,
    temp_files,
)
from cirl_study.logs.lock import writer_pid
from cirl_study.logs.provenance import PipelineOf, RunIdentity, pipeline_faults
from cirl_study.logs.record_checks import decode_trials
from cirl_study.logs.scan import MESSAGE_HEADER, RECORD_PREFIX, scan_data, section_crcs_hold
from cirl_study.logs.versions import record_payload
from cirl_study.record import TrialRecord, TrialRow
from cirl_study.workers import started


@dataclass(frozen=True)
class RunContents:
    """The trials of a run as rows (:class:`~cirl_study.record.TrialRow`, sorted by
    ``trial_id``), each file's provenance, the run's identity, the damaged files salvaged,
    the warnings raised while reading, each file with the ids of the trials it logs
    (``files``, in the order read), and the process id of the run writing to the directory
    as it was read (``writer``: :func:`~cirl_study.logs.lock.writer_pid`, ``None`` if none
    was)."""

    rows: list[TrialRow]
    provenance: list[dict[str, str]]
    identity: RunIdentity
    damaged: list[Path]
    warnings: list[str]
    files: list[tuple[Path, list[str]]]
    writer: str | None

    def records(self, wanted: set[str]) -> list[TrialRecord]:
        """The whole records of the ``wanted`` trials, decoding only the files that log one
        (the records of the intact chunks of a file salvaged)."""
        return _records_of(self.identity, self.files, wanted, self.damaged)


@dataclass
class _IntactFile:
    """A file that read cleanly through its summary: its provenance and its trial records."""

    path: Path
    records: list[TrialRecord]
    provenance: dict[str, str]
    damage: list[str] = field(default_factory=list)
    content_faults: list[str] = field(default_factory=list)

    @property
    def faults(self) -> list[str]:
        return []


def _intact_summary(path: Path, data: bytes) -> _IntactFile | None:
    """The file ``path`` (its content ``data``) through its summary, or ``None`` if it does not
    read cleanly.

    Every CRC that covers what is read holds (:func:`~cirl_study.logs.scan.section_crcs_hold`:
    the data section, chunks included, and the summary); the file frames no more records than
    a log file may hold (:func:`~cirl_study.logs.bounds.framed_records`, before the summary is
    parsed); there is one ``provenance`` record stating a run identity and a ``trial_index``
    listing as many distinct trials as the summary counts, at most
    :data:`~cirl_study.logs.bounds.MAX_FILE_TRIALS`. Every chunk holding a trial is
    decompressed with its own CRC checked, and every record must be complete and consistent
    (:func:`~cirl_study.logs.record_checks.decode_trials`) and listed by the index in order.
    """
    budget = Budget()
    try:
        if not section_crcs_hold(data):
            return None
        budget.parsed(framed_records(data))
        reader = make_reader(io.BytesIO(data), validate_crcs=True)
        summary = reader.get_summary()
        if summary is None or summary.statistics is None:
            return None
        metadata = list(reader.iter_metadata())
        trial_channels = [c.id for c in summary.channels.values() if c.topic == TRIAL_TOPIC]
        counts = summary.statistics.channel_message_counts
        announced = sum(counts.get(c, 0) for c in trial_channels)
        if announced > MAX_FILE_TRIALS:
            return None
        provenance = [m for m in metadata if m.name == PROVENANCE_METADATA_NAME]
        log_format = provenance[0].metadata.get(LOG_FORMAT_KEY, "") if provenance else ""
        payloads = _trial_payloads(data, summary, budget)
        decoded = decode_trials(record_payload(payload, log_format) for payload in payloads)
    except Exception:  # any damage: the record-by-record scan will say what and salvage
        return None
    index = trial_index(metadata)
    records = [record for record, faults in decoded if record is not None and not faults]
    sound = (
        len(provenance) == 1
        and _states_identity(provenance[0].metadata)
        and index is not None
        and len(index) == len(set(index)) == announced
        and [r.trial_id for r in records] == index
    )
    if not sound:
        return None
    return _IntactFile(path, records, dict(provenance[0].metadata))


def _trial_payloads(data: bytes, summary: Summary, budget: Budget) -> list[bytes]:
    """The ``/cirl/trial`` payloads of a file, in file order, through its indexes.

    For every chunk that holds trial messages (by the summary's chunk indexes) the chunk is
    decompressed within ``budget`` (:meth:`~cirl_study.logs.bounds.Budget.inflate`) and its
    uncompressed CRC checked; the trial channel's message index, which
    the chunk index points to, gives each trial message's offset in the chunk, so no other
    message is parsed (the replay topics are most of a file), where the mcap package's reader
    parses every message of a chunk in pure Python (``benchmarks/README.md`` compares them).

    Raises:
        ValueError: anything does not match (the caller then scans the file record by
            record, which says what is wrong).
    """
    (channel,) = [c.id for c in summary.channels.values() if c.topic == TRIAL_TOPIC]
    payloads = []
    for index in sorted(summary.chunk_indexes, key=lambda i: i.chunk_start_offset):
        if channel not in index.message_index_offsets:
            continue
        start = index.chunk_start_offset + RECORD_PREFIX
        chunk = Chunk.read(ReadDataStream(io.BytesIO(data[start : start + index.chunk_length])))
        if not chunk.uncompressed_crc:
            raise ValueError("a chunk carries no CRC")
        raw = budget.inflate(chunk)
        position = index.message_index_offsets[channel]
        for offset in _message_offsets(data, position, channel, budget):
            opcode, length, channel_id = struct.unpack_from("<BQH", raw, offset)
            if opcode != Opcode.MESSAGE or channel_id != channel:
                raise ValueError(f"no trial message at offset {offset}")
            body = offset + RECORD_PREFIX
            payloads.append(raw[body + MESSAGE_HEADER : body + length])
    return payloads


def _message_offsets(data: bytes, position: int, channel: int, budget: Budget) -> list[int]:
    """The offsets in its chunk of every message a ``MessageIndex`` record lists, sorted (each
    counted in ``budget`` before any is read).

    The record at ``position`` is opcode, length, ``channel_id`` (u16), ``records_length``
    (u32) and ``(log_time, offset)`` pairs of u64 (MCAP specification); read with numpy
    rather than the mcap package's reader, which takes each pair in Python.
    """
    opcode, length, channel_id, records_length = struct.unpack_from("<BQHI", data, position)
    if opcode != Opcode.MESSAGE_INDEX or channel_id != channel:
        raise ValueError("no message index of the trial channel there")
    if records_length % 16 or records_length + 6 != length:
        raise ValueError("a message index of the wrong length")
    budget.parsed(records_length // 16)
    start = position + RECORD_PREFIX + 6
    pairs = np.frombuffer(data, dtype="<u8", count=records_length // 8, offset=start)
    return sorted(pairs[1::2].tolist())


def _states_identity(provenance: dict[str, str]) -> bool:
    try:
        RunIdentity.of(provenance)
    except ValueError:
        return False
    return True


@dataclass(frozen=True)
class _FileReading:
    """What :func:`read_run` keeps of one file, read in a worker (:func:`_reading`): its
    faults, its run identity (or why it has none), its trial ids, provenance and rows;
    ``unreadable`` when nothing of it could be read (``damage`` then says why)."""

    path: Path
    damage: list[str]
    content_faults: list[str]
    salvage_warning: str
    identity: RunIdentity | UserError
    trial_ids: list[str]
    provenance: dict[str, str] | None
    rows: list[TrialRow]
    unreadable: bool = False


def _reading(path: Path) -> _FileReading:
    """One file of :func:`read_run`, its records reduced to rows."""
    try:
        contents = _read_file(path)
    except UnreadableFile as error:
        return _FileReading(
            path=path,
            damage=[error.reason],
            content_faults=[],
            salvage_warning=f"{path}: {error.reason}; passed over, nothing of it read",
            identity=error,
            trial_ids=[],
            provenance=None,
            rows=[],
            unreadable=True,
        )
    sound = not contents.content_faults
    try:
        identity: RunIdentity | UserError = _file_identity(contents)
    except UserError as error:
        identity = error
    return _FileReading(
        path=path,
        damage=contents.damage,
        content_faults=contents.content_faults,
        salvage_warning=_salvage_warning(contents) if contents.damage and sound else "",
        identity=identity,
        trial_ids=[record.trial_id for record in contents.records],
        provenance=contents.provenance,
        rows=[TrialRow.of(record, path.name) for record in contents.records] if sound else [],
    )


def _read_file(path: Path) -> _IntactFile | FileContents:
    """Fast read of an intact file through its summary, else the record-by-record scan.

    Raises:
        cirl_study.files.UnreadableFile: ``path`` is no regular file, or too long to read.
        UserError: it is not an MCAP file.
    """
    data = read_log(path)
    intact = _intact_summary(path, data)
    return intact if intact is not None else _readable(contents_of(scan_data(path, data)))


def read_run(
    run_dir: str | Path,
    pipeline_of: PipelineOf,
    *,
    salvage: bool = False,
    meanwhile: Callable[[], object] = lambda: None,
) -> RunContents:
    """Read every complete log file of ``run_dir`` into rows (see the module docstring).

    Files are read on every core, each whole in one worker process
    (:func:`~cirl_study.workers.started`), and each record comes back only as its
    row, so memory grows with the run's trial count by a row (a few hundred bytes), not a
    record, per trial; :func:`read_trials` fetches whole records by id. Files are
    judged in their order, so the first fault found is the one reading in order would find.

    Args:
        run_dir: the run directory.
        pipeline_of: the study's judgement of the pipeline each file's identity carries,
            asked in this process.
        salvage: keep the intact chunks of a damaged file (with a warning) instead of
            refusing it.
        meanwhile: called once the files are handed to the workers, e.g. to import what the
            analysis needs while they are read.
    """
    run_dir = Path(run_dir)
    # Everything asked of the directory first: its log files, whether a run writes to it,
    # and what each temporary file is; then the files are read.
    logs = _complete_files(run_dir)
    writer = writer_pid(run_dir)
    temporary = [(path, non_regular(path)) for path in temp_files(run_dir)]
    rows: list[TrialRow] = []
    identities: dict[RunIdentity, Path] = {}
    first_file: dict[str, Path] = {}
    provenance, damaged, warnings = [], [], []
    files: list[tuple[Path, list[str]]] = []
    with started(_reading, logs) as readings:
        meanwhile()
        for reading in readings:
            path = reading.path
            content_faults = [
                *pipeline_faults(reading.provenance, pipeline_of),
                *reading.content_faults,
            ]
            if content_faults:
                damage = f"damaged ({reading.damage[0]}) and " if reading.damage else ""
                raise UserError(
                    f"{path}: {damage}unusable ({content_faults[0]}); "
                    f"`cirl-study validate {run_dir}` lists every fault"
                )
            if reading.unreadable and not salvage:
                raise UserError(
                    f"{path}: {reading.damage[0]}; move it out of {run_dir}, or analyze with "
                    "--partial to read the rest"
                )
            if reading.damage and not salvage:
                raise UserError(
                    f"{path}: damaged ({reading.damage[0]}); move it out of {run_dir} "
                    "and run the pipeline again to replay its trials, or analyze with --partial "
                    "to keep what its intact chunks hold"
                )
            if reading.damage:
                warnings.append(reading.salvage_warning)
                damaged.append(path)
            if reading.unreadable:
                continue
            if isinstance(reading.identity, UserError):
                raise reading.identity
            identities.setdefault(reading.identity, path)
            _same_identity(run_dir, identities)
            _refuse_duplicates(first_file, path, reading.trial_ids)
            provenance.append(reading.provenance)
            # The rows' own ids: no second string per trial.
            files.append((path, [row.trial_id for row in reading.rows]))
            rows += reading.rows
    unfinished = []
    for path, reason in temporary:
        if reason is None:
            unfinished.append(path)
        elif salvage:
            warnings.append(f"{path}: {reason}; passed over")
        else:
            raise UserError(
                f"{path}: {reason}, not a temporary log file; move it out of {run_dir}, or "
                "analyze with --partial to read the rest"
            )
    if unfinished:
        warnings.append(
            f"{run_dir}: {len(unfinished)} unfinished temporary file(s) of an interrupted run "
            "ignored; run the pipeline again to complete the run"
            if writer is None
            else f"{run_dir}: {len(unfinished)} temporary file(s) ignored: a cirl-study run "
            f"(pid {writer}) is still writing it"
        )
    return RunContents(
        rows=sorted(rows, key=lambda row: row.trial_id),
        provenance=[p for p in provenance if p is not None],
        identity=_same_identity(run_dir, identities),
        damaged=damaged,
        warnings=warnings,
        files=files,
        writer=writer,
    )


@dataclass(frozen=True)
class LoggedRun:
    """What a run directory holds, for resuming it: each complete file with the ids of the
    trials its records decode to (:func:`logged_run`)."""

    identity: RunIdentity
    files: list[tuple[Path, list[str]]]

    @property
    def trial_ids(self) -> set[str]:
        """The ids of every trial logged (each in one file: :func:`logged_run` checks)."""
        return {trial_id for _, trial_ids in self.files for trial_id in trial_ids}

    def records(self, wanted: set[str]) -> list[TrialRecord]:
        """The whole records of the ``wanted`` trials, decoding only the files that log one
        (each checked again, and found of this run)."""
        return _records_of(self.identity, self.files, wanted)


def logged_run(run_dir: str | Path, identity: RunIdentity, pipeline_of: PipelineOf) -> LoggedRun:
    """The trials already logged in the complete files of ``run_dir``, for resuming
    ``identity``'s run (whose pipeline ``pipeline_of`` judges, as every file's).

    What a file holds is decided from its records, never from its own index or counts: every
    file is read as :func:`read_run` reads it (every CRC, every record decoded and checked,
    a file per core), and only the ids come back. An absent directory has none. A damaged
    or faulty file, an entry named like a log that is no regular file, a trial logged twice,
    or files of another run than ``identity``'s are refused rather than guessed at, so that
    a resumed run neither loses nor duplicates a trial, nor mixes runs.
    """
    run_dir = Path(run_dir)
    if not run_dir.exists():
        return LoggedRun(identity, [])
    identities: dict[RunIdentity, Path] = {}
    first_file: dict[str, Path] = {}
    files = []
    with started(_reading, _complete_files(run_dir, require_any=False)) as readings:
        for reading in readings:
            path = reading.path
            if reading.unreadable:
                raise UserError(f"{path}: {reading.damage[0]}; move it out of {run_dir}")
            faults = [
                *reading.damage,
                *pipeline_faults(reading.provenance, pipeline_of),
                *reading.content_faults,
            ]
            if faults:
                raise UserError(
                    f"{path} is damaged ({faults[0]}); move it out of {run_dir} "
                    "to run its trials again"
                )
            if isinstance(reading.identity, UserError):
                raise reading.identity
            identities.setdefault(reading.identity, path)
            _same_identity(run_dir, identities)
            _refuse_duplicates(first_file, path, reading.trial_ids)
            files.append((path, reading.trial_ids))
    if files:
        found = _same_identity(run_dir, identities)
        if found != identity:
            raise AnotherRunLogged(f"{run_dir}: {_another_run(found, identity)}", found)
    return LoggedRun(identity, files)


class AnotherRunLogged(UserError):
    """A run directory holds the logs of another run than the one asked for: its identity is
    :attr:`logged` (whether its settings are the asked run's is the study's to judge)."""

    def __init__(self, message: str, logged: RunIdentity) -> None:
        super().__init__(message)
        self.logged = logged


def read_trials(
    run_dir: str | Path, identity: RunIdentity, pipeline_of: PipelineOf, wanted: set[str]
) -> list[TrialRecord]:
    """The records of the ``wanted`` trials of the run in ``run_dir`` (of ``identity``'s run),
    with :func:`logged_run`'s checks of every file."""
    return logged_run(run_dir, identity, pipeline_of).records(wanted)


def _records_of(
    identity: RunIdentity,
    files: Iterable[tuple[Path, Sequence[str]]],
    wanted: set[str],
    salvaged: Collection[Path] = (),
) -> list[TrialRecord]:
    """The records of the ``wanted`` trials of ``files`` (each with the ids it logs), each
    file that logs one decoded with :func:`read_run`'s checks and found of ``identity``'s run;
    the files ``salvaged`` may be damaged (their intact chunks are read).
    """
    records = []
    for path, trial_ids in files:
        if not wanted.intersection(trial_ids):
            continue
        contents = _read_file(path)
        damage = [] if path in salvaged else contents.damage
        faults = [*damage, *contents.content_faults]
        if faults:
            raise UserError(f"{path}: unusable ({faults[0]})")
        found = _file_identity(contents)
        if found != identity:
            raise UserError(
                f"{path}: now holds the logs of another run ({_difference(found, identity)})"
            )
        records += [record for record in contents.records if record.trial_id in wanted]
    return records


def _another_run(logged: RunIdentity, asked: RunIdentity) -> str:
    """Why the run ``logged`` in a directory is not the run ``asked`` to resume, and what to
    do. (A pipeline of the same name whose settings are the logged run's resumes it: the
    study judges that, :func:`cirl_study.study.runner.same_settings`, before this is said.)
    """
    if logged.pipeline_name != asked.pipeline_name or logged.run_id == asked.run_id:
        return (
            f"holds the logs of another run ({_difference(logged, asked)}); "
            "use another --out directory"
        )
    if logged.pipeline_text == asked.pipeline_text and logged.demonstrations:
        return (
            f"holds run {logged.run_id}, made from another file of demonstrations than "
            f"{asked.pipeline_file} reads now (run {asked.run_id}); restore the file the run "
            "was made with to resume it (its logs carry it), or use another --out directory"
        )
    return (
        f"holds run {logged.run_id}, made from another version of {asked.pipeline_file}, which "
        f"is now run {asked.run_id} with other settings; restore the settings the run was made "
        "with to resume it (`cirl-study show` prints its pipeline), or use another --out "
        "directory"
    )


def _file_identity(contents: _IntactFile | FileContents) -> RunIdentity:
    """The run identity a file states, once every record of it is found to carry its run id."""
    try:
        identity = RunIdentity.of(contents.provenance or {})
    except ValueError as error:
        raise UserError(f"{contents.path}: not a log of a cirl-study run: {error}") from None
    foreign = next((r for r in contents.records if r.run_id != identity.run_id), None)
    if foreign is not None:
        raise UserError(
            f"{contents.path}: trial {terminal(foreign.trial_id)} belongs to run "
            f"{terminal(foreign.run_id)}, the file to run {identity.run_id}"
        )
    return identity


def _same_identity(run_dir: Path, identities: dict[RunIdentity, Path]) -> RunIdentity:
    """The one identity of ``identities`` (each with the first file stating it), or a refusal."""
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
    if announced is not None and announced <= MAX_FILE_TRIALS:
        recovered += f" of {announced}"
    else:
        recovered += " (how many were lost is unknown)"
    more = f" and {len(contents.damage) - 1} more fault(s)" if len(contents.damage) > 1 else ""
    return (
        f"{contents.path}: damaged ({contents.damage[0]}{more}); recovered {recovered} "
        f"from {scan.chunks - scan.damaged_chunks} intact chunk(s) of {scan.chunks} read"
    )


def _refuse_duplicates(first_file: dict[str, Path], path: Path, trial_ids: list[str]) -> None:
    """Add the ``trial_ids`` of ``path`` to ``first_file`` (each id's file); an id already
    there, logged in two files, is refused."""
    for trial_id in trial_ids:
        if trial_id in first_file:
            raise UserError(
                f"trial {terminal(trial_id)} is logged twice: in {first_file[trial_id]} and "
                f"in {path}"
            )
        first_file[trial_id] = path
