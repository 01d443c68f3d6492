"""Where trials are played: in this process, in a local process pool, or on a Dask cluster.

An engine receives batches of :class:`~cirl_study.record.TrialSpec` and yields each batch's
records (:func:`cirl_study.core.trial.play_trials`), with the time the worker spent playing
them (:class:`PlayedBatch`), as soon as the batch is done, in whatever order batches
finish. A record depends only on its spec, so the engine, the number of
workers and the order of completion never change what is logged.
"""

from __future__ import annotations

import abc
import contextlib
import logging
import math
import multiprocessing
import os
import pickle
import signal
import threading
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection, wait
from multiprocessing.process import BaseProcess
from types import TracebackType
from typing import Any, Self

from cirl_study import interrupts
from cirl_study.core.trial import play_trials
from cirl_study.errors import UserError
from cirl_study.record import TrialRecord, TrialSpec
from cirl_study.workers import cores

Batch = Sequence[TrialSpec]
Records = list[TrialRecord]


@dataclass(frozen=True)
class PlayedBatch:
    """A batch's records and the wall-clock seconds its worker spent playing them."""

    records: Records
    seconds: float


def play_batch(batch: Batch) -> PlayedBatch:
    """Play ``batch`` (:func:`cirl_study.core.trial.play_trials`), timing it where it runs."""
    began = time.perf_counter()
    records = play_trials(batch)
    return PlayedBatch(records, time.perf_counter() - began)


ENGINES: tuple[str, ...] = ("local", "dask")
"""Names accepted by :func:`make_engine`."""


class Engine(abc.ABC):
    """Plays batches of trials; a context manager that owns its workers while it is entered."""

    description: str
    workers: int
    """Trials played at once (known once the engine is entered)."""

    @abc.abstractmethod
    def start(self) -> None:
        """Start the workers (called on entering the ``with`` block)."""

    @abc.abstractmethod
    def stop(self, failing: bool) -> None:
        """Stop the workers; ``failing`` when the block is left by an exception."""

    @abc.abstractmethod
    def play(self, batches: Sequence[Batch]) -> Iterator[tuple[int, PlayedBatch]]:
        """Yield ``(index of the batch in batches, the played batch)`` as each finishes."""

    def __enter__(self) -> Self:
        try:
            self.start()
        except BaseException:  # what was started is stopped: a worker, a cluster, a client
            self.stop(failing=True)
            raise
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        trace: TracebackType | None,
    ) -> None:
        self.stop(failing=kind is not None)


class WorkerLost(Exception):
    """The workers the run needs are gone: a local worker was killed (by the OOM killer, say)
    or crashed, a Dask cluster has no workers left; the message says which, in a few words
    (``worker died (signal 9)``)."""


def _serve(connection: Connection, parent: int, others: Sequence[Connection]) -> None:
    """A local worker: play each batch received on ``connection`` and send back the
    :class:`PlayedBatch`, or ``(exception,)`` if playing it raised; end when the parent
    closes its end, or ends.

    ``others`` are the parent's ends of this worker's pipe and of those of the workers forked
    before it, closed here so that each worker's pipe ends when the parent closes its end.
    """
    # The stopping signals are the parent's to handle: it stops the run and ends its workers.
    interrupts.leave_to_parent(parent)
    for other in others:
        other.close()
    while True:
        try:
            batch = connection.recv()
        except EOFError:
            return
        try:
            played: PlayedBatch | tuple[BaseException] = play_batch(batch)
        except Exception as error:
            played = (_portable(error),)
        connection.send(played)


def _portable(error: Exception) -> Exception:
    """``error`` if it pickles, else a :class:`RuntimeError` of its text."""
    try:
        pickle.dumps(error)
    except Exception:
        return RuntimeError(f"{type(error).__name__}: {error}")
    return error


