"""The report of a calibration: ``report.md``, ``results.json``, ``universes.csv``,
``cells.csv``, the figure.

:func:`write_calibration_report` writes what
:func:`cirl_study.analysis.calibration.results.calibrate` found: the universes nearest the target
with their settings, the search's path and the refined universe beside the nearest (with
``--refine``), the target beside the nearest universes' measurements cell by cell (and every
universe's in ``cells.csv``), the paper's claims in the nearest universe, and per axis the best
level and how far the distance moves (``docs/multiverse.md``, *Calibration*). A setting a
universe's robot lacks reads ``n/a`` (:data:`NOT_APPLICABLE`); the table and the figure name
the nearest universes ``#1``, ``#2``, ... by rank, which a legend maps to their ids and the
settings they differ in (:func:`short_labels`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import msgspec
import pandas as pd

from cirl_study import escape
from cirl_study.analysis.multiverse.results import level_label
from cirl_study.analysis.report import figures
from cirl_study.analysis.report.markdown import document, measure_name, number, p_text, table
from cirl_study.analysis.report.output import write_report_directory
from cirl_study.analysis.results.types import CalibrationResults, Refinement, UniverseDistance
from cirl_study.study.spec import AXES

FIGURE_NAME = "calibration.png"
"""Target against measured, per cell, for the nearest universes."""

SHOWN = 5
"""Universes shown in the report's tables and figure, nearest first."""

COMPARED = 3
"""Universes beside the target in the report's table of cells, nearest first."""

NOT_APPLICABLE = "n/a"
"""A setting's level where the universe's robot lacks the setting (``None`` in the results)."""

THE_RUN = "the run"
"""The label of the one universe of a single study (its id is empty)."""


def _label(universe: UniverseDistance) -> str:
    return escape.markdown(universe.id) if universe.id else THE_RUN


def _optional(axis: str | None) -> bool:
    """Whether ``axis`` is an optional axis (:attr:`~cirl_study.study.spec.Axis.optional`),
    whose ``None`` is its default, not a setting that does not apply."""
    return axis in AXES and AXES[axis].optional


def _setting(value: Any, axis: str | None = None) -> str:
    """A setting's level in a table of ``report.md``: code, or a plain ``n/a``."""
    if value is None and not _optional(axis):
        return NOT_APPLICABLE
    return escape.markdown(level_label(value, axis))


def _not_applicable(levels: list[tuple[str, Any]]) -> str:
    """The sentence that says what ``n/a`` means, where ``levels`` (``(axis, level)``) hold
    one."""
    if all(level is not None or _optional(axis) for axis, level in levels):
        return ""
    return f" {NOT_APPLICABLE}: the setting does not apply (the universe's robot lacks it)."


def _ranked(results: CalibrationResults) -> list[UniverseDistance]:
    """The ranked universes, nearest first."""
    return [u for u in results.universes if u.mean_squared_log_ratio is not None]


