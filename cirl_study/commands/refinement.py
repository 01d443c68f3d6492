"""``cirl-study calibrate --refine``: the coordinate search around the nearest universe, each
probe played as a run of its own (``docs/multiverse.md``, *Refinement*).

:func:`refine` joins the three steps: the search (:func:`cirl_study.analysis.calibration.refine.
coordinate_search`) asks for a point's distance; the point is played as a probe
(:func:`cirl_study.study.probes.play_probe`), read as any run is analysed
(:func:`cirl_study.analysis.reading.read_for_analysis`) and measured as every universe of the
run is (:func:`cirl_study.analysis.calibration.results.universe_distance`). Each probe's progress
goes to stderr as a run's does.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

import typer

from cirl_study.analysis.calibration.refine import (
    FIRST_STEP,
    MIN_STEP,
    Point,
    SearchAxis,
    coordinate_search,
)
from cirl_study.analysis.calibration.results import universe_distance
from cirl_study.analysis.reading import read_for_analysis
from cirl_study.analysis.results.types import (
    CalibrationResults,
    Refinement,
    RefinementProbe,
    TargetCell,
    UniverseDistance,
)
from cirl_study.commands.progress import progress_bar
from cirl_study.escape import terminal
from cirl_study.study.engines import Engine
from cirl_study.study.multiverse import universes
from cirl_study.study.probes import play_probe
from cirl_study.study.spec import AXES, Pipeline, Universe

REFINED_AXES = ("sigma", "ascent_steps", "learning_rate")
"""The numeric settings the refinement moves, in the order a sweep visits them: the RBF width,
and for the gradient-ascent robot its step budget (an integer) and step size. The horizon and
lambda, which the paper states, stay as the nearest universe has them."""

INTEGER_AXES = frozenset({"ascent_steps"})
"""The refined settings whose values are integers."""


def refine(
    pipeline: Pipeline,
    results: CalibrationResults,
    target: Sequence[TargetCell],
    *,
    probes: Path,
    engine: Callable[[], Engine],
    max_probes: int,
) -> Refinement:
    """The refinement of the calibration ``results`` of the multiverse run of ``pipeline``:
    the coordinate search from its nearest universe over the :data:`REFINED_AXES` that
    universe has, its probes played below ``probes`` on a fresh ``engine()`` each, at most
    ``max_probes`` of them.

    Raises:
        UserError: a probe cannot be played (:func:`~cirl_study.study.probes.play_probe`)
            or its logs do not read as a complete run.
    """
    nearest = results.universes[0]
    of_run = {u.id: u for u in universes(pipeline)}
    start = of_run[nearest.id]
    names = [name for name in REFINED_AXES if getattr(start, name) is not None]
    axes = [
        SearchAxis(name, name in INTEGER_AXES, AXES[name].levels(pipeline.game)[0])
        for name in names
    ]

    def universe_at(point: Point) -> Universe:
        return replace(start, **dict(zip(names, point, strict=True)))

    def point_of(universe: Universe) -> Point:
        return tuple(getattr(universe, name) for name in names)

    measured = {u.id: u for u in results.universes}
    distances: dict[Point, UniverseDistance] = {
        point_of(u): measured[u.id] for u in of_run.values() if universe_at(point_of(u)) == u
    }
    sources: dict[Point, str] = dict.fromkeys(distances, "run")

    def distance(point: Point) -> float | None:
        universe = universe_at(point)
        count = sum(source != "run" for source in sources.values()) + 1
        _say(f"probe {count} (at most {max_probes}): {universe.id}")
        with progress_bar() as hooks:
            probe = play_probe(pipeline, universe, probes, engine(), hooks)
        analysed = read_for_analysis(
            probe.directory, warn=lambda warning: _say(f"warning: {warning}")
        )
        found = universe_distance(analysed.trials, analysed.pipeline, universe, target)
        distances[point], sources[point] = found, "played" if probe.played else "reused"
        _say(
            f"probe {count}: D = {_shown(found.mean_squared_log_ratio)} "
            f"({sources[point]} in {probe.directory})"
        )
        return found.mean_squared_log_ratio

    search = coordinate_search(
        point_of(start),
        axes,
        distance,
        known={point: d.mean_squared_log_ratio for point, d in distances.items()},
        max_probes=max_probes,
    )
    rows = [
        RefinementProbe(
            id=distances[e.point].id,
            settings=dict(zip(names, e.point, strict=True)),
            axis=e.axis,
            step=e.step,
            source=sources[e.point],
            mean_squared_log_ratio=distances[e.point].mean_squared_log_ratio,
            chi_square=distances[e.point].chi_square,
            chi_square_df=distances[e.point].chi_square_df,
            p=distances[e.point].p,
            log10_p=distances[e.point].log10_p,
            accepted=e.accepted,
        )
        for e in search.evaluations
    ]
    return Refinement(
        start=start.id,
        axes=names,
        first_step=FIRST_STEP,
        min_step=MIN_STEP,
        max_probes=max_probes,
        probes=rows,
        played=sum(row.source == "played" for row in rows),
        reused=sum(row.source == "reused" for row in rows),
        stop=search.stop,
        final=distances[search.point],
    )


def _shown(value: float | None) -> str:
    return "not ranked" if value is None else f"{value:.4g}"


def _say(text: str) -> None:
    """A line of the refinement's progress on stderr."""
    typer.echo(terminal(text, limit=None), err=True)
    sys.stderr.flush()
