"""The demonstrations a browser experiment collected: stored in the run directory, one file each.

``cirl-study serve`` stores every demonstration a participant submits, before her page is told
it is saved, as a small MCAP file of its own (:func:`store`):
``RUN/collected/<participant>/<condition>.<task>.mcap``, one message on
:data:`COLLECTED_TOPIC` (JSON, its schema generated from :class:`~cirl_study.record.Collected`)
and a ``collection`` metadata record naming the run. The file is written whole to a temporary
name, flushed to disk, then linked to its name (which fails if it exists: two submissions
never overwrite each other) and its directory flushed, so a demonstration acknowledged is one a
power cut or ``kill -9`` keeps, and a file is either whole or absent.

:func:`collected` reads them back, each checked (its CRCs, its one message, its run, its name
against its content), and :func:`collected_text` writes them as a file of demonstrations
(:mod:`cirl_study.study.participants`), which a run of a ``collect = true`` pipeline plays
exactly as it plays a file a lab brings.
"""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path

import msgspec
from mcap.exceptions import McapError
from mcap.reader import make_reader

from cirl_study.errors import UserError
from cirl_study.files import (
    UnreadableFile,
    open_for_writing,
    read_regular_file,
    remove_file,
    sync,
)
from cirl_study.record import Collected

COLLECTED_DIRECTORY = "collected"
"""The run directory's folder of collected demonstrations."""

COLLECTED_TOPIC = "/cirl/collected"
COLLECTED_SCHEMA_NAME = "cirl_study.Collected"
COLLECTION_METADATA_NAME = "collection"
RUN_ID_KEY = "run_id"

MAX_COLLECTED_BYTES = 1 << 20
"""Largest collected file read (a demonstration of 10,000 moves with their times is some
400 kB)."""

MAX_COLLECTED_FILES = 1_000_000
"""Most collected files a run directory is read with."""

_SCHEMA = msgspec.json.encode(msgspec.json.schema(Collected))
_DECODER = msgspec.json.Decoder(Collected)


def collected_path(run_dir: Path, shown: Collected) -> Path:
    """Where ``shown`` is stored: ``collected/<participant>/<condition>.<task>.mcap`` (the
    names' characters are those of :data:`~cirl_study.record.ParticipantId` and of condition
    and task names, none of which holds a ``/`` or starts with ``.``)."""
    recorded = shown.recorded
    name = f"{recorded.condition}.{shown.task}.mcap"
    return run_dir / COLLECTED_DIRECTORY / recorded.participant / name


def _encoded(run_id: str, shown: Collected) -> bytes:
    from mcap.writer import CompressionType, Writer  # only a server writes: readers start light

    stream = io.BytesIO()
    writer = Writer(stream, compression=CompressionType.NONE)
    writer.start(profile="", library="cirl-study")
    schema = writer.register_schema(COLLECTED_SCHEMA_NAME, "jsonschema", _SCHEMA)
    channel = writer.register_channel(COLLECTED_TOPIC, "json", schema)
    seconds = shown.recorded.seconds or (0.0,)
    time = int(round(seconds[-1] * 1e9))
    writer.add_message(channel, time, msgspec.json.encode(shown), time)
    writer.add_metadata(COLLECTION_METADATA_NAME, {RUN_ID_KEY: run_id})
    writer.finish()
    return stream.getvalue()


def _directory(path: Path) -> None:
    """Make the directory ``path`` (and its parents in the run directory), refusing a link."""
    if path.is_symlink():
        raise UserError(f"{path}: is a symbolic link; refusing to write through it")
    path.mkdir(parents=True, exist_ok=True)
    if path.is_symlink() or not path.is_dir():
        raise UserError(f"{path}: is not a directory; refusing to write into it")


