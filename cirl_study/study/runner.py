"""Running a pipeline: plan the trials, play them on an engine, log every batch, resume.

A run directory is written by one process at a time (:func:`~cirl_study.logs.lock.writer_lock`)
and holds complete MCAP files only: each batch of trials is written by this process to its
own file under a temporary name and renamed when complete
(:class:`~cirl_study.logs.TrialLogWriter`). A run killed at any moment therefore loses at
most the batches in flight. Started again, it deletes the temporary files, skips every
trial whose record a complete file holds (decoded and checked, never taken from the file's
own index) and plays the rest; since a trial's record
depends only on its identity (:mod:`cirl_study.study.plan`), the finished directory holds the
same records as an uninterrupted run, each exactly once. A run stopped on the way, by a
signal (:class:`~cirl_study.interrupts.Interrupted`) or by the loss of its workers
(:class:`~cirl_study.errors.RunStopped`), says in its one line how many trials it kept and
the command that resumes it.

Order of play: block ``eta_cv`` first; then, per feature level, the eta is chosen from the
logged cross-validation records (by default the lowest mean regret; in a multiverse, as each
universe sets it, :func:`~cirl_study.study.eta_cv.study_etas`), and blocks ``main`` and
``lambda_sweep`` are planned with it and played.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import itertools
import math
import os
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from operator import attrgetter
from pathlib import Path

import msgspec

from cirl_study import interrupts
from cirl_study.errors import PlayerFault, RunStopped, UserError
from cirl_study.escape import terminal
from cirl_study.files import RUNS_DIRECTORY, non_regular, remove_file
from cirl_study.interrupts import Interrupted
from cirl_study.logs.format import LOG_SUFFIX, log_files, temp_files
from cirl_study.logs.lock import LOCK_NAME, writer_lock, writer_pid
from cirl_study.logs.provenance import RunIdentity, collect_provenance
from cirl_study.logs.reader import AnotherRunLogged, LoggedRun, logged_run
from cirl_study.logs.versions import LOG_FORMAT
from cirl_study.logs.writer import TrialLogWriter
from cirl_study.record import TrialRecord, TrialRow, TrialSpec
from cirl_study.study.audit import resume_command
from cirl_study.study.engines import Engine, WorkerLost
from cirl_study.study.eta_cv import EtaChoice, EtaKey, study_etas
from cirl_study.study.limits import MAX_BATCH
from cirl_study.study.pipeline_file import (
    logged_pipeline,
    path_argument,
    pipelines_in,
    with_collected,
)
from cirl_study.study.plan import (
    eta_cv_trials,
    gradient_ascent_settings,
    study_trials,
    trial_counts,
)
from cirl_study.study.spec import Pipeline
from cirl_study.workers import aside

BATCHES_PER_WORKER = 4
"""A block is cut into at least this many batches per worker, so that workers finish together."""


@dataclass(frozen=True)
class RunResult:
    """What a call of :func:`run_pipeline` did."""

    out_dir: Path
    run_id: str
    total: int
    """Trials of the pipeline."""
    resumed: int
    """Trials found complete in the directory before this call."""
    played: int
    """Trials played (and logged) by this call."""
    files: int
    """Complete log files in the directory afterwards."""
    seconds: float
    play_seconds: float
    """Seconds the workers spent playing the trials of this call, summed over workers:
    ``play_seconds / workers`` is the run's compute floor."""
    playing_seconds: float
    """Wall-clock seconds from the start of play (when the progress bar starts) to the last
    trial logged: ``seconds`` less start-up, checks and kernel preparation."""
    workers: int
    etas: dict[EtaKey, EtaChoice]
    """The eta of every human with a trade-off, per universe and feature level."""


@dataclass
class ProgressHooks:
    """Callbacks for progress reports: ``note(text)`` for a stage before playing starts,
    ``start(total, done)`` once, then ``advance(n, block)`` as ``n`` trials of ``block`` are
    logged."""

    start: Callable[[int, int], None] = lambda total, done: None
    advance: Callable[[int, str], None] = lambda count, block: None
    note: Callable[[str], None] = lambda text: None


