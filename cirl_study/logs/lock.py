"""One writer per run directory: an advisory lock held for as long as a run writes.

The lock is :func:`fcntl.flock` on the file :data:`LOCK_NAME` in the run directory. The
operating system releases it when its holder ends, however it ends (``kill -9`` included),
so a lock is never left stale; the file itself stays and only says who held it last. A second
writer gets a one-line error naming the holder's process id, and touches nothing: it neither
plays trials nor deletes the holder's temporary files. Readers take no lock: they see only
complete files (:mod:`cirl_study.logs.writer`).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
from collections.abc import Iterator
from pathlib import Path

from cirl_study.errors import UserError
from cirl_study.files import open_descriptor

LOCK_NAME = ".cirl-study.lock"
"""Name of the lock file inside a run directory."""


@contextlib.contextmanager
def writer_lock(run_dir: Path) -> Iterator[None]:
    """Hold the run directory's writer lock for the ``with`` block.

    Raises:
        UserError: another process holds it, or the lock file cannot be opened (a link or
            anything but a regular file in its place is refused:
            :func:`cirl_study.files.open_descriptor`).
    """
    try:
        descriptor = open_descriptor(run_dir / LOCK_NAME, os.O_RDWR, truncate=False)
    except UserError as error:
        raise UserError(f"{run_dir}: cannot lock the run directory: {error}") from None
    try:
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(descriptor, 64, 0).decode(errors="replace").strip() or "unknown"
            raise UserError(
                f"{run_dir}: another cirl-study run (pid {holder}) is writing to it; "
                "wait for it to end, or use another --out directory"
            ) from None
        os.ftruncate(descriptor, 0)
        os.pwrite(descriptor, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.close(descriptor)  # closing releases the lock