def short_labels(universes: list[UniverseDistance]) -> list[str]:
    """A short label per universe that tells ``universes`` apart: its levels, as its id
    writes them (``sigma=1.5,robot=map``), of the settings whose levels differ among them. A
    setting that only some universes have (the gradient-ascent robot's, or an analysis-only
    reading at its default in others) counts where it has levels that differ, or else where
    the labels need it to differ; where a label shows a setting of its robot alone
    (``ga_steps=30``), it leaves the robot out. A universe with no such level is labelled by
    its id, a single study's universe (whose id is empty) ``the run``.

    Examples:
        >>> from cirl_study.analysis.results.types import UniverseDistance
        >>> def universe(**settings):
        ...     return UniverseDistance(
        ...         id=",".join(f"{k}={v}" for k, v in settings.items()), base=False,
        ...         settings={"centers": "lattice", **settings}, cells=[],
        ...         mean_squared_log_ratio=None, chi_square=None, chi_square_df=0, p=None,
        ...         log10_p=None, missing=[])
        >>> short_labels([universe(sigma=0.75, robot="map", ascent_steps=None),
        ...               universe(sigma=1.5, robot="gradient_ascent", ascent_steps=30)])
        ['sigma=0.75,robot=map', 'sigma=1.5,robot=gradient_ascent']
        >>> short_labels([universe(robot="map"), universe(robot="gradient_ascent", ascent_steps=30),
        ...               universe(robot="gradient_ascent", ascent_steps=300)])
        ['robot=map', 'ga_steps=30', 'ga_steps=300']
        >>> short_labels([universe(sigma=1.5), universe(sigma=1.5, regret="estimate")])
        ['sigma=1.5', 'regret=estimate']
    """

    def levels(axis: str, where: bool) -> set[Any]:
        return {
            u.settings.get(axis) for u in universes if where or u.settings.get(axis) is not None
        }

    def label(u: UniverseDistance, axes: list[str]) -> str:
        shown = [axis for axis in axes if u.settings.get(axis) is not None]
        if any(AXES[axis].nested for axis in shown):  # a setting of its robot alone names it
            shown = [axis for axis in shown if axis != "robot"]
        return ",".join(f"{AXES[axis].label}={level_label(u.settings[axis])}" for axis in shown)

    def labels(axes: list[str]) -> list[str]:
        return [label(u, axes) for u in universes]

    found = labels([axis for axis in AXES if len(levels(axis, False)) > 1])
    if len(set(found)) < len(found):
        found = labels([axis for axis in AXES if len(levels(axis, True)) > 1])
    if len(set(found)) < len(found):
        found = [""] * len(universes)
    return [label or u.id or THE_RUN for label, u in zip(found, universes, strict=True)]


def _header(results: CalibrationResults) -> list[str]:
    ranked = _ranked(results)
    nearest = ranked[0]
    factor = math.exp(math.sqrt(nearest.mean_squared_log_ratio))
    lines = [
        f"# Calibration: {escape.markdown(results.pipeline)} against "
        f"{escape.markdown(results.target_file)}",
        "",
        f"{len(results.target)} target cells (`{results.target_sha256[:12]}`), "
        f"{len(ranked)} universe(s) ranked by the mean squared log ratio of their cell means "
        "to the target (`docs/multiverse.md`, *Calibration*). The nearest is "
        f"{_label(nearest)}: its cell means lie within a typical factor of {factor:.3g} of "
        "the target.",
        "",
    ]
    unranked = [u for u in results.universes if u.mean_squared_log_ratio is None]
    if unranked:
        lines += [
            f"Not ranked: {len(unranked)} universe(s), e.g. {_label(unranked[0])}, which "
            f"{escape.markdown(unranked[0].missing[0])}.",
            "",
        ]
    return lines


def _nearest(results: CalibrationResults) -> list[str]:
    ranked = _ranked(results)[:SHOWN]
    varied = [axis.axis for axis in results.axes]
    rows = [
        [
            str(rank),
            _label(u),
            number(u.mean_squared_log_ratio),
            number(math.exp(math.sqrt(u.mean_squared_log_ratio))),
            number(u.chi_square) + (f" ({u.chi_square_df})" if u.chi_square_df else ""),
            p_text(u.log10_p),
            *[_setting(u.settings.get(axis), axis) for axis in varied],
        ]
        for rank, u in enumerate(ranked, start=1)
    ]
    return [
        "## The nearest universes",
        "",
        "Distance `D`: the mean over the target's cells of the squared log ratio of measured to "
        "target; `e^sqrt(D)`: the typical factor between them; the chi-square on the log scale "
        "(its degrees of freedom: the cells with an uncertainty) and its p, where the target "
        "gives uncertainties."
        + _not_applicable([(axis, u.settings.get(axis)) for u in ranked for axis in varied]),
        "",
        table(
            ["rank", "universe", "D", "e^sqrt(D)", "chi-square (df)", "p", *varied],
            rows,
            [True, False, True, True, True, True, *[False] * len(varied)],
        ),
        "",
    ]


