"""The report of a calibration: ``report.md``, ``results.json``, ``universes.csv``, the figure.

:func:`write_calibration_report` writes what
:func:`cirl_study.analysis.calibration.results.calibrate` found: the universes nearest the target
with their settings, the search's path and the refined universe beside the nearest (with
``--refine``), the target beside the nearest universes' measurements cell by cell, the paper's
claims in the nearest universe, and per axis the best level and how far the distance moves
(``docs/multiverse.md``, *Calibration*).
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

FIGURE_NAME = "calibration.png"
"""Target against measured, per cell, for the nearest universes."""

SHOWN = 5
"""Universes shown in the report's tables and figure, nearest first."""


def _label(universe: UniverseDistance) -> str:
    return escape.markdown(universe.id) if universe.id else "the run"


def _header(results: CalibrationResults) -> list[str]:
    ranked = [u for u in results.universes if u.mean_squared_log_ratio is not None]
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
    ranked = [u for u in results.universes if u.mean_squared_log_ratio is not None][:SHOWN]
    varied = [axis.axis for axis in results.axes]
    rows = [
        [
            str(rank),
            _label(u),
            number(u.mean_squared_log_ratio),
            number(math.exp(math.sqrt(u.mean_squared_log_ratio))),
            number(u.chi_square) + (f" ({u.chi_square_df})" if u.chi_square_df else ""),
            p_text(u.log10_p),
            *[escape.markdown(level_label(u.settings[axis])) for axis in varied],
        ]
        for rank, u in enumerate(ranked, start=1)
    ]
    return [
        "## The nearest universes",
        "",
        "Distance `D`: the mean over the target's cells of the squared log ratio of measured to "
        "target; `e^sqrt(D)`: the typical factor between them; the chi-square on the log scale "
        "(its degrees of freedom: the cells with an uncertainty) and its p, where the target "
        "gives uncertainties.",
        "",
        table(
            ["rank", "universe", "D", "e^sqrt(D)", "chi-square (df)", "p", *varied],
            rows,
            [True, False, True, True, True, True, *[False] * len(varied)],
        ),
        "",
    ]


def _cells(results: CalibrationResults) -> list[str]:
    ranked = [u for u in results.universes if u.mean_squared_log_ratio is not None][:3]
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
        "Each target cell beside the nearest universes' means (in brackets: measured over target).",
        "",
        table(header, rows, [False, True, False, True, *[True] * len(ranked)]),
        "",
        f"![Target against measured]({FIGURE_NAME})",
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
            escape.markdown(level_label(level.level))
            + (" (best)" if level.level == axis.best else ""),
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
        "levels.",
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
            *[escape.markdown(level_label(row.settings[axis])) for axis in refinement.axes],
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
            escape.markdown(level_label(nearest.settings.get(axis))),
            escape.markdown(level_label(final.settings.get(axis)))
            + (" (moved)" if nearest.settings.get(axis) != final.settings.get(axis) else ""),
        ]
        for axis in final.settings
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
    ]


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
    """``universes.csv``: one row per universe, its settings, distance and chi-square."""
    return pd.DataFrame(
        [
            {
                "universe": u.id,
                **{k: level_label(v) for k, v in u.settings.items()},
                "mean_squared_log_ratio": u.mean_squared_log_ratio,
                "chi_square": u.chi_square,
                "chi_square_df": u.chi_square_df,
                "log10_p": u.log10_p,
                "missing": "; ".join(u.missing),
            }
            for u in results.universes
        ]
    )


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
    """The figure's points: per shown universe (by rank) and cell, target and measured."""
    ranked = [u for u in results.universes if u.mean_squared_log_ratio is not None][:SHOWN]
    return pd.DataFrame(
        [
            {
                "rank": rank,
                "universe": u.id or "the run",
                "measure": c.measure,
                "target": c.target,
                "measured": c.measured,
            }
            for rank, u in enumerate(ranked, start=1)
            for c in u.cells
        ]
    )


def write_calibration_report(
    results: CalibrationResults, out_dir: Path | str, *, provenance: Mapping[str, Any] | None
) -> None:
    """Write the calibration ``results`` into ``out_dir``: ``report.md``, ``results.json``,
    ``universes.csv`` (and of a refinement ``probes.csv``), the figure (PNG and SVG) and
    ``provenance.json`` (if given).

    Raises:
        UserError: the report cannot be written.
    """
    write_report_directory(
        out_dir,
        markdown=render_markdown(results),
        results=msgspec.to_builtins(results),
        tables={
            "universes.csv": universe_table(results),
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
