"""Which universe made the published numbers: a run's cell means held against a target table.

A *target* is a CSV of published cell means (:func:`read_target`): per row a ``measure``, a
``num_features`` and a ``human``, optionally a ``robot``, the ``value``, and
optionally its uncertainty, as a standard error ``se`` or a 95% interval ``ci95_low``,
``ci95_high``. :func:`calibrate` compares every universe of a multiverse run (a single study
is one universe) with it, cell by cell, on the log scale, where a factor of 2 is the same
distance whether the cell's mean is 0.05 or 500. With :math:`t_c` the target of cell
:math:`c`, :math:`\\bar y_c` the universe's mean over its ``n_c`` ``main``-block subjects and
:math:`r_c = \\ln(\\bar y_c / t_c)`:

* the **mean squared log ratio** over the :math:`C` target cells,
  :math:`D = \\frac1C \\sum_c r_c^2`, ranks the universes (nearest first; :math:`e^{\\sqrt D}`
  is the typical factor between measured and target);
* where the target gives uncertainties, the **chi-square on the log scale**
  :math:`\\chi^2 = \\sum_c r_c^2 / (s_{t,c}^2 + s_{y,c}^2)` over those cells, with
  :math:`s_{t,c}` the target's standard error of :math:`\\ln t_c` (``se / value``, or
  :math:`(\\ln hi - \\ln lo) / (2 \\cdot 1.959964)` from a positive interval) and
  :math:`s_{y,c} = s_c / (\\bar y_c \\sqrt{n_c})` the measurement's (delta method), tested
  against :math:`\\chi^2` with as many degrees of freedom as cells: a small ``p`` says the
  universe is farther from the target than both uncertainties explain.

A target row without ``robot`` is compared with each universe's reference robot (a
multiverse universe's one robot). Per axis of a multiverse, the level of the nearest universe
and how far the nearest distance moves across levels say which settings matter; the paper's
claims are judged in the nearest universe with the paper report's own rules.
"""

from __future__ import annotations

import csv
import hashlib
import io
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from cirl_study.analysis.multiverse.results import PAPER_CLAIMS, settings, universe_trials
from cirl_study.analysis.results.study import analyse, with_claims
from cirl_study.analysis.results.types import (
    AxisDistance,
    CalibrationResults,
    CellComparison,
    ClaimRow,
    LevelDistance,
    TargetCell,
    UniverseDistance,
)
from cirl_study.analysis.statistics.tails import chi2_tail
from cirl_study.analysis.table import trial_table
from cirl_study.errors import UserError
from cirl_study.escape import terminal
from cirl_study.files import read_regular_file
from cirl_study.measure_registry import MEASURES
from cirl_study.record import MAIN, TrialRow
from cirl_study.study.multiverse import base_universe, universe_pipeline, universes
from cirl_study.study.spec import AXES, Pipeline, Universe

MAX_TARGET_BYTES = 1 << 20
"""Largest target file read."""

TARGET_COLUMNS = ("measure", "num_features", "human", "robot", "value", "se", "ci95_low",
                  "ci95_high")  # fmt: skip
"""The columns a target may have; ``measure``, ``num_features``, ``human`` and ``value``
are required, the others optional (and may be left empty in a row)."""

Z_95 = 1.959963984540054
"""The standard normal quantile of 0.975: a 95% interval is :math:`\\pm` this many standard
errors."""


