"""The experiment's logic, apart from HTTP: sessions, assignment, stages and the store.

:class:`Experiment` holds a run directory's sessions (:mod:`cirl_study.serve.sessions`) and
its collected demonstrations (:mod:`cirl_study.logs.collection`), and answers each request of
a participant's page with her :class:`~cirl_study.serve.messages.State`. Every change is
durable before it is answered: a session's file is written, a demonstration stored
(:func:`~cirl_study.logs.collection.store`), and only then is the page told. A refused request
raises :class:`Refused`, one line and an HTTP status.

A participant goes through her stages in order (:func:`stage`): the consent; before the first
task of each of her conditions, its instructions; once, before her first task, the practice;
her tasks (:mod:`cirl_study.serve.assignment`); the end. Which tasks she has done is read from
the store, so a participant resumes where she was after a reload, another browser (by her
platform id), or a restart of the server after a kill.

Requests of one participant are handled one at a time (a lock per participant); those of
different participants at once. The methods are blocking (files are written and synced): the
HTTP layer runs them in worker threads.
"""

from __future__ import annotations

import secrets
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from msgspec.structs import replace as _replace

from cirl_study.errors import UserError
from cirl_study.logs.collection import collected, store
from cirl_study.record import Collected, Recorded
from cirl_study.serve.assignment import assign
from cirl_study.serve.board import board, legend
from cirl_study.serve.messages import (
    ConditionStatus,
    Setup,
    Stage,
    State,
    Status,
    Submission,
    TaskView,
)
from cirl_study.serve.sessions import Session, SessionFiles, token_hash
from cirl_study.study.participants import PARTICIPANT, check_demonstration
from cirl_study.study.spec import ExperimentSpec, ParticipantsSpec, Pipeline, Task

RANDOM_ID_PREFIX = "R-"
"""The start of a participant id drawn at random (one without a platform id)."""


class Refused(Exception):
    """A request refused: ``status`` its HTTP status (400 bad input, 401 no such session,
    409 not now, 413 too large), ``message`` one line saying why."""

    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status = status
        self.message = message


@dataclass(frozen=True)
class Collecting:
    """What of a pipeline the experiment needs, checked: its ``[participants]`` with
    ``collect = true`` and its ``[experiment]``."""

    pipeline: Pipeline
    participants: ParticipantsSpec
    experiment: ExperimentSpec
    tasks: tuple[Task, ...]

    @classmethod
    def of(cls, pipeline: Pipeline) -> Collecting:
        """The experiment of ``pipeline``.

        Raises:
            UserError: the pipeline collects no demonstrations, or has no ``[experiment]``.
        """
        label = pipeline.path
        participants = pipeline.participants
        if participants is None or not participants.collect:
            raise UserError(
                f"{label}: serves an experiment only with [participants] collect = true "
                "(docs/participants.md)"
            )
        if pipeline.experiment is None or pipeline.tasks is None:
            raise UserError(
                f"{label}: has no [experiment] table (consent, instructions, practice and "
                "completion: docs/participants.md)"
            )
        return cls(pipeline, participants, pipeline.experiment, pipeline.tasks)


def stage(session: Session, done: set[tuple[str, str]]) -> tuple[Stage, int]:
    """Where ``session`` is, and the position in her steps of her next task (the number of
    steps at the end), given the steps ``done`` (condition, task) stored."""
    if not session.consented:
        return "consent", 0
    for position, step in enumerate(session.assignment.steps):
        if step in done:
            continue
        if step[0] not in session.instructed:
            return "instructions", position
        if not session.practised:
            return "practice", position
        return "task", position
    return "done", len(session.assignment.steps)


