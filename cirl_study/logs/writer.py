"""Writing the trials of a run to an MCAP file, atomically.

The file is written under the temporary name ``<path>.tmp`` in the same directory; only a
clean exit from the ``with`` block finishes it (summary, indexes, CRCs), syncs it to disk and
renames it to ``path``. An exception or a killed process leaves only the temporary file,
which readers ignore.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType
from typing import IO, Self

import mcap
from mcap.writer import CompressionType, Writer

from cirl_study.files import open_for_writing
from cirl_study.logs.episode import episode_messages
from cirl_study.logs.format import (
    MESSAGE_ENCODING,
    PROVENANCE_METADATA_NAME,
    SCHEMA_ENCODING,
    TRIAL_INDEX_KEY,
    TRIAL_INDEX_METADATA_NAME,
    temp_path,
    trial_duration_ns,
)
from cirl_study.logs.provenance import RunIdentity
from cirl_study.logs.schemas import CHANNELS
from cirl_study.measure_registry import measure_faults
from cirl_study.record import DecodeError, TrialRecord, decode, encode
from cirl_study.version import __version__

#: Chunks are closed once they hold this many uncompressed bytes; a truncated file loses at
#: most the chunk being written.
CHUNK_SIZE = 1 << 20

LIBRARY = f"cirl-study {__version__}; python mcap {mcap.__version__}"


class TrialLogWriter:
    """One MCAP log file of a run: ``with TrialLogWriter(path, provenance) as log: log.write(r)``.

    ``provenance`` (string to string, stating the run's identity:
    :func:`~cirl_study.logs.provenance.collect_provenance`) becomes the file's ``provenance``
    metadata record. Each :meth:`write` logs one trial record (docs/design.md
    §7) with its reward maps and its step-by-step replay; log times follow the layout of
    :mod:`cirl_study.logs.format`. A complete file ends its data section with the
    ``trial_index`` metadata record, the ids of its trials in order. Chunks are
    zstd-compressed; chunk, data-section and summary CRCs are all written.
    """

    def __init__(
        self, path: str | Path, provenance: Mapping[str, str], *, chunk_size: int = CHUNK_SIZE
    ) -> None:
        if not all(isinstance(k, str) and isinstance(v, str) for k, v in provenance.items()):
            raise TypeError("provenance must map strings to strings")
        self.run_id = RunIdentity.of(provenance).run_id  # ValueError unless it names a run
        self.path = Path(path)
        self.temp_path = temp_path(self.path)
        self.provenance = dict(provenance)
        self.chunk_size = chunk_size
        self.trial_count = 0
        self._clock_ns = 0
        self._file: IO[bytes] | None = None
        self._writer: Writer | None = None
        self._channel_ids: dict[str, int] = {}
        self._sequences: dict[str, int] = {}
        self._trial_ids: list[str] = []

    def __enter__(self) -> Self:
        if self.path.exists():
            raise FileExistsError(f"{self.path} already exists")
        self._file = open_for_writing(self.temp_path)  # closed in __exit__
        self._writer = Writer(
            self._file,
            chunk_size=self.chunk_size,
            compression=CompressionType.ZSTD,
            enable_data_crcs=True,
        )
        self._writer.start(profile="", library=LIBRARY)
        self._writer.add_metadata(PROVENANCE_METADATA_NAME, self.provenance)
        schema_ids: dict[str, int] = {}
        for topic, name, schema in CHANNELS:
            if name not in schema_ids:
                schema_ids[name] = self._writer.register_schema(
                    name=name, encoding=SCHEMA_ENCODING, data=encode(schema)
                )
            self._channel_ids[topic] = self._writer.register_channel(
                topic=topic, message_encoding=MESSAGE_ENCODING, schema_id=schema_ids[name]
            )
            self._sequences[topic] = 0
        return self

    def write(self, record: TrialRecord) -> None:
        """Log one trial record (and its replay topics) as the next trial of the file.

        Raises:
            ValueError: the record belongs to another run than the file's, its measures break
                the registry (:func:`~cirl_study.measure_registry.measure_faults`: e.g. a
                NaN, which JSON would hold as ``null``, the value of an undefined measure), or
                it would not decode again: nothing of it is written.
        """
        if self._writer is None:
            raise RuntimeError("TrialLogWriter.write called outside its `with` block")
        if record.run_id != self.run_id:
            raise ValueError(
                f"trial {record.trial_id} belongs to run {record.run_id}, the file to {self.run_id}"
            )
        # Measures that are not a mapping at all are refused below, by decoding the payload.
        faults = measure_faults(record.measures) if isinstance(record.measures, dict) else []
        if faults:
            raise ValueError(f"trial {record.trial_id} cannot be logged: {'; '.join(faults)}")
        payloads = [
            (message, encode(message.payload))
            for message in episode_messages(record, self._clock_ns)
        ]
        try:
            decode(payloads[0][1])
        except DecodeError as error:
            raise ValueError(f"trial {record.trial_id} cannot be logged: {error}") from None
        for message, data in payloads:
            self._writer.add_message(
                channel_id=self._channel_ids[message.topic],
                log_time=message.log_time,
                publish_time=message.log_time,
                data=data,
                sequence=self._sequences[message.topic],
            )
            self._sequences[message.topic] += 1
        self._clock_ns += trial_duration_ns(record.learning_steps, record.deployment_steps)
        self._trial_ids.append(record.trial_id)
        self.trial_count += 1

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        assert self._file is not None and self._writer is not None
        try:
            if exc_type is None:
                index = {TRIAL_INDEX_KEY: "\n".join(self._trial_ids)}
                self._writer.add_metadata(TRIAL_INDEX_METADATA_NAME, index)
                self._writer.finish()
                self._file.flush()
                os.fsync(self._file.fileno())
        finally:
            self._file.close()
            self._writer = None
        if exc_type is None:
            os.replace(self.temp_path, self.path)
            _sync_directory(self.path.parent)


def _sync_directory(directory: Path) -> None:
    """Make a rename inside ``directory`` durable (a no-op where directories cannot be opened)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
