"""A report directory is replaced atomically and by one writer at a time.

:func:`replacing_report` holds the report's writer lock, checks that the report there may be
replaced (:func:`refuse_another_runs_report`), and gives a fresh directory to write the new
report into. When the block ends, that directory becomes the report in one step; when it
raises (a full disk, a bug, Ctrl-C), it is removed and the previous report stays whole, byte
for byte.

* **Where.** The new report is written into ``.<name>.tmp-<random>`` beside the target
  ``<name>`` (the same parent, so that a rename moves it without copying), created as
  :func:`tempfile.mkdtemp` creates one (a fresh name, mode 0700: nobody reads a half-written
  report); before the swap it takes the old report's mode (a new one: the umask's). Each
  file, then the directory, is synced to disk, so that after the swap a power cut leaves
  the old report or the new one, not a new name over files still in the page cache.
* **The swap** is ``renameat2(RENAME_EXCHANGE)`` (Linux): one system call exchanges the two
  directories, so the target holds a whole report at every instant, and a reader (or a
  ``kill -9``) sees the old one or the new one. Where the C library, the kernel or the file
  system lacks it, the old report is renamed aside and the new one renamed in: the target
  is missing between the two renames. The old report, now under the temporary name, is
  then removed. A ``kill -9`` may leave a temporary directory, which the next writer of the
  report removes: holding the lock, it knows that no one else is writing it.
* **The lock** is the file ``.<name>.lock`` beside the report
  (:func:`cirl_study.logs.lock.exclusive_lock`), not in it: a lock file inside would leave
  with the old directory at the swap, and a second writer would lock the new one's. It is
  held from before the check of the report there to after the swap, so two writers of one
  report cannot both pass the check: the second gets one line naming the first's pid.
* **What a report is.** ``report.md``, ``results.json``, ``provenance.json`` and every
  ``*.csv``, ``*.png`` and ``*.svg`` are the report's (:func:`is_report_file`): the new
  report replaces them all, so a figure the new report does not draw is gone with the old
  one. Anything else there (a ``README.md``, notes, a subdirectory) is the user's and is kept,
  unchanged, whatever happens: a file (or a link) is hard-linked into the new directory before
  the swap, so it is there at every instant; a subdirectory is moved into the new directory
  right after the swap, whole (its owner, mode and inode stay; a copy would be the writer's).
* **Never over a run.** A run directory (one holding log files, temporary log files or a
  run's lock: :func:`run_directory_under`) is never a report directory, nor inside the
  target: a run writes its logs while a report may be written, and the swap would take the
  files it makes after the user's files were linked. A report inside a run directory
  (``RUN/report``, the default) is fine: a run writes only its own top level.
* **Late files.** An entry of the user's that appears in the old report between the linking
  and the swap is moved into the new one with the subdirectories, so nothing the user (or
  another process) made there is removed with the old report.
* **Links.** A symbolic link as the target is refused, and so is one as the lock file; a
  link inside the old report is never followed: it leaves with the old report, or, if it
  is the user's, is kept as a link.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import functools
import glob
import json
import os
import shutil
import stat
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from cirl_study.errors import UserError
from cirl_study.escape import terminal
from cirl_study.files import read_regular_file, remove_file, sync
from cirl_study.logs.format import LOG_SUFFIX, TEMP_SUFFIX
from cirl_study.logs.lock import LOCK_NAME, exclusive_lock

REPORT_FILE_NAMES = frozenset({"report.md", "results.json", "provenance.json"})
"""Files of a report by name; with :data:`REPORT_FILE_SUFFIXES`, what :func:`is_report_file`
accepts."""

REPORT_FILE_SUFFIXES = (".csv", ".png", ".svg")
"""Files of a report by kind: its tables and figures."""

_RENAME_EXCHANGE = 2
"""``renameat2``'s flag: exchange the two paths (``linux/fs.h``)."""

_AT_FDCWD = -100
"""``renameat2``'s directory descriptor for paths relative to the working directory."""


def is_report_file(name: str) -> bool:
    """Whether ``name`` in a report directory is the report's (see the module docstring)."""
    return name in REPORT_FILE_NAMES or name.endswith(REPORT_FILE_SUFFIXES)


@dataclass
class Replacement:
    """A report being replaced: :attr:`stage` is where to write it."""

    stage: Path
    """The fresh directory to write the new report into."""
    differences: list[str] | None = None
    """With ``keep_if_equal``, after the block: every difference from the report that was
    there (:func:`cirl_study.analysis.report.compare.compare_reports`); ``None`` if there was none
    to compare with."""

    @property
    def kept(self) -> bool:
        """Whether the report there equalled the new one by value, and was kept untouched."""
        return self.differences == []


