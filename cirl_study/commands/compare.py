"""``cirl-study compare EXPECTED GOT``: are two reports the same, number by number?"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from cirl_study.analysis.report.compare import ABSOLUTE_TOLERANCE, RELATIVE_TOLERANCE, Tolerance
from cirl_study.commands.parameters import Command, number
from cirl_study.escape import terminal

app = typer.Typer(rich_markup_mode=None)
"""The ``compare`` command, merged into :data:`cirl_study.cli.app`."""

SHOWN = 20
"""Differences printed before the rest are only counted."""


_tolerance = number(float, "a number >= 0", minimum=0.0)


@app.command(cls=Command)
def compare(
    expected: Annotated[
        Path,
        typer.Argument(
            metavar="EXPECTED", help="Report directory to compare against (e.g. the committed one)."
        ),
    ],
    got: Annotated[Path, typer.Argument(metavar="GOT", help="Report directory to check.")],
    rtol: Annotated[
        float,
        typer.Option(
            help="Relative tolerance (>= 0): a number a of EXPECTED and b of GOT agree "
            "when |a - b| <= atol + rtol |a|.",
            parser=_tolerance,
        ),
    ] = RELATIVE_TOLERANCE,
    atol: Annotated[
        float, typer.Option(help="Absolute tolerance (>= 0).", parser=_tolerance)
    ] = ABSOLUTE_TOLERANCE,
) -> None:
    """Compare the report directory GOT with EXPECTED: every number of results.json and of
    each table (trials.csv, a multiverse's universes.csv) within the tolerance, the text of
    report.md, each figure within an image tolerance, and that every SVG exists. The file
    column of trials.csv (which log file holds a trial: it depends on the number of workers
    that played the run) is not compared.

    Each difference names EXPECTED's value first, then GOT's. Exit code 0 when every number
    agrees within the tolerance and everything else is equal, 1 otherwise (the differences
    are listed), 2 when a report cannot be read.
    """
    from cirl_study.analysis.report.compare import compare_reports

    differences = compare_reports(expected, got, Tolerance(rtol=rtol, atol=atol))
    for line in differences[:SHOWN]:
        typer.echo(line)
    if len(differences) > SHOWN:
        typer.echo(f"... and {len(differences) - SHOWN} more")
    verdict = "the same" if not differences else f"different ({len(differences)} differences)"
    reports = f"{terminal(expected)} vs {terminal(got)}"
    typer.echo(f"{reports}: {verdict} at rtol={rtol:g}, atol={atol:g}")
    if differences:
        raise typer.Exit(code=1)