@dataclass
class _Worker:
    """A local worker process, the parent's end of its pipe, and the batch it plays."""

    process: BaseProcess
    connection: Connection
    batch: int | None = None
    """Index of the batch the worker plays, if any."""

    def died(self) -> WorkerLost:
        """The error of this worker's end, once it has ended."""
        self.process.join(timeout=1.0)
        code = self.process.exitcode
        if code is not None and code < 0:
            return WorkerLost(f"worker died (signal {-code})")
        return WorkerLost(f"worker died (exit code {code})")


class LocalEngine(Engine):
    """``workers`` processes on this machine, each playing one batch at a time; one worker
    plays in this process.

    The parent waits on each worker's pipe and on its process at once
    (:func:`multiprocessing.connection.wait`), so a worker that ends while the run needs it
    (``kill -9``, the OOM killer) is noticed as it ends and raises :class:`WorkerLost`, never
    a wait without end. Leaving the engine by an exception kills the workers rather than let
    them finish batches that would not be logged.
    """

    def __init__(self, workers: int) -> None:
        if workers < 1:
            raise UserError(f"workers must be a positive integer, got {workers}")
        self.workers = workers
        self.description = "in this process" if workers == 1 else f"local pool of {workers}"
        self._pool: list[_Worker] = []

    def start(self) -> None:
        if self.workers == 1:
            return
        # fork starts workers fast and with every module already imported; they are forked
        # here, before the caller starts any threads.
        methods = multiprocessing.get_all_start_methods()
        context = multiprocessing.get_context("fork" if "fork" in methods else None)
        # A stopping signal waits until every worker forked is in the pool, to be stopped.
        with interrupts.deferred():
            for _ in range(self.workers):
                ours, theirs = context.Pipe()
                others = [ours, *(worker.connection for worker in self._pool)]
                process = context.Process(
                    target=_serve, args=(theirs, os.getpid(), others), daemon=True
                )
                process.start()
                theirs.close()
                self._pool.append(_Worker(process, ours))

    def stop(self, failing: bool) -> None:
        pool, self._pool = self._pool, []
        for worker in pool:
            if failing:
                worker.process.kill()
            worker.connection.close()  # a worker waiting for a batch then ends
        for worker in pool:
            worker.process.join()

    def play(self, batches: Sequence[Batch]) -> Iterator[tuple[int, PlayedBatch]]:
        if not self._pool:
            for index, batch in enumerate(batches):
                yield index, play_batch(batch)
            return
        waiting = iter(range(len(batches)))
        for worker in self._pool:
            self._hand(worker, waiting, batches)
        while any(worker.batch is not None for worker in self._pool):
            ready = set(
                wait(
                    [w.connection for w in self._pool if w.batch is not None]
                    + [w.process.sentinel for w in self._pool]
                )
            )
            for worker in self._pool:
                if worker.batch is not None and worker.connection in ready:
                    index, played = worker.batch, self._receive(worker)
                    self._hand(worker, waiting, batches)
                    yield index, played
                elif worker.process.sentinel in ready:
                    raise worker.died()

    @staticmethod
    def _hand(worker: _Worker, waiting: Iterator[int], batches: Sequence[Batch]) -> None:
        """Send ``worker`` the next batch waiting, if any."""
        worker.batch = next(waiting, None)
        if worker.batch is not None:
            try:
                worker.connection.send(batches[worker.batch])
            except OSError:
                raise worker.died() from None

    @staticmethod
    def _receive(worker: _Worker) -> PlayedBatch:
        """What ``worker`` sent back for its batch; an exception it raised is raised here."""
        try:
            played = worker.connection.recv()
        except (EOFError, OSError):
            raise worker.died() from None
        if isinstance(played, tuple):
            raise played[0]
        return played