@contextlib.contextmanager
def replacing_report(
    target: Path, *, run_id: str, force: bool = False, keep_if_equal: bool = False
) -> Iterator[Replacement]:
    """Replace the report directory ``target`` with what the block writes into the
    :attr:`Replacement.stage` it is given (see the module docstring).

    Args:
        target: the report directory; its parent is created if missing.
        run_id: the run the new report is of.
        force: replace a report of another run too (else refused:
            :func:`refuse_another_runs_report`).
        keep_if_equal: compare the new report with the one there, and keep the one there,
            byte for byte, if they are equal by value.

    Raises:
        UserError: another process is writing the report; the target or its lock file is a
            symbolic link, or the target is not a directory; it holds another run's report
            (without ``force``); or a directory cannot be written (one line, the OS's
            reason). The report there is then unchanged, and no temporary directory is left.
    """
    absolute = Path(os.path.abspath(target))
    if not absolute.name:
        raise UserError(f"{target}: is not a directory a report can be written to")
    parent, name = Path(os.path.realpath(absolute.parent)), absolute.name
    absolute = parent / name
    _refuse_a_run(target, absolute)
    with _os_errors(target):
        parent.mkdir(parents=True, exist_ok=True)
    with exclusive_lock(
        parent / f".{name}.lock",
        cannot=f"{target}: cannot lock the report directory",
        busy=lambda pid: (
            f"{target}: another cirl-study process (pid {pid}) is writing this "
            "report; wait for it to end, or choose another report directory"
        ),
        kept="the report there is unchanged",
    ):
        mode = _existing_mode(target, absolute)
        if not force:
            refuse_another_runs_report(target, run_id)
        with _os_errors(target):
            for stale in parent.glob(f".{glob.escape(name)}.tmp-*"):
                _remove(stale)
            stage = Path(tempfile.mkdtemp(prefix=f".{name}.tmp-", dir=parent))
        replacement = Replacement(stage)
        try:
            try:
                yield replacement
            except UserError as error:  # about the temporary directory: about the report
                raise UserError(str(error).replace(str(stage), str(target))) from None
            if keep_if_equal:
                replacement.differences = _differences(absolute, stage)
                if replacement.kept:
                    return
            with _os_errors(target):
                _sync_files(stage)
                if mode is not None:
                    _link_the_users_files(absolute, stage)
                os.chmod(stage, mode if mode is not None else _default_mode())
                sync(stage)
                _swap(stage, absolute, present=mode is not None)
                if mode is not None:
                    _move_late_entries(stage, absolute)
                sync(parent)
        finally:
            with _os_errors(target):
                _remove(stage)


RESULTS_BYTES = 1 << 30
"""Longest ``results.json`` read to learn whose report a directory holds (the multiverse's
53 universes write about 8 MB); a longer one is taken as no report of a run."""


def refuse_another_runs_report(target: Path, run_id: str) -> None:
    """Refuse to replace report files in ``target`` that are not a report of ``run_id``
    (by its ``results.json``'s ``run_id``): those of another run, or files of a report
    (:func:`is_report_file`) without a ``results.json`` saying whose they are.

    Raises:
        UserError: ``target`` holds such files (one line; ``--force`` replaces them).
    """
    try:
        names = [entry.name for entry in os.scandir(target) if is_report_file(entry.name)]
    except (FileNotFoundError, NotADirectoryError):
        return
    except OSError as error:
        raise UserError(f"{target}: cannot read: {error.strerror}") from None
    if not names:
        return
    theirs = _run_id_of(target / "results.json")
    if theirs == run_id:
        return
    held = (
        f"the report of {terminal(theirs)}"
        if theirs is not None
        else f"{len(names)} report file(s) but no report of a run"
    )
    raise UserError(
        f"{target}: holds {held}, not of {run_id}; choose another report directory, "
        "or --force to replace it"
    )


def _run_id_of(results: Path) -> str | None:
    """The ``run_id`` a ``results.json`` states, ``None`` if it cannot be read or states none."""
    try:
        run_id = json.loads(read_regular_file(results, RESULTS_BYTES)).get("run_id")
    except (OSError, UserError, ValueError, AttributeError):
        return None
    return run_id if isinstance(run_id, str) else None


def _existing_mode(target: Path, absolute: Path) -> int | None:
    """The mode of the directory ``absolute`` (``None`` if there is none), refusing a link or
    anything but a directory there."""
    try:
        status = os.lstat(absolute)
    except FileNotFoundError:
        return None
    except OSError as error:
        raise UserError(f"{target}: cannot write the report: {error.strerror}") from None
    if stat.S_ISLNK(status.st_mode):
        raise UserError(f"{target}: is a symbolic link; refusing to replace the report through it")
    if not stat.S_ISDIR(status.st_mode):
        raise UserError(f"{target}: exists and is not a directory")
    return stat.S_IMODE(status.st_mode)


