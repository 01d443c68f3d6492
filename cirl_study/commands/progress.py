"""The progress of ``cirl-study run`` on stderr, imported only when a run starts: a live bar
(rich) at a terminal, plain lines elsewhere (a log, CI), one each time trials are logged
:data:`LINE_SECONDS` or more after the last line, and one when the last trial is."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, TextIO

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    ProgressColumn,
    Task,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.text import Text

from cirl_study.escape import terminal
from cirl_study.study.runner import ProgressHooks


class RateColumn(ProgressColumn):
    """Trials played per second since play began: the rate the run's summary reports."""

    def render(self, task: Task) -> Text:
        elapsed = task.finished_time if task.finished else task.elapsed
        played = task.completed - task.fields["resumed"]
        if not elapsed or played <= 0:
            return Text("- trials/s")
        return Text(f"{played / elapsed:.0f} trials/s")


LINE_SECONDS = 10.0
"""Shortest time between two plain progress lines while trials play: a line is written when
a batch of trials is logged that long or longer after the last one."""


@contextmanager
def progress_bar() -> Iterator[ProgressHooks]:
    """The run's progress on stderr: a live bar at a terminal (:func:`_live_bar`), else plain
    lines (:func:`plain_lines`)."""
    console = Console(stderr=True)
    if not console.is_terminal:
        yield plain_lines(sys.stderr)
        return
    with _live_bar(console) as hooks:
        yield hooks


def plain_lines(stream: TextIO, period: float = LINE_SECONDS) -> ProgressHooks:
    """Progress as plain lines on ``stream``: each stage's note, the trials to play when
    playing starts, then ``trials: n/N (block B), r trials/s, e s elapsed, about l s left``
    at most every ``period`` seconds and when the last trial is logged. The time left is the
    trials left at the rate so far: the blocks' trials cost alike within a factor of a few,
    so it is an estimate, said as one."""
    state = {"total": 0, "done": 0, "resumed": 0, "began": 0.0, "shown": 0.0}

    def line(text: str) -> None:
        print(text, file=stream, flush=True)

    def start(total: int, done: int) -> None:
        now = time.monotonic()
        state.update(total=total, done=done, resumed=done, began=now, shown=now)
        line(f"trials: {done}/{total} logged, {total - done} to play")

    def advance(count: int, block: str) -> None:
        state["done"] += count
        now = time.monotonic()
        if now - state["shown"] < period and state["done"] < state["total"]:
            return
        state["shown"] = now
        elapsed = max(now - state["began"], 1e-9)
        rate = (state["done"] - state["resumed"]) / elapsed
        left = state["total"] - state["done"]
        eta = f", about {left / rate:.0f} s left" if left and rate > 0 else ""
        line(
            f"trials: {state['done']}/{state['total']} ({terminal(block)}), "
            f"{rate:.0f} trials/s, {elapsed:.0f} s elapsed{eta}"
        )

    return ProgressHooks(start, advance, line)


@contextmanager
def _live_bar(console: Console) -> Iterator[ProgressHooks]:
    """A progress bar on ``console``, shown from the first ``start`` until the block ends."""
    bar = Progress(
        TextColumn("trials ({task.fields[block]})"),
        BarColumn(),
        MofNCompleteColumn(),
        RateColumn(),
        TimeElapsedColumn(),
        TextColumn("elapsed,"),
        TimeRemainingColumn(),
        TextColumn("left"),
        console=console,
    )
    task: list[Any] = []

    def start(total: int, done: int) -> None:
        bar.start()
        task.append(
            bar.add_task("trials", total=total, completed=done, resumed=done, block="starting")
        )

    def advance(count: int, block: str) -> None:
        bar.update(task[0], advance=count, block=block)

    def note(text: str) -> None:
        bar.console.print(text, style="dim", highlight=False)

    try:
        yield ProgressHooks(start, advance, note)
    finally:
        if task:
            bar.stop()
