"""The trial records and provenance of one log file, with every content fault found.

Built on :func:`~cirl_study.logs.scan.scan_file` (storage damage: CRCs, truncation, summary).
Content checks: the ``provenance`` metadata record; the schema name and encodings of every
channel; each ``/cirl/trial`` payload decodes into a
:class:`~cirl_study.record.TrialRecord`, is its canonical JSON and is consistent
(:func:`~cirl_study.logs.record_checks.decode_trials`); no trial id twice;
in an undamaged file, trial log times follow the documented layout, the replay topics hold
as many messages as the records imply, and the ``trial_index`` metadata record lists the
file's trials in order. A file holding more trials than
:data:`~cirl_study.logs.bounds.MAX_FILE_TRIALS` is damaged (only that many are decoded), and
so is one holding a record past a bound
(:class:`~cirl_study.logs.record_checks.BoundFault`: the record is passed over).
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from mcap.records import Metadata

from cirl_study.escape import terminal
from cirl_study.logs.bounds import MAX_FILE_TRIALS
from cirl_study.logs.episode import replay_counts
from cirl_study.logs.format import (
    GRID_SCHEMA_NAME,
    LOG_FORMAT_KEY,
    MESSAGE_ENCODING,
    PROVENANCE_METADATA_NAME,
    SCHEMA_ENCODING,
    TRIAL_INDEX_KEY,
    TRIAL_INDEX_METADATA_NAME,
    TRIAL_SCHEMA_NAME,
    TRIAL_TOPIC,
    trial_duration_ns,
)
from cirl_study.logs.provenance import NO_IDENTITY, RunIdentity
from cirl_study.logs.record_checks import BoundFault, decode_trials, payload_trial_id
from cirl_study.logs.scan import FileScan, scan_file
from cirl_study.logs.versions import LOG_FORMAT, record_payload, trial_id
from cirl_study.record import TrialRecord, encode


@dataclass
class FileContents:
    """Decoded content of one log file.

    ``records`` are the readable trial records in file order; ``damage`` the storage faults
    (a damaged file still yields the records of its intact chunks); ``content_faults`` what is
    wrong with the content that could be read.
    """

    scan: FileScan
    records: list[TrialRecord] = field(default_factory=list)
    provenance: dict[str, str] | None = None
    content_faults: list[str] = field(default_factory=list)

    @property
    def path(self) -> Path:
        return self.scan.path

    @property
    def damage(self) -> list[str]:
        return self.scan.faults

    @property
    def faults(self) -> list[str]:
        """All faults: storage damage first, then content."""
        return [*self.damage, *self.content_faults]


def read_file_contents(path: Path) -> FileContents:
    """Scan ``path``, decode its trials and provenance, and check its content."""
    return contents_of(scan_file(path))


def contents_of(scan: FileScan) -> FileContents:
    """:func:`read_file_contents` of a file already scanned."""
    contents = FileContents(scan=scan)
    if not scan.readable:
        return contents
    faults = contents.content_faults
    _read_provenance(contents)
    faults.extend(_channel_faults(scan))
    trial_messages = scan.topic_messages(TRIAL_TOPIC)
    if len(trial_messages) > MAX_FILE_TRIALS:
        scan.faults.append(
            f"{len(trial_messages)} trial messages, more than the {MAX_FILE_TRIALS} a log file "
            f"may hold: only the first {MAX_FILE_TRIALS} are read"
        )
        trial_messages = trial_messages[:MAX_FILE_TRIALS]
    seen: set[str] = set()
    log_format = (contents.provenance or {}).get(LOG_FORMAT_KEY, LOG_FORMAT)
    payloads = [record_payload(message.data, log_format) for message in trial_messages]
    decoded = decode_trials(payloads)
    for index, (payload, (record, problems)) in enumerate(zip(payloads, decoded, strict=True)):
        # An undecodable payload may still name its trial.
        trial_id = payload_trial_id(payload) if record is None else record.trial_id
        label = f"trial message {index}" if trial_id is None else f"trial {terminal(trial_id)}"
        past = [problem for problem in problems if isinstance(problem, BoundFault)]
        if past:  # damage: the record is passed over, like a damaged chunk
            scan.faults.append(f"{label}: {past[0]}")
            continue
        faults.extend(f"{label}: {problem}" for problem in problems)
        if record is None or problems:
            continue
        if encode(record) != payload:
            faults.append(f"{label}: payload is not canonical JSON")
        if record.trial_id in seen:
            faults.append(f"{label}: logged twice in this file")
        seen.add(record.trial_id)
        contents.records.append(record)
    if not contents.damage and len(contents.records) == len(trial_messages):
        faults.extend(_layout_faults(contents.scan, contents.records))
        faults.extend(_index_faults(contents.scan, contents.records))
    return contents


def trial_index(metadata: Sequence[Metadata]) -> list[str] | None:
    """The trial ids a file's ``trial_index`` record lists (in the current names, see
    :mod:`cirl_study.logs.versions`), ``None`` without exactly one or
    when it lists more than :data:`~cirl_study.logs.bounds.MAX_FILE_TRIALS` (not split: a
    record of newlines alone would be millions of strings)."""
    records = [m for m in metadata if m.name == TRIAL_INDEX_METADATA_NAME]
    if len(records) != 1 or TRIAL_INDEX_KEY not in records[0].metadata:
        return None
    text = records[0].metadata[TRIAL_INDEX_KEY]
    if text.count("\n") >= MAX_FILE_TRIALS:
        return None
    provenance = [m.metadata for m in metadata if m.name == PROVENANCE_METADATA_NAME]
    log_format = provenance[0].get(LOG_FORMAT_KEY, LOG_FORMAT) if provenance else LOG_FORMAT
    return [trial_id(logged, log_format) for logged in text.split("\n")] if text else []


def _index_faults(scan: FileScan, records: list[TrialRecord]) -> list[str]:
    index = trial_index(scan.metadata)
    if index is None:
        return [
            f"no {TRIAL_INDEX_METADATA_NAME!r} metadata record listing at most "
            f"{MAX_FILE_TRIALS} trials"
        ]
    if index != [record.trial_id for record in records]:
        return [f"the {TRIAL_INDEX_METADATA_NAME!r} record does not list the file's trials"]
    return []


def _read_provenance(contents: FileContents) -> None:
    records = [m for m in contents.scan.metadata if m.name == PROVENANCE_METADATA_NAME]
    if len(records) != 1:
        contents.content_faults.append(
            f"{len(records)} {PROVENANCE_METADATA_NAME!r} metadata records, expected 1"
        )
    if records:
        contents.provenance = dict(records[0].metadata)
        try:
            RunIdentity.of(contents.provenance)
        except ValueError as error:
            contents.content_faults.append(f"{NO_IDENTITY}{error}")


def _channel_faults(scan: FileScan) -> list[str]:
    faults = []
    trial_channels = scan.channel_ids(TRIAL_TOPIC)
    if len(trial_channels) != 1:
        faults.append(f"{len(trial_channels)} channels on {TRIAL_TOPIC}, expected 1")
    channels = {**scan.summary_channels, **scan.channels}
    schemas = {**scan.summary_schemas, **scan.schemas}
    for channel in channels.values():
        schema = schemas.get(channel.schema_id)
        topic = terminal(channel.topic)
        if channel.message_encoding != MESSAGE_ENCODING:
            faults.append(f"{topic}: message encoding '{terminal(channel.message_encoding)}'")
        if schema is None:
            faults.append(f"{topic}: no schema")
            continue
        if schema.encoding != SCHEMA_ENCODING:
            faults.append(f"{topic}: schema encoding '{terminal(schema.encoding)}'")
        expected = TRIAL_SCHEMA_NAME if channel.topic == TRIAL_TOPIC else None
        if channel.topic.startswith("/cirl/reward/"):
            expected = GRID_SCHEMA_NAME
        if expected is not None and schema.name != expected:
            faults.append(f"{topic}: schema '{terminal(schema.name)}', expected {expected!r}")
        try:
            json.loads(schema.data)
        except ValueError:
            faults.append(f"{topic}: schema '{terminal(schema.name)}' is not valid JSON")
        except RecursionError:
            faults.append(f"{topic}: schema '{terminal(schema.name)}' nests too deep to read")
    return faults


def _layout_faults(scan: FileScan, records: list[TrialRecord]) -> list[str]:
    """Trial log times and replay-topic message counts implied by the records."""
    faults = []
    start_ns = 0
    for record, message in zip(records, scan.topic_messages(TRIAL_TOPIC), strict=True):
        if message.log_time != start_ns:
            faults.append(
                f"trial {terminal(record.trial_id)}: logged at {message.log_time} ns, "
                f"expected {start_ns} ns from its position in the file"
            )
            break
        start_ns += trial_duration_ns(record.learning_steps, record.deployment_steps)
    expected: Counter[str] = Counter()
    for record in records:
        expected.update(replay_counts(record))
    for topic, count in sorted(expected.items()):
        found = len(scan.topic_messages(topic))
        if found != count:
            faults.append(f"{topic}: {found} messages, the trial records imply {count}")
    return faults
