"""``cirl-study show RUN``: a run's identity, status and counts, or the pipeline it plays."""

from __future__ import annotations

from typing import Annotated

import typer

from cirl_study.commands.parameters import Command, RunArgument

app = typer.Typer(rich_markup_mode=None)
"""The ``show`` command, merged into :data:`cirl_study.cli.app`."""


@app.command(cls=Command)
def show(
    run: RunArgument,
    pipeline: Annotated[
        bool,
        typer.Option(
            "--pipeline",
            help="Print only the pipeline text the run was made from, as its logs carry it "
            "(a character a terminal would obey is shown escaped).",
        ),
    ] = False,
) -> None:
    """Say what a run is and how far it got: its id, pipeline and log format; complete or
    not (and the command that completes it, or the pid of the run writing it); the trials
    logged of those planned, per block, and the files. Reads only the run's logs, checking
    every CRC; a damaged file is read as far as it is intact, and named.

    Exit code 0, or 2 when RUN holds no readable run.
    """
    from cirl_study.escape import terminal
    from cirl_study.study.audit import run_status

    status = run_status(run)
    lines = status.identity.pipeline_text.splitlines() if pipeline else status.lines()
    for line in lines:
        typer.echo(terminal(line, limit=None))