def warm_up(pipeline: Pipeline) -> None:
    """Play one throw-away trial per (human, robot) of ``pipeline`` in this process.

    The first run on a machine compiles the numerical kernels (numba; cached on disk
    afterwards, so later runs load them in a fraction of a second). Doing it here, before
    the engine starts its workers, lets forked workers inherit them and keeps the progress
    bar for playing. Nothing is logged.

    The compiling is split over two cores first: a forked worker has the first robot watch
    a stand-in path (:func:`_watch_stand_ins`: that robot's fit and the measures, without the
    humans' kernels) while this process plays the humans' demonstrations
    (:func:`~cirl_study.core.trial.demonstrations`), then has the other robots watch. The
    worker's kernels land in numba's cache, from which this process then loads them, so a
    first run compiles in about the time of the slower half instead of both
    (``benchmarks/README.md``). Where the cache cannot be written, or no worker can be
    forked, this process compiles what it needs itself; the trials played do not change.
    """
    from cirl_study.core.players import HUMANS
    from cirl_study.core.trial import demonstrations, play_trials

    base = (eta_cv_trials(pipeline) or study_trials(pipeline, _fixed_etas(pipeline)))[0]
    participants = pipeline.participants
    shown = None if participants is None else participants.shown().shown[0]
    trials = [
        msgspec.structs.replace(
            base,
            trial_id=f"warm-up of {human} and {robot}",
            human=human,
            eta=1.0 if HUMANS[human].takes_eta else None,
            robot=robot,
            gradient_ascent=gradient_ascent_settings(pipeline, robot),
            task=shown.task if shown and HUMANS[human].recorded else base.task,
            recorded=shown.recorded if shown and HUMANS[human].recorded else None,
        )
        for human in pipeline.main.humans
        for robot in pipeline.main.robots
    ]
    watching = [trial for trial in trials if trial.human == trials[0].human]
    first = [trial for trial in watching if trial.robot == watching[0].robot]
    with aside(_watch_stand_ins, first):
        demonstrations(trials)
        _watch_stand_ins([trial for trial in watching if trial.robot != watching[0].robot])
    play_trials(trials)


def _fixed_etas(pipeline: Pipeline) -> dict[EtaKey, float]:
    """The etas of ``pipeline``'s study blocks where nothing is cross-validated."""
    return {key: choice.eta for key, choice in study_etas(pipeline, []).items()}


def _watch_stand_ins(trials: Sequence[TrialSpec]) -> list[TrialRecord]:
    """The records of ``trials`` had each watched the path of first moves
    (:func:`~cirl_study.core.trial.first_move_paths`): what compiles the robots' and the
    measures' kernels and none of the humans'."""
    from cirl_study.core.trial import first_move_paths, play_watched

    return play_watched(trials, first_move_paths(trials))


def default_out_dir(pipeline: Pipeline) -> Path:
    """``data/runs/<pipeline name>`` below the current directory (:data:`RUNS_DIRECTORY`)."""
    return RUNS_DIRECTORY / pipeline.name


def batch_size(pending: int, workers: int) -> int:
    """Trials per batch: ``pending`` cut into ``BATCHES_PER_WORKER`` batches per worker at least.

    Never more than :data:`MAX_BATCH`, so a killed run loses little and a batch's records fit
    in memory comfortably.
    """
    return max(1, min(MAX_BATCH, math.ceil(pending / (workers * BATCHES_PER_WORKER))))


def split_batches(trials: Sequence[TrialSpec], size: int) -> list[list[TrialSpec]]:
    """``trials`` cut, in order, into batches of at most ``size`` that never mix blocks."""
    batches = []
    for _, group in itertools.groupby(trials, key=attrgetter("block")):
        block = list(group)
        batches += [block[i : i + size] for i in range(0, len(block), size)]
    return batches


