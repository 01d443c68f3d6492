"""``cirl-study analyze RUN``: the paper's statistics, figures and claims from a run's logs."""

from __future__ import annotations

import datetime
import gc
import importlib
import json
import sys
from pathlib import Path
from typing import Annotated, Any

import typer

app = typer.Typer(rich_markup_mode=None)
"""The ``analyze`` command, merged into :data:`cirl_study.cli.app`."""

REPORT_NAME = "report"
"""Name of the default report directory, inside the run directory it reports on."""


RunArgument = Annotated[
    Path,
    typer.Argument(
        metavar="RUN",
        help="Run directory holding the *.mcap log files, e.g. data/runs/paper.",
        show_default=False,
    ),
]

ReportDirectoryOption = Annotated[
    Path | None,
    typer.Option(
        "--out",
        metavar="DIR",
        show_default="RUN/report",
        help="Report directory: report.md, results.json, trials.csv and the figures. A "
        "report of another run there is refused unless --force.",
    ),
]

ForceOption = Annotated[
    bool,
    typer.Option("--force", help="Overwrite a report of another run in the report directory."),
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
    run: RunArgument,
    out: ReportDirectoryOption = None,
    partial: PartialOption = False,
    force: ForceOption = False,
) -> None:
    """Analyse a run's logs: the paper's statistics, figures and claims, with verdicts.

    Mixed ANOVAs, simple effects, Tukey HSD, Wilcoxon tests, Cronbach's alpha, the lambda
    sweep and the eta cross-validation, written as report.md, results.json, trials.csv and
    the figures (PNG and SVG). Reads only the run's MCAP logs, checking every CRC and that
    every file and record belongs to the run. A run missing planned trials, or holding a
    damaged file, is refused unless --partial; a foreign trial always is. Identical logs
    give an identical report. Any design of humans x robots x feature levels is analysed
    alike: the repeated-measures ANOVA with sphericity corrections, every pairwise
    comparison, and every published claim whose cells the run has (the paper's, Milli &
    Dragan's, ...), the others listed as not tested. A multiverse gets the paper's claims in
    every universe.
    """

    def stage(name: str) -> None:
        """Say at a terminal which stage is under way (each can take seconds)."""
        if sys.stderr.isatty():
            typer.echo(f"{name} ...", err=True)

    # Only the reader loads before the workers start reading the logs; the rest (pandas, the
    # statistics and plotting libraries) loads meanwhile, with the report's own provenance,
    # and each kind of report loads its own module after.
    from cirl_study.logs.reader import read_run

    stage(f"reading the logs of {run}")
    report_provenance: dict[str, Any] = {}
    contents = read_run(
        run, salvage=partial, meanwhile=lambda: report_provenance.update(_prepare_analysis())
    )

    from cirl_study.study.audit import analysed_run

    for warning in contents.warnings:
        typer.echo(f"warning: {warning}", err=True)
    chosen = analysed_run(run, contents, partial)
    pipeline, trials, partial_run = chosen.pipeline, chosen.trials, chosen.partial
    target = out if out is not None else run / REPORT_NAME
    if not force:
        _refuse_another_runs_report(target, contents.identity.run_id)
    provenance = {
        "run": sorted(
            {json.dumps(p, sort_keys=True): p for p in contents.provenance}.values(),
            key=lambda p: json.dumps(p, sort_keys=True),
        ),
        "report": report_provenance,
    }
    if pipeline.multiverse is not None:
        from cirl_study.analysis.multiverse_report import write_multiverse_report

        multiverse = write_multiverse_report(
            trials,
            target,
            pipeline,
            run_id=contents.identity.run_id,
            provenance=provenance,
            progress=stage,
        )
        shares = ", ".join(
            f"{claim.id} {claim.reproduced}/{claim.universes}" for claim in multiverse.claims
        )
        typer.echo(
            f"multiverse report of {len(trials)} trials in {len(multiverse.universes)} "
            f"universes written to {target}: universes reproducing each claim: {shares}"
        )
        return
    from cirl_study.analysis.report import write_report
    from cirl_study.analysis.theory_claims import theory_claims

    results = write_report(
        trials,
        target,
        pipeline,
        records_of=lambda wanted: contents.records(run, wanted),
        run_id=contents.identity.run_id,
        theory=theory_claims(),
        provenance=provenance,
        partial=partial_run,
        progress=stage,
    )
    claims = results.claims
    tested = [claim for claim in claims if claim.tested]
    reproduced = sum(claim.reproduced is True for claim in tested)
    answered = sum(claim.reproduced is None for claim in tested)
    typer.echo(
        f"{'partial ' if partial_run else ''}report of {len(trials)} trials written to "
        f"{target}: {len(claims)} claims, {reproduced} reproduced, "
        f"{len(tested) - reproduced - answered} not reproduced, "
        f"{len(claims) - len(tested)} not tested"
        + (f", {answered} questions answered" if answered else "")
    )


def _prepare_analysis() -> dict[str, Any]:
    """What every report needs that the logs do not hold, prepared while they are read: the
    libraries (pandas, scipy, matplotlib, pingouin and the run's audit) and the
    report's provenance, which it returns: the date, the machine and the packages
    (:func:`~cirl_study.logs.provenance.machine_provenance`).

    The libraries live as long as the process, so the garbage collector is paused while they
    load and they are frozen out of it after (``gc.freeze``, until workers fork: see
    :func:`~cirl_study.workers.started`): its full collections would otherwise walk their few
    hundred thousand objects while they load and while the rows arrive.
    """
    gc.disable()
    try:
        for module in (
            "cirl_study.analysis.statistics",
            "cirl_study.analysis.figures",
            "cirl_study.analysis.table",
            "cirl_study.study.audit",
        ):
            importlib.import_module(module)
    finally:
        gc.enable()
    gc.freeze()
    from cirl_study.logs.provenance import machine_provenance

    return {
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        **machine_provenance(),
    }


def _refuse_another_runs_report(target: Path, run_id: str) -> None:
    """Refuse to overwrite the report of another run (by its ``results.json``'s ``run_id``)."""
    from cirl_study.errors import UserError

    existing = target / "results.json"
    if not existing.is_file():
        return
    try:
        theirs = json.loads(existing.read_text(encoding="utf-8")).get("run_id")
    except (OSError, ValueError, AttributeError):
        theirs = None
    if theirs != run_id:
        raise UserError(
            f"{target}: holds the report of {'another run' if theirs is None else theirs}, not "
            f"of {run_id}; give another --out, or --force to overwrite it"
        )
