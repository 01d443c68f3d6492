"""A fault-tolerant pass over one MCAP file: every record, every CRC, every count.

The file is walked record by record (opcode, length, body), so a damaged chunk is skipped
without losing the chunks after it, and a truncated file yields everything before the cut.
Checked: the magic bytes at both ends; each chunk's CRC of its uncompressed data; the
data-section CRC in the Data End record; the summary CRC in the footer; the summary's
statistics (message counts per channel, chunk, metadata, schema and channel counts) and its
chunk and metadata indexes against what the data section really holds. The file is read and
its chunks inflated within the bounds of :mod:`cirl_study.logs.bounds`: a file that cannot be
read (not a regular file, too long) is unreadable, a chunk past a bound is damaged, and the
walk ends at the first record past the file's record bound.
"""

from __future__ import annotations

import struct
import zlib
from collections import Counter
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path

import zstandard
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    Message,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
)

from cirl_study.files import UnreadableFile
from cirl_study.logs.bounds import BoundExceeded, Budget, read_log

MAGIC = b"\x89MCAP0\r\n"
RECORD_PREFIX = 9
"""Bytes before every record's body: opcode (1 byte) and body length (8 bytes)."""
MESSAGE_HEADER = 22
"""Bytes of a Message record's body before its payload: channel id (2), sequence (4), log
time (8) and publish time (8)."""
_FOOTER_CRC_SPAN = 16  # the footer's summary_start and summary_offset_start precede its CRC

#: What a damaged record can raise while it is parsed or decompressed.
PARSE_ERRORS = (
    McapError,
    struct.error,
    ValueError,
    OverflowError,
    EOFError,
    zstandard.ZstdError,
    RuntimeError,
    MemoryError,
)


@dataclass
class FileScan:
    """What a pass over one MCAP file found.

    ``messages`` holds the messages of intact chunks only, in file order; ``faults`` lists
    every problem found (empty for a sound file); ``readable`` is false when the file is not
    an MCAP file at all, or could not be read (not a regular file, too long); ``budget`` is
    what reading it has spent.
    """

    path: Path
    size: int
    readable: bool = True
    faults: list[str] = field(default_factory=list)
    header: Header | None = None
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    messages: list[Message] = field(default_factory=list)
    metadata: list[Metadata] = field(default_factory=list)
    chunks: int = 0
    damaged_chunks: int = 0
    statistics: Statistics | None = None
    complete: bool = False
    chunk_offsets: list[int] = field(default_factory=list)
    metadata_offsets: list[int] = field(default_factory=list)
    chunk_indexes: list[ChunkIndex] = field(default_factory=list)
    metadata_indexes: list[MetadataIndex] = field(default_factory=list)
    summary_schemas: dict[int, Schema] = field(default_factory=dict)
    summary_channels: dict[int, Channel] = field(default_factory=dict)
    budget: Budget = field(default_factory=Budget)

    def channel_ids(self, topic: str) -> list[int]:
        """Ids of the channels of ``topic``."""
        channels = {**self.summary_channels, **self.channels}
        return sorted(i for i, channel in channels.items() if channel.topic == topic)

    def topic_messages(self, topic: str) -> list[Message]:
        """Readable messages of ``topic``, in file order."""
        ids = set(self.channel_ids(topic))
        return [m for m in self.messages if m.channel_id in ids]

    def summary_message_count(self, topic: str) -> int | None:
        """Messages of ``topic`` the summary statistics announce (``None`` without a summary)."""
        if self.statistics is None:
            return None
        counts = self.statistics.channel_message_counts
        return sum(counts.get(i, 0) for i in self.channel_ids(topic))


def scan_file(path: Path) -> FileScan:
    """Walk the file at ``path`` and check everything listed in the module docstring."""
    try:
        data = read_log(path)
    except UnreadableFile as error:
        return FileScan(path=path, size=0, readable=False, faults=[error.reason])
    return scan_data(path, data)


def scan_data(path: Path, data: bytes) -> FileScan:
    """:func:`scan_file` of ``data``, the content of the file ``path`` (read by
    :func:`~cirl_study.logs.bounds.read_log`)."""
    scan = FileScan(path=path, size=len(data))
    if data[: len(MAGIC)] != MAGIC:
        scan.readable = False
        scan.faults.append("not an MCAP file (bad magic bytes at the start)")
        return scan
    _walk(data, scan)
    if scan.complete:
        _check_summary(scan)
    return scan


