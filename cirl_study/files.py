"""Every file the project writes is opened here, never through a link.

A run or report directory may come from someone else: a symbolic link in it (``report.md ->
../victim``) must not make a writer write outside it, and a FIFO or a device in a file's
place must not make it hang or write there. :func:`open_for_writing` opens the file itself
(``O_NOFOLLOW``: a link in its place is refused, not followed), without blocking
(``O_NONBLOCK``: a FIFO without a reader fails at once), checks on the open descriptor that
it is a regular file, and only then truncates it, so nothing but a regular file is ever
changed. :func:`read_file` reads a file the same way: never through a link, never a FIFO.
Every refusal is one line naming the file (:class:`cirl_study.errors.UserError`).
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path
from typing import BinaryIO

from cirl_study.errors import UserError

_FLAGS = os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC


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


def read_file(path: Path) -> bytes:
    """The whole content of the regular file ``path``, opened as :func:`open_descriptor`
    opens one (a link in its place is refused, not followed; a FIFO does not block).

    Raises:
        FileNotFoundError: there is no ``path``.
        UserError: ``path`` is a symbolic link or not a regular file, or cannot be read.
    """
    try:
        descriptor = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except FileNotFoundError:
        raise
    except OSError as error:
        if error.errno == errno.ELOOP:
            raise UserError(f"{path}: is a symbolic link; refusing to read through it") from None
        raise UserError(f"{path}: cannot read: {error.strerror}") from None
    with os.fdopen(descriptor, "rb") as stream:
        if not stat.S_ISREG(os.fstat(descriptor).st_mode):
            raise UserError(f"{path}: is not a regular file; refusing to read it")
        try:
            return stream.read()
        except OSError as error:
            raise UserError(f"{path}: cannot read: {error.strerror}") from None


def remove_file(path: Path) -> None:
    """Remove ``path`` if it is there; a link is removed itself, never what it points to."""
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass
    except OSError as error:
        raise UserError(f"{path}: cannot remove: {error.strerror}") from None
