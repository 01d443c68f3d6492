"""The participants' sessions, each a small JSON file of the run directory, written durably.

A session is what the experiment knows of a participant beyond her demonstrations (which
:mod:`cirl_study.logs.collection` stores): her id, the hash of her session's token, her
assignment (:mod:`cirl_study.serve.assignment`) and how far she has come through the pages
before the tasks (consent, each condition's instructions, the practice). Which tasks she has
done is read from the collected demonstrations, never from here.

Each session is the file ``RUN/sessions/<participant>.json`` (a participant's id is a file
name: :data:`~cirl_study.record.ParticipantId`), replaced whole on every change: written under
a temporary name, synced, renamed over the old one and the directory synced, so a kill at any
moment leaves the old file or the new one, never a part. Files are opened without following
links (:mod:`cirl_study.files`), and the directory itself must not be a link: nothing is
written outside the run directory. The token itself is never written: only its SHA-256.
"""

from __future__ import annotations

import hashlib
import os
import stat
from pathlib import Path

import msgspec

from cirl_study.errors import UserError
from cirl_study.files import open_descriptor, read_regular_file, remove_file, sync
from cirl_study.record import ParticipantId
from cirl_study.serve.assignment import Assignment

SESSIONS_DIRECTORY = "sessions"
"""The directory of the sessions' files, inside the run directory."""

MAX_SESSION_BYTES = 1 << 16
"""Largest session file read (64 KiB; one holds a few hundred bytes per task)."""

_SUFFIX = ".json"
_TEMPORARY = ".json.tmp"


class Session(msgspec.Struct, frozen=True, kw_only=True):
    """One participant's session.

    ``token_sha256`` is the SHA-256 (hex) of the session's token, which the participant's page
    holds and every request of hers carries; ``platform`` whether her id came from the
    recruitment platform's URL parameter (else it was drawn at random for her);
    ``consented`` whether she agreed to the consent text; ``instructed`` the conditions whose
    instructions she has read; ``practised`` whether she has done the practice task.
    """

    participant: ParticipantId
    token_sha256: str
    platform: bool
    assignment: Assignment
    consented: bool = False
    instructed: tuple[str, ...] = ()
    practised: bool = False


def token_hash(token: str) -> str:
    """The SHA-256 (hex) of a session's ``token``, as :class:`Session` keeps it."""
    return hashlib.sha256(token.encode()).hexdigest()


class SessionFiles:
    """The sessions of the run directory ``run_dir``: :meth:`load` them all, :meth:`save` one."""

    def __init__(self, run_dir: Path) -> None:
        self.directory = run_dir / SESSIONS_DIRECTORY

    def load(self) -> list[Session]:
        """Every session stored, by index; a temporary file left by a killed writer is
        removed (its session is the file it was to replace, or none).

        Raises:
            UserError: the directory is not a directory (a link, say), or a session file is
                not one (unreadable, not a regular file, not a session, or of another name
                than its participant's), in one line naming it.
        """
        self._check_directory()
        if not self.directory.exists():
            return []
        sessions = []
        for path in sorted(self.directory.iterdir()):
            if path.name.endswith(_TEMPORARY):
                remove_file(path)
                continue
            if not path.name.endswith(_SUFFIX):
                raise UserError(f"{path}: is not a session file (RUN/sessions/<participant>.json)")
            try:
                session = msgspec.json.decode(
                    read_regular_file(path, MAX_SESSION_BYTES), type=Session
                )
            except msgspec.DecodeError as error:
                raise UserError(f"{path}: is not a session: {error}") from None
            if path.name != f"{session.participant}{_SUFFIX}":
                raise UserError(f"{path}: holds the session of {session.participant}")
            sessions.append(session)
        indexes = sorted(session.assignment.index for session in sessions)
        if len(set(indexes)) != len(indexes):
            raise UserError(f"{self.directory}: two sessions have the same index")
        return sorted(sessions, key=lambda session: session.assignment.index)

    def save(self, session: Session) -> None:
        """Store ``session`` durably, replacing its earlier state (the module docstring).

        Raises:
            UserError: it cannot be written (a full disk, a link in its place), in one line.
        """
        self._check_directory()
        try:
            self.directory.mkdir(exist_ok=True)
        except OSError as error:
            raise UserError(f"{self.directory}: cannot create: {error.strerror}") from None
        path = self.directory / f"{session.participant}{_SUFFIX}"
        temporary = self.directory / f"{session.participant}{_TEMPORARY}"
        descriptor = open_descriptor(temporary, os.O_WRONLY, truncate=True)
        try:
            data = msgspec.json.encode(session)
            written = 0
            while written < len(data):
                written += os.write(descriptor, data[written:])
            os.fsync(descriptor)
        except OSError as error:
            raise UserError(f"{temporary}: cannot write: {error.strerror}") from None
        finally:
            os.close(descriptor)
        try:
            os.replace(temporary, path)
            sync(self.directory)
        except OSError as error:
            raise UserError(f"{path}: cannot write: {error.strerror}") from None

    def _check_directory(self) -> None:
        """Refuse a sessions directory that is anything but a directory (a link above all)."""
        try:
            mode = os.lstat(self.directory).st_mode
        except FileNotFoundError:
            return
        except OSError as error:
            raise UserError(f"{self.directory}: cannot read: {error.strerror}") from None
        if not stat.S_ISDIR(mode):
            raise UserError(f"{self.directory}: is not a directory; refusing to use it")