@contextlib.contextmanager
def _children_ignore_the_terminal() -> Iterator[None]:
    """Ignore SIGINT and SIGHUP while processes are started, so that they inherit the
    disposition.

    A terminal's Ctrl-C or hang-up reaches the whole process group; the workers (and
    multiprocessing's resource tracker) should leave it to the main process, which stops the
    run and then its cluster, instead of each printing a traceback. SIGTERM stays theirs:
    it is how the cluster ends them. (Only the main thread may change signal handlers;
    elsewhere this does nothing.)
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    terminal = [signum for signum in interrupts.STOPPING if signum != signal.SIGTERM]
    previous = {signum: signal.signal(signum, signal.SIG_IGN) for signum in terminal}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


DEFAULT_NO_WORKERS_TIMEOUT = 60.0
"""Seconds a Dask cluster may be without workers before a run on it stops."""

POLL_SECONDS = 1.0
"""How often a run on Dask that waits for batches asks whether the cluster has workers."""

READY_POLL_SECONDS = 0.02
"""How often a run on Dask looks for a finished batch."""


SILENT = logging.CRITICAL + 1
"""The level of Dask's logs while it plays a run: above all of them, in this process and in a
local cluster's."""


@contextlib.contextmanager
def _silenced() -> Iterator[None]:
    """Keep Dask's client, and the event loop it runs on, from logging while the block runs."""
    from distributed.utils import silence_logging_cmgr

    handler = logging.NullHandler()
    loggers = [logging.getLogger(name) for name in ("tornado", "asyncio")]
    propagating = [logger.propagate for logger in loggers]
    for logger in loggers:
        logger.addHandler(handler)
        logger.propagate = False
    try:
        with silence_logging_cmgr(SILENT):
            yield
    finally:
        for logger, propagate in zip(loggers, propagating, strict=True):
            logger.removeHandler(handler)
            logger.propagate = propagate


