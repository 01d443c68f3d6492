"""``cirl-study reproduce``: run a pipeline, then analyze its logs (the README's main command)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cirl_study.commands.analyze import analyze
from cirl_study.commands.run import (
    EngineName,
    EngineOption,
    PipelineArgument,
    RunDirectoryOption,
    SchedulerOption,
    WorkersOption,
    run,
)

ReportOption = Annotated[
    Path | None,
    typer.Option(
        "--report",
        metavar="DIR",
        show_default="reports/<pipeline name>",
        help="Report directory: report.md, results.json, trials.csv and the figures.",
    ),
]


app = typer.Typer()
"""The ``reproduce`` command, merged into :data:`cirl_study.cli.app`."""


@app.command()
def reproduce(
    pipeline: PipelineArgument = "paper",
    out: RunDirectoryOption = None,
    report: ReportOption = None,
    workers: WorkersOption = None,
    engine: EngineOption = EngineName.local,
    scheduler: SchedulerOption = None,
) -> None:
    """Reproduce a study: play every trial of PIPELINE (run), then write its report (analyze).

    With the defaults this regenerates reports/paper/ from nothing; run again, it resumes.
    """
    from cirl_study.study.runner import default_out_dir
    from cirl_study.study.spec import load_pipeline, resolve_pipeline

    run_directory = out or default_out_dir(load_pipeline(resolve_pipeline(pipeline)))
    run(pipeline, run_directory, workers, engine, scheduler)
    analyze(run_directory, report)