def _differences(existing: Path, new: Path) -> list[str] | None:
    """Every difference between the report ``existing`` (``None`` if it has no results and
    table to compare) and ``new``; a report there that cannot be read differs."""
    from cirl_study.analysis.report.compare import compare_reports

    if not (existing / "results.json").is_file() or not any(existing.glob("*.csv")):
        return None
    ours = {path.name for path in new.iterdir()}
    theirs = {path.name for path in existing.iterdir() if is_report_file(path.name)}
    differences = [f"{name}: only in the new report" for name in sorted(ours - theirs)]
    differences += [f"{name}: not in the new report" for name in sorted(theirs - ours)]
    try:
        return differences + compare_reports(existing, new)
    except UserError as error:
        return [*differences, str(error)]


def _refuse_a_run(target: Path, absolute: Path) -> None:
    """Refuse a report directory that is a run directory or holds one
    (:func:`run_directory_under`), before anything is written."""
    if not absolute.is_dir() or absolute.is_symlink():
        return
    with _os_errors(target):
        run = run_directory_under(absolute)
    if run is not None:
        where = "is" if run == absolute else f"holds {terminal(run)}, which is"
        raise UserError(
            f"{target}: {where} a run directory (its log files); a report is never written "
            "over a run: choose another report directory"
        )


def run_directory_under(directory: Path) -> Path | None:
    """The first run directory at or under ``directory`` (not through a link): one holding a
    log file (``*.mcap``), a temporary one or a run's lock file; ``None`` if there is none."""
    pending = [directory]
    while pending:
        current = pending.pop()
        with os.scandir(current) as entries:
            for entry in entries:
                if _is_run_file(entry.name):
                    return current
                if entry.is_dir(follow_symlinks=False):
                    pending.append(Path(entry.path))
    return None


def _is_run_file(name: str) -> bool:
    return name == LOCK_NAME or name.endswith((LOG_SUFFIX, LOG_SUFFIX + TEMP_SUFFIX))


def _move_late_entries(old: Path, new: Path) -> None:
    """Move into ``new`` every entry of the user's in ``old`` that ``new`` lacks: its
    subdirectories, and any entry made after :func:`_link_the_users_files` linked its files."""
    for entry in os.scandir(old):
        if not is_report_file(entry.name) and not os.path.lexists(new / entry.name):
            os.rename(entry.path, new / entry.name)


def _link_the_users_files(old: Path, stage: Path) -> None:
    """Hard-link every file of ``old`` that is not the report's into ``stage``, links as
    links (its subdirectories are moved after the swap: :func:`_move_late_entries`)."""
    for entry in os.scandir(old):
        if not is_report_file(entry.name) and not entry.is_dir(follow_symlinks=False):
            os.link(entry.path, stage / entry.name, follow_symlinks=False)


def _sync_files(directory: Path) -> None:
    """Sync every regular file directly in ``directory`` to disk (the report's files)."""
    for entry in os.scandir(directory):
        if entry.is_file(follow_symlinks=False):
            sync(Path(entry.path))


def _swap(stage: Path, target: Path, *, present: bool) -> None:
    """Make ``stage`` the directory ``target``; what ``target`` was (if ``present``) is left
    at ``stage``."""
    if not present:
        os.rename(stage, target)  # fails if another process made target meanwhile
        return
    if _exchange(stage, target):
        return
    aside = stage.with_name(f"{stage.name}-old")
    os.rename(target, aside)
    try:
        os.rename(stage, target)
    except BaseException:
        os.rename(aside, target)
        raise
    os.rename(aside, stage)


def _exchange(first: Path, second: Path) -> bool:
    """Exchange the paths ``first`` and ``second`` atomically; ``False`` (and nothing done)
    where the system cannot."""
    renameat2 = _renameat2()
    if renameat2 is None:
        return False
    if renameat2(_AT_FDCWD, os.fsencode(first), _AT_FDCWD, os.fsencode(second), _RENAME_EXCHANGE):
        code = ctypes.get_errno()
        if code in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
            return False
        raise OSError(code, os.strerror(code), str(second))
    return True


@functools.cache
def _renameat2() -> Callable[..., int] | None:
    """The C library's ``renameat2``, ``None`` where it has none (before glibc 2.28, macOS)."""
    function = getattr(ctypes.CDLL(None, use_errno=True), "renameat2", None)
    if function is not None:
        function.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p]
        function.argtypes += [ctypes.c_uint]
        function.restype = ctypes.c_int
    return function


def _default_mode() -> int:
    """The mode ``mkdir`` gives a new directory: 0777 less the umask."""
    umask = os.umask(0o022)
    os.umask(umask)
    return 0o777 & ~umask


def _remove(path: Path) -> None:
    """Remove the directory tree ``path`` if there (a link or a file: itself only)."""
    try:
        status = os.lstat(path)
    except FileNotFoundError:
        return
    if stat.S_ISDIR(status.st_mode):
        shutil.rmtree(path)
    else:
        remove_file(path)


@contextlib.contextmanager
def _os_errors(target: Path) -> Iterator[None]:
    """Turn an operating-system error into one line about writing the report ``target``."""
    try:
        yield
    except OSError as error:
        reason = error.strerror or str(error)
        raise UserError(f"{target}: cannot write the report: {reason}") from None