def store(run_dir: Path, run_id: str, shown: Collected) -> bool:
    """Store ``shown``, durably, as a collected demonstration of the run ``run_id`` in
    ``run_dir`` (the module docstring). Safe to call from several threads or processes at
    once for different demonstrations; for the same one, exactly one stores it.

    Returns:
        ``True`` if it was stored now, ``False`` if the same demonstration already was (a
        participant's page that resends what was saved).

    Raises:
        UserError: another demonstration of the same participant, condition and task is
            stored; or the directory cannot be written (a link, not a directory, full).
    """
    target = collected_path(run_dir, shown)
    for directory in (run_dir / COLLECTED_DIRECTORY, target.parent):
        _directory(directory)
    data = _encoded(run_id, shown)
    temporary = target.with_name(f".{target.name}.{os.getpid()}.{id(shown):x}.tmp")
    try:
        with open_for_writing(temporary) as stream:
            stream.write(data)
            stream.flush()
            os.fsync(stream.fileno())
        try:
            os.link(temporary, target)
        except FileExistsError:
            if _read(target, run_id) != shown:
                raise UserError(
                    f"{shown.recorded.participant} has already submitted another "
                    f"demonstration of task {shown.task} in condition {shown.recorded.condition}"
                ) from None
            return False
        sync(target.parent)
        return True
    finally:
        remove_file(temporary)


def _read(path: Path, run_id: str) -> Collected:
    """The demonstration stored at ``path``, checked (the module docstring)."""
    try:
        data = read_regular_file(path, MAX_COLLECTED_BYTES)
    except UnreadableFile as error:
        raise UserError(str(error)) from None
    try:
        reader = make_reader(io.BytesIO(data), validate_crcs=True)
        messages = list(reader.iter_messages(topics=[COLLECTED_TOPIC]))
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    except (McapError, ValueError, KeyError, EOFError) as error:
        raise UserError(f"{path}: not a whole collected demonstration ({error})") from None
    if len(messages) != 1:
        raise UserError(f"{path}: holds {len(messages)} demonstrations, not one")
    logged = metadata.get(COLLECTION_METADATA_NAME, {}).get(RUN_ID_KEY)
    if logged != run_id:
        raise UserError(f"{path}: a demonstration of run {logged!r}, not of {run_id}")
    try:
        shown = _DECODER.decode(messages[0][2].data)
    except msgspec.DecodeError as error:
        raise UserError(f"{path}: not a collected demonstration ({error})") from None
    if collected_path(path.parents[2], shown) != path:
        raise UserError(f"{path}: holds the demonstration of another name")
    return shown


def collected(run_dir: Path, run_id: str) -> list[Collected]:
    """Every demonstration collected in ``run_dir`` for the run ``run_id``, each checked, in
    the order of participant, condition and task names; none without a ``collected`` folder.

    Raises:
        UserError: a file is not a whole demonstration of this run, under its own name.
    """
    folder = run_dir / COLLECTED_DIRECTORY
    if not folder.is_dir() or folder.is_symlink():
        return []
    paths = sorted(p for p in folder.glob("*/*.mcap") if not p.name.startswith("."))
    if len(paths) > MAX_COLLECTED_FILES:
        raise UserError(f"{folder}: more than {MAX_COLLECTED_FILES} collected demonstrations")
    return [_read(path, run_id) for path in paths]


def collected_text(demonstrations: list[Collected]) -> str:
    """The demonstrations as a file of demonstrations (:mod:`cirl_study.study.participants`:
    one row per cell, with its seconds and order), in the order given."""
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(["participant", "condition", "task", "step", "x", "y", "seconds", "order"])
    for shown in demonstrations:
        recorded = shown.recorded
        seconds = recorded.seconds or (None,) * len(recorded.path)
        for step, ((x, y), time) in enumerate(zip(recorded.path, seconds, strict=True)):
            writer.writerow([
                recorded.participant, recorded.condition, shown.task, step, x, y,
                "" if time is None else repr(time),
                "" if recorded.order is None else recorded.order,
            ])  # fmt: skip
    return text.getvalue()
