"""``cirl-study calibrate --refine``: the coordinate search around the nearest universe, each
probe played as a run of its own (``docs/multiverse.md``, *Refinement*).

The settings searched are the nearest universe's numeric ones (:data:`REFINED_AXES`), the
eta of each feature level among them (:func:`eta_setting`): at a point, a feature level's eta
is fixed (a number) or left to the universe's cross-validation (``None``, written
:data:`~cirl_study.study.spec.CROSS_VALIDATED`), whose choice at that point is where its
neighbours are taken from (:attr:`~cirl_study.analysis.calibration.refine.SearchAxis.chosen`).

:func:`refine` joins the three steps: the search (:func:`cirl_study.analysis.calibration.refine.
coordinate_search`) asks for a point's distance; the point is played as a probe
(:func:`cirl_study.study.probes.play_probe`), read as any run is analysed
(:func:`cirl_study.analysis.reading.read_for_analysis`) and measured as every universe of the
run is (:func:`cirl_study.analysis.calibration.results.universe_distance`). Each probe's progress
goes to stderr as a run's does.
"""

from __future__ import annotations

import math
import sys
from collections import defaultdict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import typer

from cirl_study.analysis.calibration.refine import (
    FIRST_STEP,
    MIN_STEP,
    Evaluation,
    Point,
    SearchAxis,
    coordinate_search,
)
from cirl_study.analysis.calibration.results import universe_distance
from cirl_study.analysis.reading import read_for_analysis
from cirl_study.analysis.results.types import (
    CalibrationResults,
    CellComparison,
    CellMove,
    Refinement,
    RefinementProbe,
    TargetCell,
    UniverseDistance,
)
from cirl_study.commands.progress import progress_bar
from cirl_study.escape import terminal
from cirl_study.record import MAIN, TrialRow
from cirl_study.study.engines import Engine
from cirl_study.study.multiverse import universes
from cirl_study.study.probes import play_probe
from cirl_study.study.spec import AXES, CROSS_VALIDATED, ETA, Pipeline, Universe

REFINED_AXES = ("sigma", "eta", "ascent_steps", "learning_rate")
"""The numeric settings the refinement moves, in the order a sweep visits them: the RBF width,
the eta of each feature level a target cell of a human with a trade-off has (one setting per
level, :func:`eta_setting`), and for the gradient-ascent robot its step budget (an integer) and
step size. The horizon and lambda, which the paper states, stay as the nearest universe has
them."""

INTEGER_AXES = frozenset({"ascent_steps"})
"""The refined settings whose values are integers."""


def eta_setting(num_features: int) -> str:
    """The name of the searched setting of the eta at ``num_features`` features (``eta_k3``)."""
    return f"eta_k{num_features}"


@dataclass(frozen=True)
class _Setting:
    """A searched setting: its name, the axis of :data:`~cirl_study.study.spec.AXES` it
    moves, and for the eta the feature level (``None`` for the other axes)."""

    name: str
    axis: str
    level: int | None = None

    def of(self, universe: Universe) -> Any:
        """Its value in ``universe`` (an eta left to cross-validation: ``None``)."""
        if self.level is None:
            return getattr(universe, self.axis)
        return universe.fixed_eta(self.level)


def searched_settings(
    pipeline: Pipeline, start: Universe, target: Sequence[TargetCell]
) -> list[_Setting]:
    """The settings the refinement from ``start`` moves (:data:`REFINED_AXES`): those
    ``start`` has, and the eta of each feature level at which the target has a cell of a
    human with a trade-off (elsewhere eta moves no target cell)."""
    taught = {c.num_features for c in target if c.human in pipeline.humans_with_eta}
    found = []
    for axis in REFINED_AXES:
        if axis == "eta":
            levels = [k for k in pipeline.game.feature_levels if k in taught]
            found += [_Setting(eta_setting(k), axis, k) for k in levels]
        elif getattr(start, axis) is not None:
            found.append(_Setting(axis, axis))
    return found


def played_etas(trials: Sequence[TrialRow], human: str) -> dict[str | None, dict[int, float]]:
    """Per universe id of the ``main`` trials among ``trials``, the eta ``human`` played at
    each feature level."""
    etas: dict[str | None, dict[int, float]] = defaultdict(dict)
    for row in trials:
        if row.block == MAIN and row.human == human and row.eta is not None:
            etas[row.universe][row.num_features] = row.eta
    return etas