def _walk(data: bytes, scan: FileScan) -> None:
    position = len(MAGIC)
    in_summary = False
    summary_start: int | None = None
    while True:
        if position + RECORD_PREFIX > len(data):
            scan.faults.append(f"truncated: the file ends at byte {len(data)} without a footer")
            return
        try:
            scan.budget.parsed()
        except BoundExceeded as error:
            scan.faults.append(f"unread past byte {position}: {error}")
            return
        opcode, length = struct.unpack_from("<BQ", data, position)
        end = position + RECORD_PREFIX + length
        if end > len(data):
            scan.faults.append(
                f"truncated: the {_name(opcode)} record at byte {position} needs {length} "
                f"bytes but the file ends at byte {len(data)}"
            )
            return
        body = data[position + RECORD_PREFIX : end]
        if in_summary and summary_start is None and opcode != Opcode.FOOTER:
            summary_start = position
        try:
            if opcode == Opcode.FOOTER:
                if not in_summary:
                    scan.faults.append("the file has no data end record")
                _footer(data, scan, Footer.read(_stream(body)), position, end, summary_start)
                return
            if opcode == Opcode.DATA_END:
                in_summary = True
                _data_end(data, scan, DataEnd.read(_stream(body)), position)
            else:
                _record(scan, opcode, body, position, in_summary)
        except PARSE_ERRORS as error:
            scan.faults.append(f"unreadable {_name(opcode)} record at byte {position}: {error}")
        position = end


def _stream(body: bytes) -> ReadDataStream:
    return ReadDataStream(BytesIO(body))


def _name(opcode: int) -> str:
    try:
        return Opcode(opcode).name.lower().replace("_", " ")
    except ValueError:
        return f"unknown (opcode {opcode:#04x})"


def _record(scan: FileScan, opcode: int, body: bytes, position: int, in_summary: bool) -> None:
    """Parse one record of the data or summary section into ``scan``."""
    if (opcode == Opcode.HEADER) != (position == len(MAGIC)):
        scan.faults.append(f"unexpected {_name(opcode)} record at byte {position}")
    if opcode == Opcode.HEADER:
        scan.header = Header.read(_stream(body))
    elif opcode == Opcode.CHUNK:
        _chunk(scan, Chunk.read(_stream(body)), position)
    elif opcode == Opcode.MESSAGE:
        scan.messages.append(Message.read(_stream(body), len(body)))
    elif opcode == Opcode.METADATA:
        scan.metadata.append(Metadata.read(_stream(body)))
        scan.metadata_offsets.append(position)
    elif opcode == Opcode.SCHEMA:
        schema = Schema.read(_stream(body))
        (scan.summary_schemas if in_summary else scan.schemas)[schema.id] = schema
    elif opcode == Opcode.CHANNEL:
        channel = Channel.read(_stream(body))
        (scan.summary_channels if in_summary else scan.channels)[channel.id] = channel
    elif opcode == Opcode.STATISTICS:
        scan.statistics = Statistics.read(_stream(body))
    elif opcode == Opcode.CHUNK_INDEX:
        scan.chunk_indexes.append(ChunkIndex.read(_stream(body)))
    elif opcode == Opcode.METADATA_INDEX:
        scan.metadata_indexes.append(MetadataIndex.read(_stream(body)))


def _chunk(scan: FileScan, chunk: Chunk, position: int) -> None:
    scan.chunks += 1
    scan.chunk_offsets.append(position)
    if chunk.uncompressed_crc == 0:
        scan.faults.append(f"chunk at byte {position} carries no CRC")
    try:
        records = _chunk_records(scan.budget, scan.budget.inflate(chunk))
    except PARSE_ERRORS as error:
        scan.damaged_chunks += 1
        scan.faults.append(f"damaged chunk at byte {position}: {error}")
        return
    for record in records:
        if isinstance(record, Schema):
            scan.schemas[record.id] = record
        elif isinstance(record, Channel):
            scan.channels[record.id] = record
        else:
            scan.messages.append(record)


def _chunk_records(budget: Budget, raw: bytes) -> list[Schema | Channel | Message]:
    """The schemas, channels and messages of a chunk's decompressed records, in order (other
    records, which MCAP allows in a chunk, are skipped); each counts in ``budget``.

    Raises:
        BoundExceeded: the file's records pass their bound.
        ValueError: a record runs past the end of the chunk.
    """
    records: list[Schema | Channel | Message] = []
    position = 0
    while position < len(raw):
        budget.parsed()
        opcode, length = struct.unpack_from("<BQ", raw, position)
        end = position + RECORD_PREFIX + length
        if end > len(raw):
            raise ValueError(f"a record at byte {position} of the chunk runs past its end")
        body = raw[position + RECORD_PREFIX : end]
        if opcode == Opcode.SCHEMA:
            records.append(Schema.read(_stream(body)))
        elif opcode == Opcode.CHANNEL:
            records.append(Channel.read(_stream(body)))
        elif opcode == Opcode.MESSAGE:
            records.append(Message.read(_stream(body), length))
        position = end
    return records


