"""``cirl-study reproduce``: run a pipeline, then analyze its logs (the README's main command)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer

from cirl_study.commands.analyze import ForceOption, report_run
from cirl_study.commands.parameters import Command
from cirl_study.commands.run import (
    EngineName,
    EngineOption,
    PipelineArgument,
    RunDirectoryOption,
    SchedulerOption,
    WorkersOption,
    run,
)
from cirl_study.escape import terminal

ReportOption = Annotated[
    Path | None,
    typer.Option(
        "--report",
        metavar="DIR",
        show_default="reports/<pipeline name>",
        help="Report directory: report.md, results.json, trials.csv and the figures, "
        "replaced whole unless equal by value (its other files are kept). A report of "
        "another run there is refused unless --force.",
    ),
]


REPORTS_DIRECTORY = Path("reports")
"""Parent of ``reproduce``'s default report directory ``reports/<pipeline name>``: the
committed reports of the shipped pipelines."""

app = typer.Typer(rich_markup_mode=None)
"""The ``reproduce`` command, merged into :data:`cirl_study.cli.app`."""


@app.command(cls=Command)
def reproduce(
    pipeline: PipelineArgument = "paper",
    out: RunDirectoryOption = None,
    report: ReportOption = None,
    workers: WorkersOption = None,
    engine: EngineOption = EngineName.local,
    scheduler: SchedulerOption = None,
    force: ForceOption = False,
) -> None:
    """Reproduce a study: play every trial of PIPELINE (run), then write its report (analyze).

    With the defaults this regenerates reports/paper/ from nothing (run again, it resumes)
    and says whether the new report equals the one there, number by number (cirl-study
    compare): if it does, the files there are kept as they are; else the new report
    replaces them. It also says how long the run and the analysis took. A report of another
    run is refused (before the run) unless --force.
    """
    from cirl_study.analysis.report.replacement import refuse_another_runs_report
    from cirl_study.study.pipeline_file import load_pipeline, resolve_pipeline
    from cirl_study.study.runner import default_out_dir

    spec = load_pipeline(resolve_pipeline(pipeline))
    run_directory = out or default_out_dir(spec)
    target = report or REPORTS_DIRECTORY / spec.name
    if not force:  # checked again, under the report's lock, before it is replaced
        refuse_another_runs_report(target, spec.run_id)
    began = time.perf_counter()
    run(pipeline, run_directory, workers, engine, scheduler)
    played = time.perf_counter() - began
    began = time.perf_counter()
    replacement = report_run(run_directory, target, force=force, keep_if_equal=True)
    analysed = time.perf_counter() - began
    typer.echo(f"run {played:.1f} s, analysis {analysed:.1f} s ({analysed / played:.2f} x the run)")
    differences, shown = replacement.differences, terminal(target)
    if differences is None:
        typer.echo(f"{shown}: a new report (there was none to compare with)")
    elif differences:
        typer.echo(
            f"{shown}: DIFFERS from the report it replaced in {len(differences)} place(s), "
            f"e.g. {differences[0]}"
        )
    else:
        typer.echo(f"{shown}: equals the report there, number by number; its files are kept")
