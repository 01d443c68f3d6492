"""Every file the project writes, and every log file it reads, is opened here, never through
a link.

A run or report directory may come from someone else: a symbolic link in it (``report.md ->
../victim``) must not make a writer write outside it, and a FIFO or a device in a file's
place must not make it hang or write there. :func:`open_for_writing` opens the file itself
(``O_NOFOLLOW``: a link in its place is refused, not followed), without blocking
(``O_NONBLOCK``: a FIFO without a reader fails at once), checks on the open descriptor that
it is a regular file, and only then truncates it, so nothing but a regular file is ever
changed. :func:`read_regular_file` reads the same way: a link, a FIFO, a device or a
directory in a file's place is refused before it is opened (:func:`non_regular`), and again on
the open descriptor, so a reader never follows a link out, never blocks on a FIFO, and never
opens a device (opening one can act on it); a file longer than the reader's bound is refused
before it is read. Every refusal is one line naming the file
(:class:`cirl_study.errors.UserError`).
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path
from typing import BinaryIO

from cirl_study.errors import UserError

RUNS_DIRECTORY = Path("data") / "runs"
"""Where ``cirl-study run NAME`` puts a pipeline's run unless ``--out``: ``data/runs/NAME``
below the current directory."""

_FLAGS = os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC
_READ_FLAGS = os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC

_KINDS = (
    (stat.S_ISLNK, "a symbolic link"),
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a FIFO"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


class UnreadableFile(UserError):
    """A file :func:`read_regular_file` refuses; ``reason`` says why without naming it (the
    message is ``path: reason``), for a reader that reports it beside the file's name."""

    def __init__(self, path: Path, reason: str) -> None:
        super().__init__(f"{path}: {reason}")
        self.path = path
        self.reason = reason

    def __reduce__(self) -> tuple[type[UnreadableFile], tuple[Path, str]]:
        return (UnreadableFile, (self.path, self.reason))  # raised in worker processes too


def _kind(mode: int) -> str:
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def non_regular(path: Path) -> str | None:
    """Why the entry ``path`` is no regular file (``"is a FIFO, not a regular file"``), or
    ``None`` for a regular file or for none at all; the entry itself is looked at, never what
    a link names.

    Raises:
        UnreadableFile: ``path`` cannot be looked at (e.g. its directory is not searchable).
    """
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return None
    except OSError as error:
        raise UnreadableFile(path, f"cannot read: {error.strerror}") from None
    return None if stat.S_ISREG(mode) else f"is {_kind(mode)}, not a regular file"


def read_regular_file(path: Path, max_bytes: int) -> bytes:
    """The whole content of the regular file ``path``, at most ``max_bytes`` long (see the
    module docstring).

    Raises:
        UnreadableFile: ``path`` is not a regular file (the reason says what it is), is
            longer than ``max_bytes``, or cannot be read.
    """
    reason = non_regular(path)
    if reason is not None:
        raise UnreadableFile(path, reason)
    try:
        descriptor = os.open(path, _READ_FLAGS)
    except OSError as error:
        if error.errno == errno.ELOOP:  # replaced by a link since it was looked at
            raise UnreadableFile(path, "is a symbolic link, not a regular file") from None
        raise UnreadableFile(path, f"cannot read: {error.strerror}") from None
    try:
        status = os.fstat(descriptor)
        if not stat.S_ISREG(status.st_mode):
            raise UnreadableFile(path, f"is {_kind(status.st_mode)}, not a regular file")
        too_long = f"longer than the {max_bytes} bytes a reader takes"
        if status.st_size > max_bytes:
            raise UnreadableFile(path, f"is {status.st_size} bytes, {too_long}")
        with open(descriptor, "rb", closefd=False) as stream:
            data = stream.read(status.st_size + 1)
        if len(data) > status.st_size:  # it grew since it was measured
            raise UnreadableFile(path, f"grew while it was read; {too_long}")
    except OSError as error:
        raise UnreadableFile(path, f"cannot read: {error.strerror}") from None
    finally:
        os.close(descriptor)
    return data


def open_descriptor(path: Path, flags: int, *, truncate: bool) -> int:
    """A descriptor of the regular file ``path``, created if missing (mode 0644), opened with
    ``flags`` (``os.O_WRONLY`` or ``os.O_RDWR``) and truncated when ``truncate``.

    Raises:
        UserError: ``path`` is a symbolic link, not a regular file (a directory, a FIFO, a
            device), or cannot be opened.
    """
    try:
        descriptor = os.open(path, flags | _FLAGS, 0o644)
    except OSError as error:
        if error.errno == errno.ELOOP:
            raise UserError(f"{path}: is a symbolic link; refusing to write through it") from None
        if error.errno in (errno.EISDIR, errno.ENXIO):
            raise UserError(f"{path}: is not a regular file; refusing to write to it") from None
        raise UserError(f"{path}: cannot write: {error.strerror}") from None
    try:
        if not stat.S_ISREG(os.fstat(descriptor).st_mode):
            raise UserError(f"{path}: is not a regular file; refusing to write to it")
        os.set_blocking(descriptor, True)
        if truncate:
            os.ftruncate(descriptor, 0)
    except BaseException:
        os.close(descriptor)
        raise
    return descriptor


def open_for_writing(path: Path) -> BinaryIO:
    """``path`` opened for writing from empty, as a binary stream (see the module docstring).

    Raises:
        UserError: as :func:`open_descriptor`.
    """
    return os.fdopen(open_descriptor(path, os.O_WRONLY, truncate=True), "wb")


def write_file(path: Path, data: bytes) -> None:
    """Write ``data`` as the whole content of ``path`` (see :func:`open_for_writing`)."""
    with open_for_writing(path) as stream:
        stream.write(data)


def sync(path: Path) -> None:
    """``fsync`` the file or directory ``path`` (not through a link): after a rename or link
    inside a directory, syncing the directory makes the new name durable.

    Raises:
        OSError: ``path`` cannot be opened (a link among them) or synced.
    """
    descriptor = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


def remove_file(path: Path) -> None:
    """Remove ``path`` if it is there; a link is removed itself, never what it points to."""
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass
    except OSError as error:
        raise UserError(f"{path}: cannot remove: {error.strerror}") from None
