"""``cirl-study analyze RUN``: the paper's statistics, figures and claims from a run's logs."""

from __future__ import annotations

import json
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


@app.command()
def analyze(run: RunArgument, out: ReportDirectoryOption = None) -> None:
    """Analyse a run's logs: the paper's statistics, figures and claims, with verdicts.

    Mixed ANOVAs, simple effects, Tukey HSD, Wilcoxon tests, Cronbach's alpha, the lambda
    sweep and the eta cross-validation, written as report.md, results.json, trials.csv and
    PNG figures. Reads only the run's MCAP logs: a damaged file is salvaged with a warning
    on stderr, an incomplete design is refused. Identical logs give an identical report.
    """
    # The statistics and plotting libraries load only when an analysis is asked for.
    from cirl_study.analysis.report import write_report
    from cirl_study.analysis.theory_claims import office_supplies_claims
    from cirl_study.logs import read_run
    from cirl_study.logs.provenance import machine_provenance
    from cirl_study.theory import office_supplies_results

    contents = read_run(run)
    for warning in contents.warnings:
        typer.echo(f"warning: {warning}", err=True)
    target = out if out is not None else REPORTS_DIRECTORY / contents.pipeline_name
    theory = office_supplies_claims(office_supplies_results())
    provenance = {
        "run": sorted(
            {json.dumps(p, sort_keys=True): p for p in contents.provenance}.values(),
            key=lambda p: json.dumps(p, sort_keys=True),
        ),
        "report": machine_provenance(),
    }
    results = write_report(
        contents.records, target, contents.pipeline_name, theory=theory, provenance=provenance
    )
    claims = results["claims"]
    reproduced = sum(claim["reproduced"] for claim in claims)
    untested = sum(not claim["tested"] for claim in claims)
    typer.echo(
        f"report of {len(contents.records)} trials written to {target}: {len(claims)} claims, "
        f"{reproduced} reproduced, {len(claims) - reproduced - untested} not reproduced, "
        f"{untested} not tested"
    )