class DaskEngine(Engine):
    """Dask distributed: the scheduler at ``scheduler``, or a new local cluster.

    Without a scheduler address a :class:`distributed.LocalCluster` of ``workers``
    single-threaded workers is started (in worker processes, or as threads of this process
    when ``processes`` is false) and closed afterwards; a scheduler that does not answer
    within ``connect_timeout`` seconds is an error. A cluster without a worker for
    ``no_workers_timeout`` seconds on end, from the start or while batches wait (its workers
    died, or it never had any), raises :class:`WorkerLost`, and so do a batch whose workers
    die each time it is tried (:class:`distributed.KilledWorker`) and a scheduler lost on
    the way. The client and its event loop log nothing while the engine runs: the run's one
    line says what happened. Dask is an optional dependency (``pip install
    'cirl-study[dask]'``); workers of a remote cluster need cirl-study installed in the same
    version.
    """

    def __init__(
        self,
        workers: int,
        scheduler: str | None = None,
        processes: bool = True,
        connect_timeout: float = 10.0,
        no_workers_timeout: float = DEFAULT_NO_WORKERS_TIMEOUT,
    ):
        if workers < 1:
            raise UserError(f"workers must be a positive integer, got {workers}")
        if not 0 < no_workers_timeout < math.inf:
            raise UserError(f"the no-workers timeout must be positive, got {no_workers_timeout}")
        self.workers = workers
        self.scheduler = scheduler
        self.processes = processes
        self.connect_timeout = connect_timeout
        self.no_workers_timeout = no_workers_timeout
        self.description = (
            f"Dask scheduler {scheduler}" if scheduler else f"Dask local cluster of {workers}"
        )
        self._client: Any = None
        self._cluster: Any = None
        self._without_workers: float | None = None
        """Since when the cluster has had no workers, while it has none."""
        self._quiet = contextlib.ExitStack()

    def start(self) -> None:
        try:
            from dask.distributed import Client, LocalCluster
        except ImportError:
            raise UserError(
                "the dask engine needs Dask: pip install -e '.[dask]' in a checkout, "
                "pip install 'cirl-study[dask]' otherwise"
            ) from None
        # The client's own account of workers or a scheduler lost (a warning or a traceback
        # each) is the run's to give, in one line.
        self._quiet.enter_context(_silenced())
        if self.scheduler is None:
            with _children_ignore_the_terminal():
                self._cluster = LocalCluster(
                    n_workers=self.workers,
                    threads_per_worker=1,
                    processes=self.processes,
                    dashboard_address=None,
                    silence_logs=SILENT,
                )
            self._client = Client(self._cluster)
        else:
            try:
                self._client = Client(self.scheduler, timeout=self.connect_timeout)
            except (OSError, TimeoutError, ValueError) as error:
                message = str(error).splitlines()[0] if str(error) else type(error).__name__
                raise UserError(
                    f"cannot connect to the Dask scheduler at {self.scheduler}: {message}"
                ) from None
            try:
                self._client.wait_for_workers(1, timeout=self.no_workers_timeout)
            except TimeoutError:
                raise self._no_workers() from None
            self.workers = max(1, sum(self._client.nthreads().values()))

    def stop(self, failing: bool) -> None:
        client, cluster = self._client, self._cluster
        self._client = self._cluster = None
        # A run already failing (Ctrl-C, an error) must report why, not how closing failed.
        with contextlib.suppress(Exception) if failing else contextlib.nullcontext():
            if client is not None:
                client.close()
            if cluster is not None:
                cluster.close()
        self._quiet.close()

    def play(self, batches: Sequence[Batch]) -> Iterator[tuple[int, PlayedBatch]]:
        from dask.distributed import KilledWorker, as_completed

        futures: dict[Any, int] = {
            self._client.submit(play_batch, batch, pure=False): i for i, batch in enumerate(batches)
        }
        # Results are gathered as batches finish (a batch whose worker dies before its result
        # is gathered is played again); this thread only polls, so that it also watches the
        # cluster's workers.
        finished = as_completed(futures, with_results=True)
        self._without_workers = None
        checked = time.monotonic()
        while not finished.is_empty():
            if not finished.has_ready():
                time.sleep(READY_POLL_SECONDS)
                if time.monotonic() - checked >= POLL_SECONDS:
                    self._check_workers()
                    checked = time.monotonic()
                continue
            try:
                future, played = next(finished)
            except KilledWorker:
                lost = "Dask workers died playing a batch, each time it was tried"
                raise WorkerLost(lost) from None
            if future.status != "finished":  # cancelled: the scheduler is gone
                raise WorkerLost(f"lost the connection to {self._name()}")
            yield futures[future], played

    def _check_workers(self) -> None:
        """Raise :class:`WorkerLost` once the cluster has had no workers for the timeout, or
        once its scheduler is gone."""
        try:
            workers = self._client.nthreads()
        except OSError:
            raise WorkerLost(f"lost the connection to {self._name()}") from None
        if workers:
            self._without_workers = None
        elif self._without_workers is None:
            self._without_workers = time.monotonic()
        elif time.monotonic() - self._without_workers >= self.no_workers_timeout:
            raise self._no_workers()

    def _no_workers(self) -> WorkerLost:
        return WorkerLost(f"{self._name()} has had no workers for {self.no_workers_timeout:g} s")

    def _name(self) -> str:
        return f"the Dask scheduler at {self.scheduler}" if self.scheduler else "the Dask cluster"


def make_engine(
    name: str,
    workers: int | None,
    scheduler: str | None,
    no_workers_timeout: float | None = None,
) -> Engine:
    """The engine ``name`` (see :data:`ENGINES`) with ``workers`` workers (default: all cores);
    ``scheduler`` and ``no_workers_timeout`` (default :data:`DEFAULT_NO_WORKERS_TIMEOUT`) are
    the Dask engine's."""
    count = cores() if workers is None else workers
    if name == "local":
        if scheduler is not None:
            raise UserError("a scheduler address is for the dask engine, not the local one")
        if no_workers_timeout is not None:
            raise UserError("a no-workers timeout is for the dask engine, not the local one")
        return LocalEngine(count)
    if name == "dask":
        timeout = DEFAULT_NO_WORKERS_TIMEOUT if no_workers_timeout is None else no_workers_timeout
        return DaskEngine(count, scheduler, no_workers_timeout=timeout)
    raise UserError(f"the engine must be one of {', '.join(ENGINES)}, got {name!r}")