def batch_file_name(batch: Sequence[TrialSpec]) -> str:
    """``<block>-<hash of the batch's trial ids>.mcap``: the same batch, the same name.

    A batch never mixes blocks (:func:`split_batches`).
    """
    digest = hashlib.blake2b(digest_size=8)
    for trial in batch:
        digest.update(trial.trial_id.encode() + b"\n")
    return f"{batch[0].block}-{digest.hexdigest()}{LOG_SUFFIX}"


def run_identity(pipeline: Pipeline) -> RunIdentity:
    """The identity every log file of ``pipeline``'s run states in its provenance."""
    participants = pipeline.participants
    return RunIdentity(
        pipeline.run_id,
        pipeline.name,
        path_argument(pipeline.path),
        pipeline.text,
        demonstrations=""
        if participants is None or participants.collect
        else participants.shown().text,
    )


def prepare_run_directory(out_dir: Path, identity: RunIdentity) -> LoggedRun:
    """Make ``out_dir`` ready for this run; return what it holds.

    Refuses damaged log files and log files of another run (another pipeline file, or
    another version of it), since a run's records must all come from one specification
    (:func:`~cirl_study.logs.reader.logged_run`); then deletes the temporary files of an
    interrupted run, which only this process, holding the writer lock, may own. An entry
    named like a temporary file that is no regular file (a link, a FIFO, a directory) was not
    made by a run: it is refused, not deleted.
    """
    logged = logged_run(out_dir, identity, pipelines_in(out_dir))
    temporaries = temp_files(out_dir)
    for path in temporaries:
        reason = non_regular(path)
        if reason is not None:
            raise UserError(
                f"{path}: {reason}, not a temporary log file of a run; move it out of {out_dir}"
            )
    for path in temporaries:
        remove_file(path)
    return logged


@dataclass
class _Session:
    """One call of :func:`run_pipeline`: where batches go, and which trials are logged."""

    engine: Engine
    out_dir: Path
    provenance: dict[str, str]
    progress: ProgressHooks
    logged: LoggedRun
    """What the directory held before this call."""
    done: set[str]
    play_seconds: float = 0.0
    """Seconds the workers spent playing the batches of this call, summed over workers."""

    def play(self, trials: Sequence[TrialSpec]) -> Iterator[list[TrialRecord]]:
        """Play the ``trials`` not yet logged; log each batch to its own file, then yield it."""
        pending = [trial for trial in trials if trial.trial_id not in self.done]
        if not pending:
            return
        batches = split_batches(pending, batch_size(len(pending), self.engine.workers))
        for index, played in self.engine.play(batches):
            batch, records = batches[index], played.records
            self.play_seconds += played.seconds
            if [record.trial_id for record in records] != [t.trial_id for t in batch]:
                raise RuntimeError("the engine returned records that do not match their batch")
            with interrupts.deferred():  # a signal leaves the batch logged and kept, or neither
                self._log(batch_file_name(batch), records)
                self.done.update(trial.trial_id for trial in batch)
            self.progress.advance(len(batch), batch[0].block)
            yield records

    def _log(self, name: str, records: Sequence[TrialRecord]) -> None:
        """Write one batch's file; an operating-system error ends the run in one line."""
        path = self.out_dir / name
        try:
            with TrialLogWriter(path, self.provenance) as log:
                for record in records:
                    log.write(record)
        except OSError as error:
            raise UserError(
                f"{path}: cannot write the log ({error.strerror or error}); the "
                f"{len(self.done)} trial(s) logged before are kept: fix the cause and run "
                "again to resume"
            ) from None