def _cells(results: CalibrationResults) -> list[str]:
    ranked = _ranked(results)[:COMPARED]
    header = ["measure", "K", "human", "target"]
    header += [f"#{rank} measured" for rank in range(1, len(ranked) + 1)]
    rows = []
    for position, cell in enumerate(results.target):
        compared = [u.cells[position] for u in ranked]
        rows.append(
            [
                measure_name(cell.measure),
                str(cell.num_features),
                escape.markdown(cell.human + (f" ({cell.robot})" if cell.robot else "")),
                number(cell.value),
                *[f"{number(c.measured)} (x{math.exp(c.log_ratio):.3g})" for c in compared],
            ]
        )
    return [
        "## Target against measured",
        "",
        "Each target cell beside the nearest universes' means (in brackets: measured over target); "
        "every universe's, with the number of subjects, is in [`cells.csv`](cells.csv).",
        "",
        table(header, rows, [False, True, False, True, *[True] * len(ranked)]),
        "",
        f"![Target against measured]({FIGURE_NAME})",
        "",
        *_legend(results),
    ]


def _legend(results: CalibrationResults) -> list[str]:
    """Which universe each ``#k`` of the table and the figure is: its rank, the settings it
    differs in from the others shown (:func:`short_labels`) and its id."""
    shown = _ranked(results)[:SHOWN]
    rows = [
        [f"#{rank}", escape.markdown(label), _label(u)]
        for rank, (u, label) in enumerate(zip(shown, short_labels(shown), strict=True), start=1)
    ]
    return [
        "In the table and the figure, `#k` is the universe of rank k:",
        "",
        table(["#", "differs in", "universe"], rows, [False, False, False]),
        "",
    ]


def _claims(results: CalibrationResults) -> list[str]:
    rows = [
        [
            f"`{claim.id}`",
            claim.claim,
            claim.measurement,
            "reproduced" if claim.reproduced else "not reproduced",
        ]
        for claim in results.nearest_claims
    ]
    return [
        "## The paper's claims in the nearest universe",
        "",
        "Judged with the paper report's own rules on the nearest universe's trials.",
        "",
        table(["claim", "the paper says", "we measured", "verdict"], rows, [False] * 4),
        "",
    ]


def _axes(results: CalibrationResults) -> list[str]:
    if not results.axes:
        return []
    rows = [
        [
            escape.markdown(axis.axis),
            _setting(level.level, axis.axis) + (" (best)" if level.level == axis.best else ""),
            str(level.universes),
            number(level.nearest_distance),
            number(level.median_distance),
            number(axis.spread),
        ]
        for axis in results.axes
        for level in axis.levels
    ]
    return [
        "## What moves the distance",
        "",
        "Per setting that varies among the ranked universes, each level's nearest and median "
        "distance; the spread is how far the nearest distance moves across the setting's "
        "levels."
        + _not_applicable(
            [(axis.axis, level.level) for axis in results.axes for level in axis.levels]
        ),
        "",
        table(
            ["setting", "level", "universes", "nearest D", "median D", "spread"],
            rows,
            [False, False, True, True, True, True],
        ),
        "",
    ]


STOPS = {
    "exact": "it reached a distance of 0, which nothing is nearer than",
    "converged": "no neighbour at the smallest step, on any setting, was nearer",
    "budget": "it had played its budget of probes",
}
"""Why a refinement stopped, by its ``stop``."""


