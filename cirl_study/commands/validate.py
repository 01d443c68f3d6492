"""``cirl-study validate RUN``: check every log file of a run and the run as a whole."""

from __future__ import annotations

import dataclasses

import typer

from cirl_study.commands.parameters import Command, RunArgument

app = typer.Typer(rich_markup_mode=None)
"""The ``validate`` command, merged into :data:`cirl_study.cli.app`."""


@app.command(cls=Command)
def validate(
    run: RunArgument,
) -> None:
    """Check every MCAP log file of a run and the run as a whole.

    Checks CRCs, the summary and its message counts, schemas, every trial record complete and
    consistent, every file and record of one run, no duplicate trial ids, the design, and
    that the logs hold exactly the trials the run's pipeline plans (what is missing, per
    block, and what is foreign). Prints `OK path: N trials` or `FAIL path: reason` for each
    file, then a line for the run.

    Exit code 0 when everything is sound, 1 on any fault, 2 when RUN is not a directory.
    """
    from cirl_study.escape import terminal
    from cirl_study.logs.validate import validate_run
    from cirl_study.study.audit import plan_faults
    from cirl_study.study.pipeline_file import pipelines_in

    verdict = validate_run(run, pipelines_in(run))
    plan = plan_faults(run, verdict.rows) if verdict.rows else []
    verdict = dataclasses.replace(verdict, faults=(*plan, *verdict.faults))
    for file_verdict in verdict.files:
        typer.echo(terminal(file_verdict.line(), limit=None))
    typer.echo(terminal(verdict.line(), limit=None))
    if not verdict.ok:
        raise typer.Exit(code=1)
