"""``cirl-study calibrate RUN --target TABLE``: which universe of a run made published numbers."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any

import typer

from cirl_study.commands.analyze import (
    ForceOption,
    RunArgument,
    prepare_analysis,
    report_provenance_of,
)
from cirl_study.commands.parameters import Command
from cirl_study.escape import terminal

app = typer.Typer(rich_markup_mode=None)
"""The ``calibrate`` command, merged into :data:`cirl_study.cli.app`."""

REPORT_NAME = "calibration"
"""Name of the default calibration report directory, inside the run directory."""

TargetOption = Annotated[
    Path,
    typer.Option(
        "--target",
        metavar="TABLE",
        help="CSV of published cell means: columns measure, num_features, policy and value, "
        "optionally robot, and se or ci95_low and ci95_high (docs/multiverse.md, Calibration).",
        show_default=False,
    ),
]

CalibrationDirectoryOption = Annotated[
    Path | None,
    typer.Option(
        "--out",
        metavar="DIR",
        show_default="RUN/calibration",
        help="Report directory: report.md, results.json, universes.csv and the figure, "
        "replaced whole once written. A report of another run there is refused unless --force.",
    ),
]


@app.command(cls=Command)
def calibrate(
    run: RunArgument,
    target: TargetOption,
    out: CalibrationDirectoryOption = None,
    force: ForceOption = False,
) -> None:
    """Rank a run's universes by their distance to a table of published numbers.

    Every universe of a multiverse run (a single study is one) is compared with the target
    cell by cell on the log scale: the mean squared log ratio of its cell means to the
    target's ranks them, and where the target gives standard errors or 95% intervals a
    chi-square on the log scale says whether the nearest is within both uncertainties. The
    report lists the nearest universes with their settings, the target beside their cell
    means, the paper's claims in the nearest universe, and per setting the best level and
    how far the distance moves. Reads only the run's MCAP logs, checked as analyze checks
    them; the run must be complete.
    """
    from cirl_study.analysis.calibration import read_target
    from cirl_study.logs.reader import read_run

    target_dir = out if out is not None else run / REPORT_NAME
    cells, sha256 = read_target(target)
    report_provenance: dict[str, Any] = {}
    contents = read_run(
        run,
        meanwhile=lambda: report_provenance.update(prepare_analysis(outputs=(run, target_dir))),
    )
    from cirl_study.analysis.calibration import calibrate as calibrate_run
    from cirl_study.analysis.calibration_report import write_calibration_report
    from cirl_study.analysis.replacement import replacing_report
    from cirl_study.study.audit import analysed_run

    for warning in contents.warnings:
        typer.echo(f"warning: {terminal(warning, limit=None)}", err=True)
    chosen = analysed_run(run, contents, partial=False)
    run_id = contents.identity.run_id
    results = calibrate_run(
        chosen.trials,
        chosen.pipeline,
        cells,
        target_file=target.name,
        target_sha256=sha256,
        run_id=run_id,
    )
    provenance = report_provenance_of(contents.provenance, report_provenance)
    with replacing_report(target_dir, run_id=run_id, force=force) as replacement:
        write_calibration_report(results, replacement.stage, provenance=provenance)
    nearest = results.universes[0]
    factor = math.exp(math.sqrt(nearest.mean_squared_log_ratio))
    name = terminal(nearest.id) if nearest.id else "the run"
    typer.echo(
        f"calibration of {len(results.universes)} universe(s) against {len(cells)} target "
        f"cells written to {terminal(target_dir)}: nearest {name}, "
        f"D = {nearest.mean_squared_log_ratio:.4g} (within a factor of {factor:.3g})"
    )