def read_target(path: Path) -> tuple[list[TargetCell], str]:
    """The cells of the target CSV at ``path`` and the SHA-256 of its bytes.

    Raises:
        UserError: the file cannot be read, is not UTF-8 CSV with a header of
            :data:`TARGET_COLUMNS` (required ones present, none twice), or a row is not a cell: an
            unknown measure, a feature count that is not a positive integer, an empty
            human, a value that is not a positive number (distances are on the log scale),
            an uncertainty that is not positive, an interval that does not hold its value,
            or a cell given twice. One line, naming the file and the row.
    """
    label = terminal(str(path))
    data = read_regular_file(path, MAX_TARGET_BYTES)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise UserError(f"{label}: not UTF-8 text") from None
    reader = csv.DictReader(io.StringIO(text, newline=""))
    header = reader.fieldnames or []
    repeated = [name for position, name in enumerate(header) if name in header[:position]]
    if repeated:
        raise UserError(f"{label}: names the column {terminal(repeated[0])} twice")
    unknown = [name for name in header if name not in TARGET_COLUMNS]
    if unknown:
        raise UserError(
            f"{label}: column {terminal(unknown[0])} is not one of {', '.join(TARGET_COLUMNS)}"
        )
    for required in ("measure", "num_features", "human", "value"):
        if required not in header:
            raise UserError(f"{label}: has no column {required}")
    cells: list[TargetCell] = []
    seen: set[tuple[str, int, str, str | None]] = set()
    for line, row in enumerate(reader, start=2):
        cell = _target_cell(row, f"{label} line {line}")
        key = (cell.measure, cell.num_features, cell.human, cell.robot)
        if key in seen:
            raise UserError(f"{label} line {line}: repeats the cell of an earlier line")
        seen.add(key)
        cells.append(cell)
    if not cells:
        raise UserError(f"{label}: holds no cell")
    return cells, hashlib.sha256(data).hexdigest()


def _target_cell(row: dict[str, str | None], where: str) -> TargetCell:
    """One row of a target as a :class:`TargetCell` (see :func:`read_target`)."""
    if None in row:
        raise UserError(f"{where}: has more fields than the header")
    field = {name: (value or "").strip() for name, value in row.items()}
    measure = field["measure"]
    if measure not in MEASURES:
        raise UserError(
            f"{where}: measure must be one of {', '.join(MEASURES)}, got {terminal(measure)}"
        )
    features = field["num_features"]
    if not features.isdigit() or int(features) < 1:
        raise UserError(
            f"{where}: num_features must be a positive integer, got {terminal(features)}"
        )
    if not field["human"]:
        raise UserError(f"{where}: human is empty")
    value = _positive(field["value"], "value", where)
    log_se = None
    if field.get("se"):
        log_se = _positive(field["se"], "se", where) / value
    low, high = field.get("ci95_low"), field.get("ci95_high")
    if low or high:
        if log_se is not None:
            raise UserError(f"{where}: gives both se and a 95% interval; give one")
        if not (low and high):
            raise UserError(f"{where}: a 95% interval needs both ci95_low and ci95_high")
        lo, hi = _number(low, "ci95_low", where), _number(high, "ci95_high", where)
        if not lo <= value <= hi or lo == hi:
            raise UserError(f"{where}: the 95% interval [{lo:g}, {hi:g}] must hold the value")
        log_se = (
            (math.log(hi) - math.log(lo)) / (2 * Z_95) if lo > 0 else (hi - lo) / (2 * Z_95) / value
        )
    return TargetCell(
        measure=measure,
        num_features=int(features),
        human=field["human"],
        robot=field.get("robot") or None,
        value=value,
        log_se=log_se,
    )


