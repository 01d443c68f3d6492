"""The most one log file can make a reader spend, and the one place each bound is enforced.

A run directory may come from someone else, and nothing a reader can check before it spends
covers what a file announces: a chunk's ``uncompressed_size`` and a zstd or lz4 frame's
content size lie outside every CRC, and a chunk's CRC can only be checked once it is
decompressed. So every reader of a log (the record-by-record scan, the fast reader through
the summary, ``validate``, resume) takes a file only through here:

* the file is read whole by :func:`read_log`: a regular file only (a link, a FIFO, a device or
  a directory named like a log is refused, never followed or opened, so a reader never hangs
  on one), of at most :data:`MAX_LOG_FILE_BYTES`;
* every chunk is decompressed by :meth:`Budget.inflate`, its declared size at most
  :data:`MAX_CHUNK_BYTES` and the decompressor stopped one byte past the declared size, so a
  frame that inflates further than it says is refused without being inflated; all of a
  file's chunks together at most :data:`MAX_INFLATED_BYTES`;
* at most :data:`MAX_FILE_RECORDS` records of a file are parsed (:meth:`Budget.parsed`), which
  also bounds what the counts of its summary and indexes may announce;
* a file holds at most :data:`MAX_FILE_TRIALS` trials, and its ``trial_index`` lists at most
  as many (:mod:`cirl_study.logs.contents` decodes no more).

Past a bound a reader raises :class:`BoundExceeded` (a :class:`ValueError`): the file is
damaged, like one with a failed CRC; one line names it and what was wrong, and, where the
caller salvages, the rest of the run is still read. Each bound is above what the study's own
writer produces for any pipeline the study's limits of one run (``check_resources``) admit
(they refuse a pipeline whose files would hold more than half :data:`MAX_FILE_RECORDS`
messages; the sizes follow from that and from its batch memory budget), so only a file that
was not written by a run is ever refused.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import lz4.frame
import zstandard
from mcap.records import Chunk

from cirl_study.files import read_regular_file

MAX_LOG_FILE_BYTES = 1 << 30
"""Largest log file read (1 GiB): a reader holds the whole file in memory. A file of the
study's holds one batch, a few MB at the paper's size; a file stored without compression (MCAP
allows it) is as large as what it inflates to, so this matches :data:`MAX_INFLATED_BYTES`."""

MAX_CHUNK_BYTES = 64 << 20
"""Most bytes one chunk may inflate to (64 MiB), declared and actual. The writer closes a chunk
once it holds :data:`cirl_study.logs.writer.CHUNK_SIZE` (1 MiB), so a chunk holds at most that
and one more message; the largest message a pipeline admits (a reward map or a record of the
largest grid and horizons the study's ``check_resources`` allows) is a few MiB."""

MAX_INFLATED_BYTES = 1 << 30
"""Most bytes all the chunks of one file may inflate to together (1 GiB): a reader keeps the
messages of a file in memory while it checks them, one file per core. A file of the study's
holds :data:`MAX_FILE_TRIALS` trials of at most :data:`MAX_FILE_RECORDS` messages, which at the
pipeline's limits is a few hundred MB at most; at the paper's size it is about 2 MB."""

MAX_FILE_RECORDS = 1_000_000
"""Most records (messages and every other record, inside chunks or not) parsed of one file, and
the most any count of its summary or indexes may announce. Each record costs a reader about a
microsecond and a hundred bytes beside its data. A file of the study's holds
``MAX_FILE_TRIALS * (T_learn + T_deploy + 5)`` messages (6,000 at the paper's size) and a few
records per chunk; the study's ``check_resources`` refuses a pipeline whose files would come
within half of this bound."""

MAX_FILE_TRIALS = 250
"""Most trials one file may hold: a file holds one batch of a run, and a batch at most this
many trials (the study's ``MAX_BATCH`` is this value). It bounds the records a reader
decodes and checks per file, each of which may make it compute its grid's features."""


class BoundExceeded(ValueError):
    """A log file passes one of the bounds above; the message says which and by how much."""


def read_log(path: Path) -> bytes:
    """The whole content of the log file ``path`` (see the module docstring).

    Raises:
        cirl_study.files.UnreadableFile: ``path`` is not a regular file (the reason says what
            it is), is longer than :data:`MAX_LOG_FILE_BYTES`, or cannot be read.
    """
    return read_regular_file(path, MAX_LOG_FILE_BYTES)


def framed_records(data: bytes) -> int:
    """How many records the complete file ``data`` frames (opcode and length, bodies not
    parsed), to bound what a general MCAP reader then parses of it.

    Raises:
        BoundExceeded: more than :data:`MAX_FILE_RECORDS`.
        ValueError: a record runs past the end of the file.
    """
    position, count, end = 8, 0, len(data) - 8  # the magic bytes at both ends
    while position < end:
        count += 1
        if count > MAX_FILE_RECORDS:
            raise BoundExceeded(f"more than the {MAX_FILE_RECORDS} records a log file may hold")
        (length,) = struct.unpack_from("<Q", data, position + 1)
        position += 9 + length
    if position != end:
        raise ValueError("a record runs past the end of the file")
    return count


@dataclass
class Budget:
    """What reading one file has spent so far: bytes inflated and records parsed."""

    inflated: int = 0
    records: int = 0

    def parsed(self, count: int = 1) -> None:
        """Count ``count`` more records parsed.

        Raises:
            BoundExceeded: the file's records pass :data:`MAX_FILE_RECORDS`.
        """
        self.records += count
        if self.records > MAX_FILE_RECORDS:
            raise BoundExceeded(f"more than the {MAX_FILE_RECORDS} records a log file may hold")

    def inflate(self, chunk: Chunk) -> bytes:
        """A chunk's records, decompressed (zstd, lz4 or none: what MCAP allows) with its
        uncompressed CRC checked (unless it carries none, a 0).

        Nothing is decompressed past the declared size: the decompressor is asked for one
        byte more, and getting it refuses the chunk.

        Raises:
            BoundExceeded: the declared size passes :data:`MAX_CHUNK_BYTES`, or with the chunks
                inflated before it, :data:`MAX_INFLATED_BYTES`.
            ValueError: another compression, a frame that announces or gives another size than
                the chunk, or a CRC mismatch (the decompressors' own errors pass through).
        """
        size = chunk.uncompressed_size
        if size > MAX_CHUNK_BYTES:
            raise BoundExceeded(
                f"announces {size} uncompressed bytes, more than the {MAX_CHUNK_BYTES} a chunk "
                "may hold"
            )
        if self.inflated + size > MAX_INFLATED_BYTES:
            raise BoundExceeded(
                f"inflates the file's chunks past the {MAX_INFLATED_BYTES} bytes a log file may "
                "hold"
            )
        self.inflated += size
        if chunk.compression == "zstd":
            raw = _zstd(chunk.data, size)
        elif chunk.compression == "lz4":
            raw = _lz4(chunk.data, size)
        elif chunk.compression == "":
            raw = chunk.data
        else:
            raise ValueError(f"unsupported chunk compression {chunk.compression!r}")
        if len(raw) > size:
            raise BoundExceeded(f"inflates past the {size} bytes it announces")
        if len(raw) < size:
            raise ValueError(f"inflates to {len(raw)} bytes, it announces {size}")
        if chunk.uncompressed_crc and zlib.crc32(raw) != chunk.uncompressed_crc:
            raise ValueError("chunk CRC mismatch")
        return raw


def _zstd(data: bytes, size: int) -> bytes:
    """The first zstd frame of ``data``, decompressed up to ``size + 1`` bytes."""
    announced = zstandard.frame_content_size(data)  # -1: not recorded in the frame
    if announced not in (-1, size):
        raise ValueError(f"its zstd frame holds {announced} bytes, the chunk announces {size}")
    with zstandard.ZstdDecompressor().stream_reader(data) as stream:
        return stream.read(size + 1)


def _lz4(data: bytes, size: int) -> bytes:
    """The lz4 frame ``data``, decompressed up to ``size + 1`` bytes; a frame that does not
    end there is refused."""
    announced = lz4.frame.get_frame_info(data)["content_size"]  # 0: not recorded
    if announced not in (0, size):
        raise ValueError(f"its lz4 frame holds {announced} bytes, the chunk announces {size}")
    decompressor = lz4.frame.LZ4FrameDecompressor()
    raw = decompressor.decompress(data, max_length=size + 1)
    if len(raw) == size and not decompressor.eof:
        raw += decompressor.decompress(b"", max_length=1)
        if not decompressor.eof and len(raw) == size:
            raise ValueError("its lz4 frame is cut short")
    return raw