def _cross_validate(
    session: _Session, pipeline: Pipeline, trials: Sequence[TrialSpec]
) -> dict[EtaKey, EtaChoice]:
    """Play block ``eta_cv`` (its ``trials``) and take the etas of ``pipeline``'s study blocks
    from its records (:func:`~cirl_study.study.eta_cv.study_etas`).

    The records of trials logged before this call are read back from the logs (the files
    read when the run was prepared); those played now are taken as they were logged (the log
    holds them byte for byte, and JSON keeps every float exactly), which spares reading the
    files just written.
    """
    logged_before = {trial.trial_id for trial in trials} & session.done
    rows: dict[str, TrialRow] = {}
    if logged_before:
        logged = session.logged.records(logged_before)
        rows = {record.trial_id: TrialRow.of(record) for record in logged}
    for batch in session.play(trials):
        rows.update((record.trial_id, TrialRow.of(record)) for record in batch)
    missing = [trial.trial_id for trial in trials if trial.trial_id not in rows]
    if missing:
        raise UserError(f"cross-validation trial {missing[0]} is missing from the logs")
    try:
        return study_etas(pipeline, [rows[trial.trial_id] for trial in trials])
    except ValueError as error:
        raise UserError(f"eta cross-validation: {error}") from None


def run_pipeline(
    pipeline: Pipeline,
    out_dir: Path,
    engine: Engine,
    progress: ProgressHooks | None = None,
) -> RunResult:
    """Run (or resume) ``pipeline`` into ``out_dir`` on ``engine`` (not yet entered).

    ``pipeline`` is as :func:`~cirl_study.study.pipeline_file.parse_pipeline` validates it,
    within the limits of :mod:`cirl_study.study.limits`.

    Raises:
        UserError: among others, the run directory cannot be created or locked (another run
            holds it; an OS error such as a full disk while its lock file is written), in one
            line; nothing is played, every log file there is kept, and a directory this run
            created is removed again.
    """
    hooks = progress or ProgressHooks()
    began = time.perf_counter()
    created = _make_directory(out_dir)
    with contextlib.ExitStack() as stack:
        try:
            stack.enter_context(writer_lock(out_dir))
        except BaseException:
            if writer_pid(out_dir) is None:  # the lock failed, and no other run holds it
                _remove_unused(out_dir, created)
            raise
        try:
            return _run_locked(pipeline, out_dir, engine, hooks, began)
        except BaseException:
            _remove_unused(out_dir, created)
            raise


def _refuse_unplanned(out_dir: Path, logged: set[str], planned: Sequence[TrialSpec]) -> None:
    """Refuse, before the study blocks play, a directory holding trials the plan lacks."""
    unplanned = sorted(logged - {trial.trial_id for trial in planned})
    if unplanned:
        raise UserError(
            f"{out_dir}: holds {len(unplanned)} logged trial(s) this pipeline does not plan "
            f"(e.g. {unplanned[0]}), written by another version of cirl-study; "
            "use another --out directory"
        )


def _make_directory(out_dir: Path) -> list[Path]:
    """Create the run directory, or say in one line why it cannot be; the directories
    created, ``out_dir`` first, then each parent created for it."""
    if out_dir.exists() and not out_dir.is_dir():
        raise UserError(f"{out_dir}: exists and is not a directory")
    missing = list(itertools.takewhile(lambda path: not path.exists(), [out_dir, *out_dir.parents]))
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise UserError(f"{out_dir}: cannot create the run directory: {error.strerror}") from None
    return missing


def _remove_unused(out_dir: Path, created: Sequence[Path]) -> None:
    """Remove the directories ``created`` for a run that failed before it logged anything
    (its engine could not start, say), so that it leaves nothing behind: ``out_dir`` only if
    it holds the lock file alone, each parent only if it is empty then."""
    if not created:
        return
    with contextlib.suppress(OSError):
        if os.listdir(out_dir) == [LOCK_NAME]:
            (out_dir / LOCK_NAME).unlink()
        for directory in created:
            directory.rmdir()


def _players(pipeline: Pipeline) -> tuple[str, ...]:
    """Every player ``pipeline`` plays: its humans, its robots and a multiverse's."""
    universes = pipeline.multiverse.universes if pipeline.multiverse is not None else ()
    return (
        *pipeline.main.humans,
        *pipeline.main.robots,
        *(universe.robot for universe in universes),
    )


