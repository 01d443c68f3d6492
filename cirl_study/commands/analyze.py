"""``cirl-study analyze RUN``: the paper's statistics, figures and claims from a run's logs."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated

import typer

app = typer.Typer()
"""The ``analyze`` command, merged into :data:`cirl_study.cli.app`."""

REPORTS_DIRECTORY = Path("reports")
"""Parent of the default report directory ``reports/<pipeline name>``."""


RunArgument = Annotated[
    Path,
    typer.Argument(
        help="Run directory holding the *.mcap log files, e.g. data/runs/paper.",
        show_default=False,
    ),
]

ReportDirectoryOption = Annotated[
    Path | None,
    typer.Option(
        "--out",
        metavar="DIR",
        show_default="reports/<pipeline name>",
        help="Report directory: report.md, results.json, trials.csv and the figures.",
    ),
]


PartialOption = Annotated[
    bool,
    typer.Option(
        "--partial",
        help="Report on an incomplete or damaged run: what its logs hold, marked partial "
        "in the report's first line (main-block subjects missing a cell are left out).",
    ),
]


@app.command()
def analyze(
    run: RunArgument, out: ReportDirectoryOption = None, partial: PartialOption = False
) -> None:
    """Analyse a run's logs: the paper's statistics, figures and claims, with verdicts.

    Mixed ANOVAs, simple effects, Tukey HSD, Wilcoxon tests, Cronbach's alpha, the lambda
    sweep and the eta cross-validation, written as report.md, results.json, trials.csv and
    PNG figures. Reads only the run's MCAP logs, checking every CRC and that every file and
    record belongs to the run. A run missing planned trials, or holding a damaged file, is
    refused unless --partial; a foreign trial always is. Identical logs give an identical
    report.
    """
    # The statistics and plotting libraries load only when an analysis is asked for.
    from cirl_study.analysis.report import write_report
    from cirl_study.analysis.table import complete_main_subjects
    from cirl_study.analysis.theory_claims import office_supplies_claims
    from cirl_study.errors import UserError
    from cirl_study.logs import read_run
    from cirl_study.logs.provenance import machine_provenance
    from cirl_study.study.audit import audit_run, resume_command, run_pipeline_of
    from cirl_study.theory import office_supplies_results

    def stage(name: str) -> None:
        """Say at a terminal which stage is under way (each can take seconds)."""
        if sys.stderr.isatty():
            typer.echo(f"{name} ...", err=True)

    stage(f"reading the logs of {run}")
    contents = read_run(run, salvage=partial)
    for warning in contents.warnings:
        typer.echo(f"warning: {warning}", err=True)
    audit = audit_run(run_pipeline_of(contents.identity), contents.records)
    faults = audit.faults(resume_command(contents.identity, run))
    if audit.foreign or (faults and not partial):
        advice = "" if audit.foreign else ", or analyze it with --partial"
        raise UserError(f"{run}: not a complete run: {faults[0]}{advice}")
    records, left_out = contents.records, []
    partial_run = None
    if partial and not (audit.complete and not contents.damaged):
        records, left_out = complete_main_subjects(records)
        partial_run = {
            "planned": audit.planned,
            "logged": audit.logged,
            "missing": audit.missing_text() or None,
            "damaged_files": len(contents.damaged),
            "main_subjects_left_out": len(left_out),
        }
    target = out if out is not None else REPORTS_DIRECTORY / contents.identity.pipeline_name
    theory = office_supplies_claims(office_supplies_results())
    provenance = {
        "run": sorted(
            {json.dumps(p, sort_keys=True): p for p in contents.provenance}.values(),
            key=lambda p: json.dumps(p, sort_keys=True),
        ),
        "report": machine_provenance(),
    }
    results = write_report(
        records,
        target,
        contents.identity.pipeline_name,
        theory=theory,
        provenance=provenance,
        partial=partial_run,
        progress=stage,
    )
    claims = results["claims"]
    reproduced = sum(claim["reproduced"] for claim in claims)
    untested = sum(not claim["tested"] for claim in claims)
    typer.echo(
        f"{'partial ' if partial_run else ''}report of {len(records)} trials written to "
        f"{target}: {len(claims)} claims, "
        f"{reproduced} reproduced, {len(claims) - reproduced - untested} not reproduced, "
        f"{untested} not tested"
    )
