"""The progress bar of ``cirl-study run`` on stderr (rich), imported only when a run starts."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

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

from cirl_study.study.runner import ProgressHooks


class RateColumn(ProgressColumn):
    """Trials played per second since play began: the rate the run's summary reports."""

    def render(self, task: Task) -> Text:
        elapsed = task.finished_time if task.finished else task.elapsed
        played = task.completed - task.fields["resumed"]
        if not elapsed or played <= 0:
            return Text("- trials/s")
        return Text(f"{played / elapsed:.0f} trials/s")


@contextmanager
def progress_bar() -> Iterator[ProgressHooks]:
    """A progress bar on stderr, shown from the first ``start`` until the block ends."""
    bar = Progress(
        TextColumn("trials"),
        BarColumn(),
        MofNCompleteColumn(),
        RateColumn(),
        TimeElapsedColumn(),
        TextColumn("elapsed,"),
        TimeRemainingColumn(),
        TextColumn("left"),
        console=Console(stderr=True),
    )
    task: list[Any] = []

    def start(total: int, done: int) -> None:
        bar.start()
        task.append(bar.add_task("trials", total=total, completed=done, resumed=done))

    def advance(count: int) -> None:
        bar.advance(task[0], count)

    def note(text: str) -> None:
        if bar.console.is_terminal:
            bar.console.print(text, style="dim", highlight=False)

    try:
        yield ProgressHooks(start, advance, note)
    finally:
        if task:
            bar.stop()