def _same_settings(another: AnotherRunLogged, pipeline: Pipeline, out_dir: Path) -> Pipeline:
    """The pipeline of the run ``another`` found logged, if its settings are ``pipeline``'s
    (:func:`same_settings`): a run is its settings, not its text. Else ``another`` is raised:
    a run of other settings is another run, and so is a run of an earlier log format (its
    version seeded and named its trials as it did).
    """
    if another.logged.log_format != LOG_FORMAT:
        raise another
    try:
        logged = logged_pipeline(another.logged, out_dir)
    except ValueError:
        raise another from None
    if not same_settings(logged, pipeline):
        raise another
    return logged


def same_settings(first: Pipeline, second: Pipeline) -> bool:
    """Whether two pipelines play the same trials with the same numbers: equal in every
    setting, their ``description``, text (comments, layout) and file aside.

    >>> from cirl_study.study.pipeline_file import load_pipeline, resolve_pipeline
    >>> smoke = load_pipeline(resolve_pipeline("smoke"))
    >>> same_settings(smoke, dataclasses.replace(smoke, description="another", text="# x"))
    True
    >>> same_settings(smoke, dataclasses.replace(smoke, seed=smoke.seed + 1))
    False
    """

    def settings(pipeline: Pipeline) -> Pipeline:
        return dataclasses.replace(pipeline, description="", path=Path(), text="", sha256="")

    return settings(first) == settings(second)


def _kept(identity: RunIdentity, out_dir: Path, done: set[str]) -> str:
    """``N trials kept; resume with `<command>```: what a run stopped on the way says."""
    return f"{len(done)} trials kept; {resume_command(identity, out_dir)}"


def _run_locked(
    pipeline: Pipeline,
    out_dir: Path,
    engine: Engine,
    hooks: ProgressHooks,
    began: float,
) -> RunResult:
    """:func:`run_pipeline` once this process holds the directory's writer lock."""
    pipeline = with_collected(pipeline, out_dir)
    identity = run_identity(pipeline)
    try:
        logged = prepare_run_directory(out_dir, identity)
    except AnotherRunLogged as another:
        pipeline = _same_settings(another, pipeline, out_dir)
        identity = another.logged
        hooks.note(
            f"{terminal(out_dir)}: resuming run {identity.run_id}, made from another text of "
            f"{terminal(pipeline.name)} with the same settings (its description, comments or "
            "layout differ); its files keep the text it was made from"
        )
        logged = prepare_run_directory(out_dir, identity)
    provenance = collect_provenance(identity, out_dir, _players(pipeline))
    done = logged.trial_ids
    resumed = len(done)
    total = sum(trial_counts(pipeline).values())
    if resumed < total:
        hooks.note("preparing the numerical kernels (compiled on a first run, then cached)")
        preparing = time.perf_counter()
        warm_up(pipeline)
        hooks.note(f"numerical kernels ready in {time.perf_counter() - preparing:.1f} s")
    session = _Session(engine, out_dir, provenance, hooks, logged, done)
    try:
        with engine:
            hooks.start(total, resumed)
            play_began = time.perf_counter()
            cv_trials = eta_cv_trials(pipeline)
            etas = _cross_validate(session, pipeline, cv_trials)
            trials = study_trials(pipeline, {key: choice.eta for key, choice in etas.items()})
            _refuse_unplanned(out_dir, done, [*cv_trials, *trials])
            for _ in session.play(trials):
                pass
            playing_seconds = time.perf_counter() - play_began
    except WorkerLost as lost:
        raise RunStopped(f"{lost}: {_kept(identity, out_dir, done)}") from None
    except PlayerFault as fault:
        raise PlayerFault(f"{fault}; {_kept(identity, out_dir, done)}") from None
    except KeyboardInterrupt as interrupt:
        raise Interrupted.of(interrupt, _kept(identity, out_dir, done)) from None
    return RunResult(
        out_dir=out_dir,
        run_id=pipeline.run_id,
        total=total,
        resumed=resumed,
        played=len(done) - resumed,
        files=len(log_files(out_dir)),
        seconds=time.perf_counter() - began,
        play_seconds=session.play_seconds,
        playing_seconds=playing_seconds,
        workers=engine.workers,
        etas=etas,
    )