def _refinement(results: CalibrationResults) -> list[str]:
    refinement = results.refinement
    if refinement is None:
        return []
    nearest, final = results.universes[0], refinement.final
    probes = refinement.played + refinement.reused
    of_run = len(refinement.probes) - probes
    path = [
        [
            str(index),
            escape.markdown(row.axis),
            f"x{row.step:.3g}",
            *[_setting(row.settings[axis]) for axis in refinement.axes],
            row.source,
            number(row.mean_squared_log_ratio),
            number(row.chi_square) + (f" ({row.chi_square_df})" if row.chi_square_df else ""),
            p_text(row.log10_p),
            "yes" if row.accepted else "",
        ]
        for index, row in enumerate(refinement.probes, start=1)
    ]
    beside = [
        [
            escape.markdown(axis),
            _setting(nearest.settings.get(axis), axis),
            _setting(final.settings.get(axis), axis)
            + (" (moved)" if nearest.settings.get(axis) != final.settings.get(axis) else ""),
        ]
        for axis in AXES
        if nearest.settings.get(axis) is not None or final.settings.get(axis) is not None
    ]
    beside += [
        ["D", number(nearest.mean_squared_log_ratio), number(final.mean_squared_log_ratio)],
        ["p", p_text(nearest.log10_p), p_text(final.log10_p)],
    ]
    axes = ", ".join(f"`{axis}`" for axis in refinement.axes)
    return [
        "## Refinement",
        "",
        f"A coordinate search from the nearest universe over {axes} (`docs/multiverse.md`, "
        "*Refinement*): each sweep takes every setting in turn, measures its value divided "
        "and multiplied by the step factor, and moves to the nearer of the two when it lowers "
        f"`D`; a sweep that does not move shrinks the step, from x{refinement.first_step:.3g} "
        f"to its square root, down to x{refinement.min_step:.3g}. It measured "
        f"{len(refinement.probes)} point(s): {probes} probe(s), each a universe played as a "
        f"run of its own ({refinement.played} played now, {refinement.reused} reused; at most "
        f"{refinement.max_probes}), and {of_run} universe(s) of the run; it stopped because "
        f"{STOPS[refinement.stop]}.",
        "",
        table(
            [
                "#",
                "setting",
                "step",
                *refinement.axes,
                "source",
                "D",
                "chi-square (df)",
                "p",
                "moved to",
            ],
            path,
            [True, False, True, *[True] * len(refinement.axes), False, True, True, True, False],
        ),  # fmt: skip
        "",
        f"The refined universe {_label(final)} beside the nearest universe of the run:",
        "",
        table(["setting", "nearest of the run", "refined"], beside, [False, True, True]),
        "",
        *_moves(results),
    ]


def _moves(results: CalibrationResults) -> list[str]:
    """Which target cells each searched setting moves: per cell, the largest factor by which
    one move of each setting changed its mean."""
    refinement = results.refinement
    if refinement is None or not refinement.moves:
        return []
    moved = {(m.setting, m.measure, m.num_features, m.human): m.log_ratio for m in refinement.moves}
    rows = [
        [
            measure_name(cell.measure),
            str(cell.num_features),
            escape.markdown(cell.human + (f" ({cell.robot})" if cell.robot else "")),
            *[
                _factor(moved.get((axis, cell.measure, cell.num_features, cell.human)))
                for axis in refinement.axes
            ],
        ]
        for cell in results.target
    ]
    return [
        "Which cells each setting moves: per target cell and searched setting, the factor by "
        "which the setting's move that changed the cell's mean most multiplied it (measured "
        "over the point the move started from; every move is in `results.json`, "
        "`refinement.moves`).",
        "",
        table(
            ["measure", "K", "human", *refinement.axes],
            rows,
            [False, True, False, *[True] * len(refinement.axes)],
        ),
        "",
    ]


def _factor(log_ratio: float | None) -> str:
    """``x1.52``: a change of a mean on the log scale as a factor (``–``: not measured)."""
    return "–" if log_ratio is None else f"x{math.exp(log_ratio):.3g}"


def render_markdown(results: CalibrationResults) -> str:
    """``report.md`` of a calibration."""
    return document(
        [
            _header(results),
            _nearest(results),
            _refinement(results),
            _cells(results),
            _claims(results),
            _axes(results),
        ]
    )


def universe_table(results: CalibrationResults) -> pd.DataFrame:
    """``universes.csv``: one row per universe, its settings (empty where its robot lacks the
    setting), distance and chi-square."""
    return pd.DataFrame(
        [
            {
                "universe": u.id,
                **{k: None if v is None else level_label(v) for k, v in u.settings.items()},
                "mean_squared_log_ratio": u.mean_squared_log_ratio,
                "chi_square": u.chi_square,
                "chi_square_df": u.chi_square_df,
                "log10_p": u.log10_p,
                "missing": "; ".join(u.missing),
            }
            for u in results.universes
        ]
    )


