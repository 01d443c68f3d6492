"""``cirl-study analyze RUN``: the paper's statistics, figures and claims from a run's logs."""

from __future__ import annotations

import datetime
import gc
import importlib
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from cirl_study.commands.parameters import Command
from cirl_study.escape import terminal

if TYPE_CHECKING:
    from cirl_study.analysis.replacement import Replacement

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
        help="Report directory: report.md, results.json, trials.csv and the figures, "
        "replaced whole once written (its other files are kept). A report of another run "
        "there is refused unless --force.",
    ),
]

ForceOption = Annotated[
    bool,
    typer.Option("--force", help="Replace a report of another run in the report directory."),
]


PartialOption = Annotated[
    bool,
    typer.Option(
        "--partial",
        help="Report on an incomplete or damaged run: what its logs hold, marked partial "
        "in the report's first line (main-block subjects missing a cell are left out).",
    ),
]


@app.command(cls=Command)
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
    every universe. The new report replaces the old one at once, when it is complete: a
    failure leaves the old one whole.
    """
    report_run(run, out if out is not None else run / REPORT_NAME, partial=partial, force=force)


def report_run(
    run: Path,
    target: Path,
    *,
    partial: bool = False,
    force: bool = False,
    keep_if_equal: bool = False,
) -> Replacement:
    """Analyse the run ``run`` into the report directory ``target`` and say so in one line:
    what :func:`analyze` does, for it and for ``reproduce``.

    The report replaces the one there whole, and only a report of the same run unless
    ``force``; with ``keep_if_equal`` a report there equal by value to the new one is kept
    untouched (:func:`~cirl_study.analysis.replacement.replacing_report`).

    Returns:
        What the replacement did.
    """

    def stage(name: str) -> None:
        """Say at a terminal which stage is under way (each can take seconds)."""
        if sys.stderr.isatty():
            typer.echo(f"{terminal(name, limit=None)} ...", err=True)

    # Only the reader loads before the workers start reading the logs; the rest (pandas, the
    # statistics and plotting libraries) loads meanwhile, with the report's own provenance,
    # and each kind of report loads its own module after.
    from cirl_study.logs.reader import read_run
    from cirl_study.study.pipeline_file import logged_pipeline

    stage(f"reading the logs of {run}")
    report_provenance: dict[str, Any] = {}
    contents = read_run(
        run,
        logged_pipeline,
        salvage=partial,
        meanwhile=lambda: report_provenance.update(prepare_analysis(outputs=(run, target))),
    )

    from cirl_study.analysis.replacement import replacing_report
    from cirl_study.study.audit import analysed_run

    for warning in contents.warnings:
        typer.echo(f"warning: {terminal(warning, limit=None)}", err=True)
    chosen = analysed_run(run, contents, partial)
    pipeline, trials, partial_run = chosen.pipeline, chosen.trials, chosen.partial
    run_id = contents.identity.run_id
    provenance = report_provenance_of(contents.provenance, report_provenance)
    with replacing_report(
        target, run_id=run_id, force=force, keep_if_equal=keep_if_equal
    ) as replacement:
        if pipeline.multiverse is not None:
            from cirl_study.analysis.multiverse_report import write_multiverse_report

            multiverse = write_multiverse_report(
                trials,
                replacement.stage,
                pipeline,
                run_id=run_id,
                provenance=provenance,
                progress=stage,
            )
            shares = ", ".join(
                f"{claim.id} {claim.reproduced}/{claim.universes}" for claim in multiverse.claims
            )
            what = f"multiverse report of {len(trials)} trials in {len(multiverse.universes)} "
            what += "universes"
            summary = f"universes reproducing each claim: {shares}"
        else:
            from cirl_study.analysis.report import write_report
            from cirl_study.analysis.theory_claims import theory_claims

            results = write_report(
                trials,
                replacement.stage,
                pipeline,
                records_of=lambda wanted: contents.records(run, wanted),
                run_id=run_id,
                theory=theory_claims(),
                provenance=provenance,
                partial=partial_run,
                progress=stage,
            )
            claims = results.claims
            tested = [claim for claim in claims if claim.tested]
            reproduced = sum(claim.reproduced is True for claim in tested)
            answered = sum(claim.reproduced is None for claim in tested)
            what = f"{'partial ' if partial_run else ''}report of {len(trials)} trials"
            summary = (
                f"{len(claims)} claims, {reproduced} reproduced, "
                f"{len(tested) - reproduced - answered} not reproduced, "
                f"{len(claims) - len(tested)} not tested"
                + (f", {answered} questions answered" if answered else "")
            )
    where = "equal by value to the one kept in" if replacement.kept else "written to"
    typer.echo(f"{what} {where} {terminal(target)}: {summary}")
    return replacement


def report_provenance_of(run: list[dict[str, str]], report: dict[str, Any]) -> dict[str, Any]:
    """``provenance.json`` of a report: each distinct provenance of the run's log files
    (``run``, in a fixed order) and the report's own (``report``, from
    :func:`prepare_analysis`)."""
    distinct = {json.dumps(p, sort_keys=True): p for p in run}
    return {"run": [distinct[key] for key in sorted(distinct)], "report": report}


def prepare_analysis(outputs: tuple[Path, ...]) -> dict[str, Any]:
    """What every report needs that the logs do not hold, prepared while they are read: the
    libraries (pandas, scipy, matplotlib, pingouin and the run's audit) and the
    report's provenance, which it returns: the date, the machine and the packages
    (:func:`~cirl_study.logs.provenance.machine_provenance`; whether the checkout is dirty
    judged without the ``outputs``, the run and report directories).

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
        **machine_provenance(outputs=outputs),
    }
