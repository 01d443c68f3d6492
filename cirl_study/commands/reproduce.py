"""``cirl-study reproduce``: run a pipeline, then analyze its logs (the README's main command)."""

from __future__ import annotations

import shutil
import tempfile
import time
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


REPORTS_DIRECTORY = Path("reports")
"""Parent of ``reproduce``'s default report directory ``reports/<pipeline name>``: the
committed reports of the shipped pipelines."""

app = typer.Typer(rich_markup_mode=None)
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

    With the defaults this regenerates reports/paper/ from nothing (run again, it resumes)
    and says whether the new report equals the one it replaced, number by number
    (cirl-study compare), and how long the run and the analysis took.
    """
    from cirl_study.analysis.compare import compare_reports
    from cirl_study.study.runner import default_out_dir
    from cirl_study.study.spec import load_pipeline, resolve_pipeline

    spec = load_pipeline(resolve_pipeline(pipeline))
    run_directory = out or default_out_dir(spec)
    target = report or REPORTS_DIRECTORY / spec.name
    began = time.perf_counter()
    run(pipeline, run_directory, workers, engine, scheduler)
    played = time.perf_counter() - began
    with tempfile.TemporaryDirectory(prefix="cirl-study-previous-") as scratch:
        previous = Path(scratch) / "report"
        had_report = (target / "results.json").is_file() and any(target.glob("*.csv"))
        if had_report:
            shutil.copytree(target, previous)
        began = time.perf_counter()
        analyze(run_directory, target, force=True)
        analysed = time.perf_counter() - began
        typer.echo(
            f"run {played:.1f} s, analysis {analysed:.1f} s ({analysed / played:.2f} x the run)"
        )
        if not had_report:
            typer.echo(f"{target}: a new report (there was none to compare with)")
            return
        differences = compare_reports(previous, target)
    if differences:
        typer.echo(
            f"{target}: DIFFERS from the report it replaced in {len(differences)} place(s), "
            f"e.g. {differences[0]}"
        )
    else:
        typer.echo(f"{target}: equals the report it replaced, number by number")