def _data_section_crc_holds(data: bytes, data_end_position: int, stored: int) -> bool:
    """The data section's CRC: every byte before the Data End record."""
    return zlib.crc32(data[:data_end_position]) == stored


def _summary_crc_holds(data: bytes, summary_start: int, footer_position: int, stored: int) -> bool:
    """The summary's CRC: from its first record through the footer's two offsets."""
    covered = data[summary_start : footer_position + RECORD_PREFIX + _FOOTER_CRC_SPAN]
    return zlib.crc32(covered) == stored


_FOOTER_BODY = struct.Struct("<QQI")  # summary_start, summary_offset_start, summary_crc
_DATA_END_BODY = struct.Struct("<I")  # data_section_crc


def section_crcs_hold(data: bytes) -> bool:
    """Whether a complete file's data-section and summary CRCs are present and hold.

    Reads only the footer and the Data End record (at the fixed places the footer points to),
    then two CRC-32 passes over the file: the cheap complement of a reader that checks chunk
    CRCs only (:func:`mcap.reader.make_reader` with ``validate_crcs``). Metadata records, such
    as the provenance, lie outside every chunk and are covered by the data-section CRC alone.
    """
    footer_position = len(data) - len(MAGIC) - RECORD_PREFIX - _FOOTER_BODY.size
    if footer_position < len(MAGIC) or data[-len(MAGIC) :] != MAGIC:
        return False
    opcode, length = struct.unpack_from("<BQ", data, footer_position)
    if opcode != Opcode.FOOTER or length != _FOOTER_BODY.size:
        return False
    summary_start, _, summary_crc = _FOOTER_BODY.unpack_from(data, footer_position + RECORD_PREFIX)
    end_of_data = summary_start if summary_start else footer_position
    data_end = end_of_data - RECORD_PREFIX - _DATA_END_BODY.size
    if data_end < len(MAGIC):
        return False
    opcode, length = struct.unpack_from("<BQ", data, data_end)
    if opcode != Opcode.DATA_END or length != _DATA_END_BODY.size:
        return False
    (data_crc,) = _DATA_END_BODY.unpack_from(data, data_end + RECORD_PREFIX)
    return (
        summary_start > 0
        and data_crc != 0
        and summary_crc != 0
        and _data_section_crc_holds(data, data_end, data_crc)
        and _summary_crc_holds(data, summary_start, footer_position, summary_crc)
    )


def _data_end(data: bytes, scan: FileScan, record: DataEnd, position: int) -> None:
    if record.data_section_crc == 0:
        scan.faults.append("the data section carries no CRC")
    elif not _data_section_crc_holds(data, position, record.data_section_crc):
        scan.faults.append("data-section CRC mismatch")


def _footer(
    data: bytes,
    scan: FileScan,
    footer: Footer,
    position: int,
    end: int,
    summary_start: int | None,
) -> None:
    if data[end:] != MAGIC:
        scan.faults.append(f"{len(data) - end} bytes after the footer are not the closing magic")
    if footer.summary_start != (summary_start or 0):
        scan.faults.append(f"the footer points to a summary at byte {footer.summary_start}")
    elif footer.summary_start == 0:
        scan.faults.append("the file has no summary section")
    elif footer.summary_crc == 0:
        scan.faults.append("the summary section carries no CRC")
    elif not _summary_crc_holds(data, footer.summary_start, position, footer.summary_crc):
        scan.faults.append("summary CRC mismatch")
    scan.complete = True


def _check_summary(scan: FileScan) -> None:
    """Compare the summary section with what the data section holds."""
    stats = scan.statistics
    if stats is None:
        scan.faults.append("the summary has no statistics record")
        return
    actual = Counter(m.channel_id for m in scan.messages)
    announced = {i: n for i, n in stats.channel_message_counts.items() if n}
    if stats.message_count != len(scan.messages) or announced != dict(actual):
        scan.faults.append(
            f"the summary counts {stats.message_count} messages, {len(scan.messages)} are readable"
        )
    counts = {
        "chunks": (stats.chunk_count, scan.chunks),
        "metadata records": (stats.metadata_count, len(scan.metadata)),
        "schemas": (stats.schema_count, len(scan.schemas)),
        "channels": (stats.channel_count, len(scan.channels)),
    }
    for name, (expected, found) in counts.items():
        if expected != found:
            scan.faults.append(f"the summary counts {expected} {name}, the file holds {found}")
    if sorted(i.chunk_start_offset for i in scan.chunk_indexes) != scan.chunk_offsets:
        scan.faults.append("the chunk index does not match the chunks in the file")
    if sorted(i.offset for i in scan.metadata_indexes) != scan.metadata_offsets:
        scan.faults.append("the metadata index does not match the metadata records in the file")
    if scan.summary_schemas != scan.schemas or scan.summary_channels != scan.channels:
        scan.faults.append("the summary's schemas or channels differ from the data section's")
