"""``cirl-study analyze RUN``: the paper's statistics, figures and claims from a run's logs."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from cirl_study.commands.parameters import Command, RunArgument
from cirl_study.escape import terminal

if TYPE_CHECKING:
    from cirl_study.analysis.report.replacement import Replacement

app = typer.Typer(rich_markup_mode=None)
"""The ``analyze`` command, merged into :data:`cirl_study.cli.app`."""

REPORT_NAME = "report"
"""Name of the default report directory, inside the run directory it reports on."""


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
    Dragan's, ...), the others listed as not tested; the claims on the run's data, the
    theorems checked exactly (independent of the run) and the claims not tested are counted
    apart, with a warning when the judged claims' cells have fewer than 20 subjects. A
    multiverse gets the paper's claims in every universe. The new report replaces the old
    one at once, when it is complete: a failure leaves the old one whole.
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
    untouched (:func:`~cirl_study.analysis.report.replacement.replacing_report`).

    Returns:
        What the replacement did.
    """

    def stage(name: str) -> None:
        """Say at a terminal which stage is under way (each can take seconds)."""
        if sys.stderr.isatty():
            typer.echo(f"{terminal(name, limit=None)} ...", err=True)

    # Only the reading loads before the workers start reading the logs; the rest (pandas, the
    # statistics and plotting libraries) loads meanwhile, and each kind of report loads its
    # own module after.
    from cirl_study.analysis.reading import read_for_analysis

    stage(f"reading the logs of {run}")
    analysed = read_for_analysis(run, partial=partial, outputs=(target,), warn=warn)

    from cirl_study.analysis.report.replacement import replacing_report

    pipeline, trials, run_id = analysed.pipeline, analysed.trials, analysed.run_id
    with replacing_report(
        target, run_id=run_id, force=force, keep_if_equal=keep_if_equal
    ) as replacement:
        if pipeline.multiverse is not None:
            from cirl_study.analysis.multiverse.report import write_multiverse_report

            multiverse = write_multiverse_report(
                trials,
                replacement.stage,
                pipeline,
                run_id=run_id,
                provenance=analysed.provenance,
                progress=stage,
            )
            shares = ", ".join(
                f"{claim.id} {claim.reproduced}/{claim.universes}" for claim in multiverse.claims
            )
            what = f"multiverse report of {len(trials)} trials in {len(multiverse.universes)} "
            what += "universes"
            summary = f"universes reproducing each claim: {shares}"
        else:
            from cirl_study.analysis.report.study import write_report
            from cirl_study.analysis.results.claims import count_claims
            from cirl_study.analysis.results.theory_claims import theory_claims

            results = write_report(
                trials,
                replacement.stage,
                pipeline,
                records_of=analysed.records,
                run_id=run_id,
                theory=theory_claims(),
                provenance=analysed.provenance,
                partial=analysed.partial,
                progress=stage,
            )
            what = f"{'partial ' if analysed.partial else ''}report of {len(trials)} trials"
            summary = count_claims(results.claims).summary()
    where = "equal by value to the one kept in" if replacement.kept else "written to"
    typer.echo(f"{what} {where} {terminal(target)}: {summary}")
    return replacement


def warn(warning: str) -> None:
    """Say a warning of reading a run's logs on stderr, as every command reading one does."""
    typer.echo(f"warning: {terminal(warning, limit=None)}", err=True)
