"""One writer per directory: an advisory lock held for as long as a run or a report writes.

The lock is :func:`fcntl.flock` on a lock file: :data:`LOCK_NAME` inside a run directory
(:func:`writer_lock`), a file beside a report directory (whose swap would lose one inside it:
the analysis's replacement of a report). The operating system releases it when its holder
ends, however it ends (``kill -9`` included), so a lock is never left stale; the file itself
stays and only says who held it last. A second writer gets a one-line error naming the
holder's process id, and touches nothing: it neither plays trials nor deletes the holder's
temporary files. Readers take no lock: they see only complete files
(:mod:`cirl_study.logs.writer`) and whole reports; they ask :func:`writer_pid` whether a run
is being written, so as to say so rather than advise resuming it.

A process forked while a lock is held (a pool worker) does not hold it: its copy of the
lock's descriptor is closed as it starts (:func:`os.register_at_fork`), never unlocked, which
would release the holder's lock. A holder's lock thus ends with the holder, even while
workers it forked are still ending.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import stat
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from cirl_study.errors import UserError
from cirl_study.files import open_descriptor

LOCK_NAME = ".cirl-study.lock"
"""Name of the lock file inside a run directory."""

LOCK_ATTEMPTS = 20
"""Tries, 10 ms apart, to take the lock before another writer is said to hold it: a reader
asking :func:`writer_pid` holds the lock's shared side for an instant."""

_HELD: set[int] = set()
"""Descriptors of the locks this process holds."""


def _close_held_in_child() -> None:
    """Close, in a forked child, its copies of the descriptors of the locks its parent holds."""
    for descriptor in _HELD:
        with contextlib.suppress(OSError):
            os.close(descriptor)
    _HELD.clear()


os.register_at_fork(after_in_child=_close_held_in_child)


@contextlib.contextmanager
def writer_lock(run_dir: Path) -> Iterator[None]:
    """Hold the run directory's writer lock for the ``with`` block.

    Raises:
        UserError: as :func:`exclusive_lock`.
    """
    with exclusive_lock(
        run_dir / LOCK_NAME,
        cannot=f"{run_dir}: cannot lock the run directory",
        busy=lambda pid: (
            f"{run_dir}: another cirl-study run (pid {pid}) is writing to it; "
            "wait for it to end, or use another --out directory"
        ),
        kept="no trial was played, and every log file there is kept",
    ):
        yield


@contextlib.contextmanager
def exclusive_lock(
    lock_file: Path, *, cannot: str, busy: Callable[[str], str], kept: str
) -> Iterator[None]:
    """Hold the lock on ``lock_file`` (created if missing) for the ``with`` block, with this
    process's id written in the file.

    Args:
        lock_file: the lock file.
        cannot: the start of the error when the lock cannot be taken or its file written.
        busy: the error when another process holds the lock, of the process id the file
            names (``unknown`` if it names none).
        kept: what is left as it was when the lock cannot be taken, the end of that error
            (nothing the lock guards is touched before it is held).

    Raises:
        UserError: another process holds the lock (after :data:`LOCK_ATTEMPTS` tries); or
            the lock file cannot be opened (a link or anything but a regular file in its place
            is refused: :func:`cirl_study.files.open_descriptor`), locked or written (any OS
            error: a full disk, a quota, a file system without locks), in one line naming
            the file, the OS's reason and ``kept``.
    """
    try:
        descriptor = open_descriptor(lock_file, os.O_RDWR, truncate=False)
    except UserError as error:
        raise UserError(f"{cannot}: {error}; {kept}") from None
    _HELD.add(descriptor)
    try:
        try:
            _take(descriptor, busy)
        except OSError as error:
            reason = error.strerror or str(error)
            raise UserError(f"{cannot}: {lock_file}: {reason}; {kept}") from None
        yield
    finally:
        _HELD.discard(descriptor)
        os.close(descriptor)  # closing releases the lock


def _take(descriptor: int, busy: Callable[[str], str]) -> None:
    """Lock the open lock file ``descriptor`` and write this process's id in it.

    Raises:
        UserError: another process holds the lock (``busy`` of its id).
        OSError: locking or writing the file failed.
    """
    for attempt in range(LOCK_ATTEMPTS):
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
            break
        except BlockingIOError:
            if attempt == LOCK_ATTEMPTS - 1:
                raise UserError(busy(_holder(descriptor))) from None
            time.sleep(0.01)
    os.ftruncate(descriptor, 0)
    os.pwrite(descriptor, f"{os.getpid()}\n".encode(), 0)


def writer_pid(run_dir: Path) -> str | None:
    """The process id of the run writing to ``run_dir`` now (``unknown`` if its lock file does
    not say), or ``None`` when none is.

    For readers, which never write into a run directory: the lock file is neither created nor
    changed, a link or anything but a regular file in its place means no writer, and the
    lock's shared side is held only for the instant of asking (:data:`LOCK_ATTEMPTS`).
    """
    flags = os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC
    try:
        descriptor = os.open(run_dir / LOCK_NAME, flags)
    except OSError:
        return None
    try:
        if not stat.S_ISREG(os.fstat(descriptor).st_mode):
            return None
        try:
            fcntl.flock(descriptor, fcntl.LOCK_SH | fcntl.LOCK_NB)
        except BlockingIOError:
            return _holder(descriptor)
        return None
    finally:
        os.close(descriptor)  # closing releases the shared lock


def _holder(descriptor: int) -> str:
    """The process id the lock file holds, as its holder wrote it; ``unknown`` unless digits."""
    text = os.pread(descriptor, 64, 0).decode(errors="replace").strip()
    return text if text.isdigit() and text.isascii() else "unknown"