def refine(
    pipeline: Pipeline,
    results: CalibrationResults,
    target: Sequence[TargetCell],
    trials: Sequence[TrialRow],
    *,
    probes: Path,
    engine: Callable[[], Engine],
    max_probes: int,
) -> Refinement:
    """The refinement of the calibration ``results`` of the multiverse run of ``pipeline``
    (its ``trials``): the coordinate search from its nearest universe over the settings of
    :func:`searched_settings`, its probes played below ``probes`` on a fresh ``engine()``
    each, at most ``max_probes`` of them.

    Raises:
        UserError: a probe cannot be played (:func:`~cirl_study.study.probes.play_probe`)
            or its logs do not read as a complete run.
    """
    nearest = results.universes[0]
    of_run = {u.id: u for u in universes(pipeline)}
    start = of_run[nearest.id]
    searched = searched_settings(pipeline, start, target)
    levels = pipeline.game.feature_levels
    teacher = next(iter(pipeline.humans_with_eta), None)
    chosen_at: dict[Point, dict[int, float]] = {}

    def universe_at(point: Point) -> Universe:
        fixed = dict(start.eta or ())
        moved: dict[str, Any] = {}
        for setting, value in zip(searched, point, strict=True):
            if setting.level is None:
                moved[setting.axis] = value
            elif value is None:
                fixed.pop(setting.level, None)
            else:
                fixed[setting.level] = value
        eta = tuple(sorted(fixed.items())) or None
        return replace(start, **moved, eta=eta).fitted(pipeline.gradient_ascent, levels)

    def point_of(universe: Universe) -> Point:
        return tuple(setting.of(universe) for setting in searched)

    def search_axis(setting: _Setting) -> SearchAxis:
        if setting.level is None:
            valid = AXES[setting.axis].levels(pipeline.game)[0]
            return SearchAxis(setting.name, setting.axis in INTEGER_AXES, valid)
        return SearchAxis(
            setting.name,
            False,
            lambda v: ETA.low <= v <= ETA.high,
            chosen=lambda point, k=setting.level: chosen_at[point][k],
        )

    measured = {u.id: u for u in results.universes}
    distances: dict[Point, UniverseDistance] = {}
    run_etas = played_etas(trials, teacher) if teacher is not None else {}
    for universe in of_run.values():
        point = point_of(universe)
        if universe_at(point) == universe:
            distances[point] = measured[universe.id]
            chosen_at[point] = run_etas.get(universe.played.id, {})
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
        if teacher is not None:
            chosen_at[point] = played_etas(analysed.trials, teacher)[universe.played.id]
        _say(
            f"probe {count}: D = {_shown(found.mean_squared_log_ratio)} "
            f"({sources[point]} in {probe.directory})"
        )
        return found.mean_squared_log_ratio

    search = coordinate_search(
        point_of(start),
        [search_axis(setting) for setting in searched],
        distance,
        known={point: d.mean_squared_log_ratio for point, d in distances.items()},
        max_probes=max_probes,
    )
    names = [setting.name for setting in searched]

    def written(point: Point) -> dict[str, Any]:
        return {
            name: CROSS_VALIDATED if value is None else value
            for name, value in zip(names, point, strict=True)
        }

    rows = [
        RefinementProbe(
            id=distances[e.point].id,
            settings=written(e.point),
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
        start_settings=written(point_of(start)),
        final_settings=written(search.point),
        final=distances[search.point],
        moves=cell_moves(search.evaluations, distances, names, target, written),
    )


def cell_moves(
    evaluations: Sequence[Evaluation],
    distances: Mapping[Point, UniverseDistance],
    names: Sequence[str],
    target: Sequence[TargetCell],
    written: Callable[[Point], dict[str, Any]],
) -> list[CellMove]:
    """Per searched setting (``names``, in order) and target cell (in the target's order),
    the point of that setting's moves that moved the cell's mean most: the largest
    :math:`|\\ln(\\bar y / \\bar y_o)|` over the ``evaluations`` along the setting whose
    point and origin (``distances``) both measure the cell (a setting or cell without such a
    point is left out)."""
    moves = []
    for name in names:
        along = [e for e in evaluations if e.axis == name]
        for cell in target:
            largest: tuple[float, Evaluation, CellComparison] | None = None
            points = 0
            for e in along:
                here = _comparison(distances[e.point], cell)
                there = _comparison(distances[e.origin], cell)
                if here is None or there is None:
                    continue
                points += 1
                change = math.log(here.measured / there.measured)
                if largest is None or abs(change) > abs(largest[0]):
                    largest = (change, e, here)
            if largest is None:
                continue
            change, e, here = largest
            moves.append(
                CellMove(
                    setting=name,
                    measure=cell.measure,
                    num_features=cell.num_features,
                    human=cell.human,
                    robot=here.robot,
                    points=points,
                    log_ratio=change,
                    origin=written(e.origin)[name],
                    value=written(e.point)[name],
                )
            )
    return moves


def _comparison(distance: UniverseDistance, cell: TargetCell) -> CellComparison | None:
    """The universe's measurement of the target ``cell`` (``None``: it lacks it)."""
    for compared in distance.cells:
        same = (compared.measure, compared.num_features, compared.human) == (
            cell.measure,
            cell.num_features,
            cell.human,
        )
        if same and cell.robot in (None, compared.robot):
            return compared
    return None


def _shown(value: float | None) -> str:
    return "not ranked" if value is None else f"{value:.4g}"


def _say(text: str) -> None:
    """A line of the refinement's progress on stderr."""
    typer.echo(terminal(text, limit=None), err=True)
    sys.stderr.flush()