CELL_COLUMNS = [
    "universe",
    "rank",
    "measure",
    "num_features",
    "human",
    "robot",
    "n",
    "mean",
    "target",
    "log_ratio",
    "measured_log_se",
    "target_log_se",
]
"""The columns of ``cells.csv`` (:func:`cell_table`)."""


def cell_table(results: CalibrationResults) -> pd.DataFrame:
    """``cells.csv``: every universe's measurement of every target cell it has, a row each:
    the universe (empty: a single study) and its ``rank`` (empty: not ranked), the cell, the
    ``n`` subjects and their ``mean`` beside the ``target`` value, ``log_ratio``
    (``ln(mean / target)``) and the standard errors on the log scale; then, of a refinement,
    the refined universe's (rank empty) where it is not a universe of the run. The
    universes in the order of ``results.json``, nearest first."""
    ranks = {u.id: rank for rank, u in enumerate(_ranked(results), start=1)}
    universes = list(results.universes)
    refinement = results.refinement
    if refinement is not None and refinement.final.id not in {u.id for u in universes}:
        universes.append(refinement.final)
    rows = [
        {
            "universe": u.id,
            "rank": ranks.get(u.id),
            "measure": c.measure,
            "num_features": c.num_features,
            "human": c.human,
            "robot": c.robot,
            "n": c.n,
            "mean": c.measured,
            "target": c.target,
            "log_ratio": c.log_ratio,
            "measured_log_se": c.measured_log_se,
            "target_log_se": c.target_log_se,
        }
        for u in universes
        for c in u.cells
    ]
    return pd.DataFrame(rows, columns=CELL_COLUMNS).astype({"rank": "Int64"})


def probe_table(refinement: Refinement) -> pd.DataFrame:
    """``probes.csv`` of a refined calibration: every point the search measured, in order."""
    return pd.DataFrame(
        [
            {
                "universe": row.id,
                **{axis: row.settings[axis] for axis in refinement.axes},
                "axis": row.axis,
                "step": row.step,
                "source": row.source,
                "mean_squared_log_ratio": row.mean_squared_log_ratio,
                "chi_square": row.chi_square,
                "chi_square_df": row.chi_square_df,
                "log10_p": row.log10_p,
                "accepted": row.accepted,
            }
            for row in refinement.probes
        ]
    )


def comparison_frame(results: CalibrationResults) -> pd.DataFrame:
    """The figure's points: per shown universe (by rank, with its short label,
    :func:`short_labels`) and cell, target and measured."""
    shown = _ranked(results)[:SHOWN]
    return pd.DataFrame(
        [
            {
                "rank": rank,
                "universe": label,
                "measure": c.measure,
                "target": c.target,
                "measured": c.measured,
            }
            for rank, (u, label) in enumerate(zip(shown, short_labels(shown), strict=True), 1)
            for c in u.cells
        ]
    )


def write_calibration_report(
    results: CalibrationResults, out_dir: Path | str, *, provenance: Mapping[str, Any] | None
) -> None:
    """Write the calibration ``results`` into ``out_dir``: ``report.md``, ``results.json``,
    ``universes.csv``, ``cells.csv`` (and of a refinement ``probes.csv``), the figure (PNG
    and SVG) and ``provenance.json`` (if given).

    Raises:
        UserError: the report cannot be written.
    """
    write_report_directory(
        out_dir,
        markdown=render_markdown(results),
        results=msgspec.to_builtins(results),
        tables={
            "universes.csv": universe_table(results),
            "cells.csv": cell_table(results),
            **(
                {}
                if results.refinement is None
                else {"probes.csv": probe_table(results.refinement)}
            ),
        },
        figures=figures.draw_all(
            {FIGURE_NAME: (figures.calibration_plot, (comparison_frame(results),))}
        ),
        provenance=provenance,
    )