def _number(text: str, name: str, where: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise UserError(f"{where}: {name} must be a number, got {terminal(text)}") from None
    if not math.isfinite(value):
        raise UserError(f"{where}: {name} must be finite, got {terminal(text)}")
    return value


def _positive(text: str, name: str, where: str) -> float:
    value = _number(text, name, where)
    if value <= 0:
        raise UserError(f"{where}: {name} must be positive (distances are on the log scale)")
    return value


def calibrate(
    trials: Sequence[TrialRow],
    pipeline: Pipeline,
    target: Sequence[TargetCell],
    *,
    target_file: str,
    target_sha256: str,
    run_id: str | None,
) -> CalibrationResults:
    """Every universe of the run of ``pipeline`` (its ``trials``) against ``target`` (see the
    module docstring).

    Raises:
        UserError: no universe of the run measures one of the target's cells, or no universe
            can be ranked.
    """
    # Per universe: its study's pipeline and the rows it analyses (a single study's: all).
    if pipeline.multiverse is None:
        studies = {"": (pipeline, list(trials))}
        base = None
    else:
        studies = {
            u.id: (universe_pipeline(pipeline, u), rows)
            for u, rows in universe_trials(trials, pipeline).items()
        }
        base = base_universe(pipeline).id
    main = [r for _, rows in studies.values() for r in rows if r.block == MAIN]
    ranked = ranked_distances(cell_means(trial_table(main)), _settings(pipeline), target, base)
    return CalibrationResults(
        pipeline=pipeline.name,
        target_file=target_file,
        target_sha256=target_sha256,
        target=list(target),
        universes=ranked,
        axes=_axes([d for d in ranked if d.mean_squared_log_ratio is not None]),
        nearest_claims=_claims_in(*studies[ranked[0].id], paper_only=base is not None),
        run_id=run_id,
    )


def universe_distance(
    trials: Sequence[TrialRow],
    pipeline: Pipeline,
    universe: Universe,
    target: Sequence[TargetCell],
) -> UniverseDistance:
    """The distance to ``target`` of ``universe``, one of the multiverse ``pipeline``'s, on
    the run's ``trials``, measured as :func:`calibrate` measures each universe (a refinement's
    probe, :mod:`cirl_study.study.probes`); not the base universe's."""
    main = [r for r in universe_trials(trials, pipeline)[universe] if r.block == MAIN]
    means = cell_means(trial_table(main)).get(universe.id, {})
    reference = universe_pipeline(pipeline, universe).main.reference_robot
    return _distance(universe.id, False, settings(universe), reference, means, target)


def _settings(pipeline: Pipeline) -> dict[str, tuple[dict[str, Any], str]]:
    """Per universe id (``""`` for a single study): its settings and its reference robot."""
    if pipeline.multiverse is None:
        return {"": ({}, pipeline.main.reference_robot)}
    return {
        u.id: (settings(u), universe_pipeline(pipeline, u).main.reference_robot)
        for u in universes(pipeline)
    }


CellKey = tuple[str, int, str, str]
"""A cell of a run: ``(measure, num_features, human, robot)``."""

Measured = tuple[int, float, float]
"""A cell's ``(n, mean, sd)`` over its subjects."""


def ranked_distances(
    means: Mapping[str, Mapping[CellKey, Measured]],
    studies: Mapping[str, tuple[dict[str, Any], str]],
    target: Sequence[TargetCell],
    base: str | None,
) -> list[UniverseDistance]:
    """Every universe's distance to ``target`` (see the module docstring), the ranked ones
    nearest first (ties by id), then those that cannot be ranked.

    Args:
        means: per universe id, its cells' ``(n, mean, sd)`` (:func:`cell_means`).
        studies: per universe id, its settings and its reference robot, which a target
            cell without a robot is compared with.
        target: the target's cells.
        base: the id of the pipeline's own universe (``None`` in a single study).

    Raises:
        UserError: no universe measures one of the target's cells, or none can be ranked.
    """
    for cell in target:
        if not any(_key(cell, robot) in means.get(uid, {}) for uid, (_, robot) in studies.items()):
            raise UserError(f"no universe of the run measures the target's cell {_cell_name(cell)}")
    distances = [
        _distance(uid, uid == base, chosen, robot, means.get(uid, {}), target)
        for uid, (chosen, robot) in studies.items()
    ]
    ranked = sorted(
        (d for d in distances if d.mean_squared_log_ratio is not None),
        key=lambda d: (d.mean_squared_log_ratio, d.id),
    )
    if not ranked:
        raise UserError(f"no universe can be ranked: {distances[0].missing[0]}")
    return ranked + [d for d in distances if d.mean_squared_log_ratio is None]


def cell_means(main: pd.DataFrame) -> dict[str, dict[CellKey, Measured]]:
    """Per universe id (``""`` in a single study), per cell of the trial table ``main`` (of
    the ``main`` block, each universe's rows as it analyses them): ``(n, mean, sd)`` of each
    registered measure (:data:`~cirl_study.measure_registry.MEASURES`) over the trials
    that hold a value of it (a measure may be undefined for a trial, or missing from records of
    a log format before it: a cell none of whose trials holds it is left out, and a target
    naming it is then told the universe lacks the cell)."""
    main = main.assign(universe=main["universe"].fillna(""))
    keys = ["universe", "num_features", "human", "robot"]
    means: dict[str, dict[CellKey, Measured]] = {}
    for measure in MEASURES:
        grouped = main.groupby(keys, sort=True)[measure].agg(["count", "mean", "std"])
        for (universe, k, human, robot), row in grouped.iterrows():
            if row["count"] == 0:
                continue
            means.setdefault(str(universe), {})[(measure, int(k), str(human), str(robot))] = (
                int(row["count"]),
                float(row["mean"]),
                float(row["std"]),
            )
    return means


def _key(cell: TargetCell, reference: str) -> CellKey:
    return (cell.measure, cell.num_features, cell.human, cell.robot or reference)


def _cell_name(cell: TargetCell) -> str:
    robot = f", {cell.robot}" if cell.robot else ""
    return f"({cell.measure}, K={cell.num_features}, {terminal(cell.human)}{robot})"


def _distance(
    uid: str,
    base: bool,
    chosen: dict[str, Any],
    reference: str,
    means: Mapping[CellKey, Measured],
    target: Sequence[TargetCell],
) -> UniverseDistance:
    """One universe's :class:`~cirl_study.analysis.results.types.UniverseDistance`."""
    cells, missing = [], []
    for cell in target:
        key = _key(cell, reference)
        if key not in means:
            missing.append(f"lacks the cell {_cell_name(cell)}")
            continue
        n, mean, sd = means[key]
        if not mean > 0:
            missing.append(f"measures a mean of {mean:g} in {_cell_name(cell)}, not positive")
            continue
        cells.append(
            CellComparison(
                measure=cell.measure,
                num_features=cell.num_features,
                human=cell.human,
                robot=key[3],
                target=cell.value,
                target_log_se=cell.log_se,
                measured=mean,
                measured_log_se=sd / (mean * math.sqrt(n)) if n > 1 and math.isfinite(sd) else None,
                n=n,
                log_ratio=math.log(mean / cell.value),
            )
        )
    distance = chi_square = p = log10_p = None
    uncertain = [c for c in cells if c.target_log_se is not None]
    if not missing:
        distance = float(np.mean([c.log_ratio**2 for c in cells]))
        if uncertain:
            chi_square = float(
                sum(
                    c.log_ratio**2 / (c.target_log_se**2 + (c.measured_log_se or 0.0) ** 2)
                    for c in uncertain
                )  # fmt: skip
            )
            p, log10_p = chi2_tail(chi_square, len(uncertain))
    return UniverseDistance(
        id=uid,
        base=base,
        settings=chosen,
        cells=cells,
        mean_squared_log_ratio=distance,
        chi_square=chi_square,
        chi_square_df=len(uncertain) if not missing else 0,
        p=p,
        log10_p=log10_p,
        missing=missing,
    )


def _axes(ranked: Sequence[UniverseDistance]) -> list[AxisDistance]:
    """Per axis that varies among the ``ranked`` universes (nearest first), its levels'
    distances (:class:`~cirl_study.analysis.results.types.AxisDistance`)."""
    summaries = []
    for axis in AXES:
        if not any(axis in u.settings for u in ranked):
            continue
        levels = list(dict.fromkeys(u.settings.get(axis) for u in ranked))
        if len(levels) < 2:
            continue
        rows = []
        for level in levels:
            at = [u for u in ranked if u.settings.get(axis) == level]
            rows.append(
                LevelDistance(
                    level=level,
                    universes=len(at),
                    nearest=at[0].id,
                    nearest_distance=float(at[0].mean_squared_log_ratio),
                    median_distance=float(np.median([u.mean_squared_log_ratio for u in at])),
                )
            )
        nearest = [row.nearest_distance for row in rows]
        summaries.append(
            AxisDistance(
                axis=axis,
                best=rows[int(np.argmin(nearest))].level,
                spread=float(max(nearest) - min(nearest)),
                levels=rows,
            )
        )
    return summaries


def _claims_in(study: Pipeline, rows: list[TrialRow], *, paper_only: bool) -> list[ClaimRow]:
    """The claims tested on a study's ``rows`` with the paper report's rules; of a multiverse
    universe (``paper_only``), the paper's claims a universe tests (``PAPER_CLAIMS``)."""
    results = with_claims(analyse(rows, study), run_id=None, partial=None, theory=None)
    return [c for c in results.claims if c.tested and (not paper_only or c.id in PAPER_CLAIMS)]