class Experiment:
    """The experiment of ``pipeline`` (:class:`Collecting`) on the run directory ``run_dir``,
    whose writer lock the caller holds: its sessions and its store, loaded whole."""

    def __init__(self, pipeline: Pipeline, run_dir: Path) -> None:
        self.spec = Collecting.of(pipeline)
        self.pipeline = pipeline
        self.run_dir = run_dir
        self.run_id = pipeline.run_id
        self.files = SessionFiles(run_dir)
        self.board = board(pipeline.game)
        self._tasks = {task.name: task for task in self.spec.tasks}
        self._lock = threading.Lock()
        self._locks: dict[str, threading.Lock] = {}
        self._sessions: dict[str, Session] = {}
        self._by_token: dict[str, str] = {}
        self._done: dict[str, set[tuple[str, str]]] = {}
        for session in self.files.load():
            self._remember(session)
        for shown in collected(run_dir, self.run_id):
            recorded = shown.recorded
            self._done.setdefault(recorded.participant, set()).add((recorded.condition, shown.task))
        self._next_index = 1 + max(
            (s.assignment.index for s in self._sessions.values()), default=-1
        )

    def setup(self) -> Setup:
        """What every page needs first (:class:`~cirl_study.serve.messages.Setup`)."""
        return Setup(
            title=self.pipeline.description,
            participant_parameter=self.spec.experiment.participant_parameter,
            board=self.board,
        )

    def start(self, participant: str | None, token: str | None) -> State:
        """Start or resume a session: the one of ``token`` (the page's, from an earlier start)
        unless the page's address names another ``participant``; else the session of the
        platform's id ``participant``, under a new token (a page that held the old one must
        start again); else a new session, of ``participant`` or of a random id.

        Raises:
            Refused: ``participant`` is not an id (400).
        """
        if participant is not None and not PARTICIPANT.fullmatch(participant):
            raise Refused(
                400,
                "the participant id is not an id (a letter or digit, then letters, digits, "
                "_ . or -; at most 64)",
            )
        if self.spec.experiment.participant_parameter is None:
            participant = None
        if token is not None:
            known = self._by_token.get(token_hash(token))
            if known is not None and participant in (None, known):
                return self._state(self._sessions[known])
        fresh = secrets.token_urlsafe(32)
        with self._lock:
            if participant is not None and participant in self._sessions:
                with self._participant_lock(participant):
                    old = self._sessions[participant]
                    session = _replace(old, token_sha256=token_hash(fresh))
                    self.files.save(session)
                    del self._by_token[old.token_sha256]
                    self._remember(session)
                return self._state(session, fresh)
            platform = participant is not None
            while participant is None or participant in self._sessions:
                participant = RANDOM_ID_PREFIX + secrets.token_hex(8)
            assignment = assign(
                self.pipeline.seed,
                self._next_index,
                self.spec.participants.conditions,
                [task.name for task in self.spec.tasks],
                self.spec.participants.within,
            )
            session = Session(
                participant=participant,
                token_sha256=token_hash(fresh),
                platform=platform,
                assignment=assignment,
            )
            self.files.save(session)
            self._next_index += 1
            self._remember(session)
        return self._state(session, fresh)

    def state(self, token: str) -> State:
        """The state of the session of ``token``.

        Raises:
            Refused: no session has ``token`` (401).
        """
        return self._state(self._session(token))

    def consent(self, token: str) -> State:
        """The participant of ``token`` agrees to the consent text."""
        return self._advance(token, "consent", lambda s, _: _replace(s, consented=True))

    def instructed(self, token: str) -> State:
        """The participant of ``token`` has read the instructions of her next condition."""

        def read(session: Session, position: int) -> Session:
            condition = session.assignment.steps[position][0]
            return _replace(session, instructed=(*session.instructed, condition))

        return self._advance(token, "instructions", read)

    def practise(self, token: str, shown: Submission) -> State:
        """The participant of ``token`` submits the practice task ``shown``, checked as a
        demonstration is and never stored.

        Raises:
            Refused: she is not at the practice (409), or ``shown`` is not a legal
                demonstration of the practice task (400).
        """
        practice = self.spec.experiment.practice

        def practised(session: Session, position: int) -> Session:
            condition = session.assignment.steps[position][0]
            if shown.task != practice.name:
                raise Refused(409, f"the practice is task {practice.name}, not {shown.task}")
            attempt = _collected(session.participant, condition, shown, None)
            self._check(attempt, (practice,))
            return _replace(session, practised=True)

        return self._advance(token, "practice", practised)

    def submit(self, token: str, shown: Submission) -> State:
        """Store the demonstration ``shown`` of the participant of ``token``'s current task,
        durably, before answering. Submitting a stored demonstration again is answered as
        its first submission was (a page that lost the answer retries), and changes
        nothing.

        Raises:
            Refused: she is not at a task or ``shown`` is not her current task (409), it is
                not a legal demonstration of it (400), or another demonstration of it is
                stored already (409).
        """
        session = self._session(token)
        with self._participant_lock(session.participant):
            session = self._session(token)
            done = self._done.setdefault(session.participant, set())
            steps = session.assignment.steps
            now, position = stage(session, done)
            if now == "task" and steps[position][1] == shown.task:
                condition, task = steps[position]
                demonstration = _collected(session.participant, condition, shown, position + 1)
                self._check(demonstration, self.spec.tasks)
                self._store(demonstration)
                done.add((condition, task))
                return self._state(session)
            stored = [p for p, step in enumerate(steps) if step in done and step[1] == shown.task]
            if not stored:
                if now != "task":
                    raise Refused(409, f"the session is at the {now}, not at a task")
                raise Refused(409, f"the current task is {steps[position][1]}, not {shown.task}")
            for place in stored:
                again = _collected(session.participant, steps[place][0], shown, place + 1)
                try:
                    if not store(self.run_dir, self.run_id, again):
                        return self._state(session)
                except UserError:
                    continue
            raise Refused(409, f"task {shown.task} is done; its demonstration is stored already")

    def status(self) -> Status:
        """Participants started and finished, and demonstrations stored, per condition."""
        with self._lock:
            sessions = list(self._sessions.values())
        rows = []
        for condition in self.spec.participants.conditions:
            started = finished = stored = 0
            for session in sessions:
                steps = [s for s in session.assignment.steps if s[0] == condition]
                if not steps:
                    continue
                done = self._done.get(session.participant, set())
                count = sum(step in done for step in steps)
                started += 1
                finished += count == len(steps)
                stored += count
            rows.append(
                ConditionStatus(
                    condition=condition, started=started, finished=finished, demonstrations=stored
                )
            )
        return Status(run_id=self.run_id, participants=len(sessions), conditions=tuple(rows))

    def _store(self, demonstration: Collected) -> None:
        """Store ``demonstration`` (new, or the same as the one stored)."""
        try:
            store(self.run_dir, self.run_id, demonstration)
        except UserError as error:
            raise Refused(409, str(error)) from None

    def _check(self, demonstration: Collected, tasks: tuple[Task, ...]) -> None:
        """Refuse ``demonstration`` unless it is legal in the game (400)."""
        conditions = self.spec.participants.conditions
        try:
            check_demonstration(self.pipeline.game, tasks, conditions, demonstration)
        except UserError as error:
            raise Refused(400, str(error)) from None

    def _advance(self, token: str, at: Stage, change: Callable[[Session, int], Session]) -> State:
        """The session of ``token``, at the stage ``at``, changed by ``change`` (of the
        session and its next step's position) and saved; at a later stage, unchanged (a
        page that lost the answer retries)."""
        session = self._session(token)
        with self._participant_lock(session.participant):
            session = self._session(token)
            done = self._done.get(session.participant, set())
            now, position = stage(session, done)
            order: tuple[Stage, ...] = ("consent", "instructions", "practice", "task", "done")
            if now != at:
                if order.index(now) > order.index(at):
                    return self._state(session)
                raise Refused(409, f"the session is at the {now}, not at the {at}")
            changed = change(session, position)
            self.files.save(changed)
            self._remember(changed)
            return self._state(changed)

    def _state(self, session: Session, token: str | None = None) -> State:
        """What the page of ``session`` shows now (``token``: a new session's, to hand over)."""
        done = self._done.get(session.participant, set())
        now, position = stage(session, done)
        experiment = self.spec.experiment
        steps = session.assignment.steps
        condition = steps[min(position, len(steps) - 1)][0]
        state = State(
            participant=session.participant,
            stage=now,
            done=sum(step in done for step in steps),
            count=len(steps),
            token=token,
            condition=condition if now in ("instructions", "practice", "task") else None,
        )
        if now == "consent":
            return _replace(state, text=experiment.consent)
        if now == "instructions":
            return _replace(state, text=experiment.instructions_for(condition))
        if now == "practice":
            return _replace(state, task=self._view(experiment.practice, 0, len(steps)))
        if now == "task":
            task = self._tasks[steps[position][1]]
            return _replace(state, task=self._view(task, position + 1, len(steps)))
        return _replace(
            state,
            completion_code=experiment.completion_code,
            completion_url=experiment.completion_url,
        )

    def _view(self, task: Task, number: int, count: int) -> TaskView:
        meanings, move = legend(self.pipeline.game, task)
        return TaskView(
            name=task.name,
            number=number,
            count=count,
            practice=number == 0,
            legend=meanings,
            move_weight=move,
        )

    def _session(self, token: str) -> Session:
        participant = self._by_token.get(token_hash(token))
        if participant is None:
            raise Refused(
                401, "no session has this token (it may have continued in another window)"
            )
        return self._sessions[participant]

    def _remember(self, session: Session) -> None:
        self._sessions[session.participant] = session
        self._by_token[session.token_sha256] = session.participant

    def _participant_lock(self, participant: str) -> threading.Lock:
        lock = self._locks.get(participant)
        if lock is None:
            lock = self._locks.setdefault(participant, threading.Lock())
        return lock


def _collected(participant: str, condition: str, shown: Submission, order: int | None) -> Collected:
    """The demonstration ``shown`` by ``participant`` in ``condition``, ``order``-th of her
    tasks."""
    if len(shown.seconds) != len(shown.path):
        raise Refused(
            400,
            f"the demonstration has {len(shown.path)} cells and {len(shown.seconds)} times; "
            "each cell has its time",
        )
    recorded = Recorded(
        participant=participant,
        condition=condition,
        path=shown.path,
        seconds=shown.seconds,
        order=order,
    )
    return Collected(task=shown.task, recorded=recorded)
