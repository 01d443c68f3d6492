"""Independent pieces of work on every core: each item is handled whole in one worker process.

Used where the items do not depend on each other and what comes back is small beside the
work: reading a run's log files (each file's records are decompressed, decoded and checked,
and only their rows or a verdict come back), drawing a report's figures (only the PNG and
SVG bytes come back) and analysing a multiverse's universes (only their summaries come
back). With :func:`started` the calling process goes on with its own work meanwhile: it
loads pandas, scipy and matplotlib while the files are read, and computes the tests and
writes the trial table while the figures are drawn.
"""

from __future__ import annotations

import contextlib
import gc
import multiprocessing
import os
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any, TypeVar

from cirl_study import interrupts

Item = TypeVar("Item")
Result = TypeVar("Result")


def cores() -> int:
    """The number of cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def forkable() -> bool:
    """Whether workers can be forked safely: the platform forks and no other thread runs."""
    return "fork" in multiprocessing.get_all_start_methods() and threading.active_count() == 1


def map_in_workers(work: Callable[[Item], Result], items: Sequence[Item]) -> Iterator[Result]:
    """``work(item)`` for each of ``items``, in their order, on every core.

    ``work`` must be a module-level function (it is sent to the workers by name). The workers
    are forked, so every module the caller imported is already there. Results come back in
    the order of ``items``, and an exception raised by ``work`` is raised here at its item:
    working in parallel reports what working in order would (later items may have been done,
    and are dropped). With one item, one core, no ``fork`` on the platform, or other threads
    running in this process (a fork copies the locks they may hold, e.g. a Dask client's) the
    items are handled in this process. :func:`started` does the same while this process
    goes on with work of its own.
    """
    with started(work, items) as results:
        yield from results


@contextlib.contextmanager
def started(work: Callable[[Item], Result], items: Sequence[Item]) -> Iterator[Iterator[Result]]:
    """:func:`map_in_workers` begun: the workers have every item on entry, and this process
    is free for its own work until it takes the results, in order, from the iterator given.

    ``with started(read_file, paths) as readings: import_statistics(); rows = list(readings)``
    imports while the files are read. Leaving the block early stops the workers: an item not
    begun is never begun. When the items are handled in this process (see
    :func:`map_in_workers`), each is handled as its result is taken.
    """
    workers = min(cores(), len(items))
    with _forked(work, items, workers if workers >= 2 else 0) as results:
        yield results


@contextlib.contextmanager
def aside(work: Callable[[Item], Result], item: Item) -> Iterator[Iterator[Result]]:
    """``work(item)`` begun in one forked worker while this process does its own work on the
    other cores: ``with aside(compile_robots, trials) as done: compile_humans(); next(done)``.

    The result is taken, and an exception raised by ``work`` raised, from the iterator given;
    leaving the block waits for the worker, and a result not taken is dropped. With one core,
    no ``fork`` on the platform or other threads running, ``work(item)`` is done in this
    process when its result is taken (so not at all if it is not).
    """
    with _forked(work, [item], 1 if cores() >= 2 else 0) as results:
        yield results


@contextlib.contextmanager
def _forked(
    work: Callable[[Item], Result], items: Sequence[Item], workers: int
) -> Iterator[Iterator[Result]]:
    """``work`` of each of ``items`` in ``workers`` forked processes (in this one, lazily,
    when ``workers`` is 0 or this process cannot fork)."""
    if workers == 0 or not forkable():
        yield map(work, items)
        return
    # A signal that stops the command is the calling process's to handle: it stops the workers.
    pool = ProcessPoolExecutor(
        workers,
        mp_context=multiprocessing.get_context("fork"),
        initializer=interrupts.leave_to_parent,
        initargs=(os.getpid(),),
    )
    try:
        # The workers are forked by the first submission, with this process's objects frozen
        # out of the garbage collector's generations: a collection in a worker then leaves
        # the pages it shares with this process alone instead of copying them (a third of
        # the page faults of a report's figure workers).
        # A stopping signal waits until the pool holds every worker it forked: one forked but
        # not yet the pool's would never be told to end, and the interpreter's exit waits for
        # it.
        with interrupts.deferred():
            gc.freeze()
            try:
                results = pool.map(work, items)
            finally:
                gc.unfreeze()
        yield results
    finally:  # after a failure, or when the caller stops early: start nothing more
        pool.shutdown(wait=True, cancel_futures=True)


Call = tuple[Callable[..., Any], tuple[Any, ...]]
"""A call to make in a worker: a module-level function and its positional arguments."""


def call(made: Call) -> Any:
    """``function(*arguments)`` of a :data:`Call`: the work of :func:`started` (or
    :func:`map_in_workers`) when the items are calls of different functions."""
    function, arguments = made
    return function(*arguments)
