"""``cirl-study calibrate RUN --target TABLE``: which universe of a run made published numbers."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from cirl_study.analysis.calibration.refine import DEFAULT_MAX_PROBES
from cirl_study.commands.analyze import ForceOption, warn
from cirl_study.commands.parameters import Command, RunArgument, number
from cirl_study.errors import UserError
from cirl_study.escape import terminal

if TYPE_CHECKING:
    from cirl_study.analysis.results.types import Refinement, UniverseDistance

app = typer.Typer(rich_markup_mode=None)
"""The ``calibrate`` command, merged into :data:`cirl_study.cli.app`."""

REPORT_NAME = "calibration"
"""Name of the default calibration report directory, inside the run directory."""

PROBES_NAME = "probes"
"""Name of the default directory of a refinement's probes, inside the run directory."""

TargetOption = Annotated[
    Path,
    typer.Option(
        "--target",
        metavar="TABLE",
        help="CSV of published cell means: columns measure, num_features, human and value, "
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
        help="Report directory: report.md, results.json, universes.csv, cells.csv and the figure, "
        "replaced whole once written. A report of another run there is refused unless --force.",
    ),
]

RefineOption = Annotated[
    bool,
    typer.Option(
        "--refine",
        help="Then search the numeric settings around the nearest universe (sigma, the eta "
        "of each feature level; for the gradient-ascent robot its steps and learning rate), one "
        "at a time, until the distance stops falling; each probe a universe played as a run of "
        "its own in --probes (docs/multiverse.md, Refinement).",
    ),
]

MaxProbesOption = Annotated[
    int | None,
    typer.Option(
        "--max-probes",
        metavar="N",
        parser=number(int, "an integer"),
        show_default=str(DEFAULT_MAX_PROBES),
        help="With --refine: the most probes the search plays (or reuses).",
    ),
]

ProbesOption = Annotated[
    Path | None,
    typer.Option(
        "--probes",
        metavar="DIR",
        show_default="RUN/probes",
        help="With --refine: where the probes are played, a run directory per universe "
        "(DIR/<universe id>). A probe played before is read, not replayed; one holding "
        "another pipeline's logs is refused.",
    ),
]

ProbeWorkersOption = Annotated[
    int | None,
    typer.Option(
        "--workers",
        metavar="N",
        parser=number(int, "an integer"),
        show_default="all cores",
        help="With --refine: a probe's trials played at once, by worker processes on this "
        "machine; 1 plays in this process. Results do not depend on it.",
    ),
]


@app.command(cls=Command)
def calibrate(
    run: RunArgument,
    target: TargetOption,
    out: CalibrationDirectoryOption = None,
    force: ForceOption = False,
    refine: RefineOption = False,
    max_probes: MaxProbesOption = None,
    probes: ProbesOption = None,
    workers: ProbeWorkersOption = None,
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

    With --refine (a multiverse run), a coordinate search then moves the nearest universe's
    numeric settings while the distance falls, each probe played, logged and read as a run;
    the report adds the search's path. Progress of the probes goes to stderr.
    """
    from cirl_study.analysis.calibration.results import read_target
    from cirl_study.analysis.reading import read_for_analysis

    if not refine:
        for given, name in (
            (max_probes, "--max-probes"),
            (probes, "--probes"),
            (workers, "--workers"),
        ):
            if given is not None:
                raise UserError(f"{name} needs --refine")
    if max_probes is not None and max_probes < 1:
        raise UserError(f"--max-probes must be a positive integer, got {max_probes}")
    if workers is not None and workers < 1:
        raise UserError(f"--workers must be a positive integer, got {workers}")
    target_dir = out if out is not None else run / REPORT_NAME
    probes_dir = probes if probes is not None else run / PROBES_NAME
    cells, sha256 = read_target(target)
    outputs = (target_dir, probes_dir) if refine else (target_dir,)
    analysed = read_for_analysis(run, outputs=outputs, warn=warn)
    from cirl_study.analysis.calibration.report import write_calibration_report
    from cirl_study.analysis.calibration.results import calibrate as calibrate_run
    from cirl_study.analysis.report.replacement import replacing_report

    if refine and analysed.pipeline.multiverse is None:
        raise UserError(f"{terminal(run)}: --refine needs a multiverse run, not a single study")
    results = calibrate_run(
        analysed.trials,
        analysed.pipeline,
        cells,
        target_file=target.name,
        target_sha256=sha256,
        run_id=analysed.run_id,
    )
    if refine:
        import msgspec

        from cirl_study.commands.refinement import refine as refine_nearest
        from cirl_study.study.engines import make_engine

        refinement = refine_nearest(
            analysed.pipeline,
            results,
            cells,
            analysed.trials,
            probes=probes_dir,
            engine=lambda: make_engine("local", workers, None),
            max_probes=DEFAULT_MAX_PROBES if max_probes is None else max_probes,
        )
        results = msgspec.structs.replace(results, refinement=refinement)
    with replacing_report(target_dir, run_id=analysed.run_id, force=force) as replacement:
        write_calibration_report(results, replacement.stage, provenance=analysed.provenance)
    nearest = results.universes[0]
    factor = math.exp(math.sqrt(nearest.mean_squared_log_ratio))
    name = terminal(nearest.id) if nearest.id else "the run"
    typer.echo(
        f"calibration of {len(results.universes)} universe(s) against {len(cells)} target "
        f"cells written to {terminal(target_dir)}: nearest {name}, "
        f"D = {nearest.mean_squared_log_ratio:.4g} (within a factor of {factor:.3g})"
    )
    if results.refinement is not None:
        typer.echo(refinement_summary(results.refinement, nearest))


STOPS = {
    "exact": "it reached D = 0",
    "converged": "no neighbour at the smallest step is nearer",
    "budget": "it spent its --max-probes",
}
"""Why a refinement stopped, in words, by its ``stop``."""


def refinement_summary(refinement: Refinement, nearest: UniverseDistance) -> str:
    """The line a refinement ends with: its probes, why it stopped, and where it ended
    against where it began (the ``nearest`` universe of the run)."""
    from cirl_study.analysis.multiverse.results import level_label

    final = refinement.final
    start, end = refinement.start_settings, refinement.final_settings
    moves = ", ".join(
        f"{name} {level_label(start[name])} -> {level_label(end[name])}" for name in refinement.axes
    )
    probes = refinement.played + refinement.reused
    return (
        f"refinement over {', '.join(refinement.axes)}: {probes} probe(s) "
        f"({refinement.played} played now, {refinement.reused} reused), stopped because "
        f"{STOPS[refinement.stop]}: {moves}, D = {final.mean_squared_log_ratio:.4g} "
        f"(was {nearest.mean_squared_log_ratio:.4g})"
    )
