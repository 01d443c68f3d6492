"""Each test of every measure, as JSON-ready rows: the shape ``results.json`` stores.

:func:`plain` turns numpy scalars and NaN into JSON data; the others run one test of
:mod:`cirl_study.analysis.statistics` or :mod:`cirl_study.analysis.anova` for each measure the
analysis tests (:func:`~cirl_study.measure_registry.analysed_measures`) and return its
rows, measures in the registry's order, each on the trials that have a value of it
(:func:`measured`).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from typing import Any

import msgspec
import numpy as np
import pandas as pd

from cirl_study.analysis import statistics
from cirl_study.analysis.anova import refuse_non_finite, repeated_measures_anova
from cirl_study.errors import UserError
from cirl_study.measure_registry import MEASURES, analysed_measures


def plain(value: Any) -> Any:
    """``value`` as plain JSON data: numpy scalars unwrapped, NaN as ``None``.

    Raises:
        UserError: ``value`` holds something JSON cannot represent.
    """
    if isinstance(value, Mapping):
        return {str(key): plain(item) for key, item in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [plain(item) for item in value]
    if value is None or isinstance(value, bool | str):
        return value
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        number = float(value)
        return number if math.isfinite(number) else None
    raise UserError(f"cannot store a {type(value).__name__} in results.json: {value!r}")


def measured(frame: pd.DataFrame) -> Iterator[tuple[str, pd.DataFrame]]:
    """Each measure the analysis tests, with the part of ``frame`` (rows of the trial table)
    its statistics read: ``frame`` without the subjects (reward draws) that have no value of it
    (NaN: ``null`` in their records) in some trial. Every test pairs a subject's trials, so
    such a subject is left out of all the measure's statistics, and a missing value is never
    averaged; a measure without a value in ``frame`` has no statistics and is not yielded.

    A value no record can hold is refused
    (:func:`~cirl_study.analysis.anova.refuse_non_finite`), as the record checks refuse it
    (:func:`~cirl_study.measure_registry.measure_faults`): an infinity, and NaN where the
    measure has a value in every trial (:attr:`~cirl_study.measure_registry.Measure.undefined`
    is ``None``), so a frame handed to the analysis with a NaN there is a fault, never
    averaged nor silently dropped.

    Raises:
        UserError: one line naming the first trial of such a value.
    """
    for measure in analysed_measures():
        refuse_non_finite(frame, measure, missing_allowed=MEASURES[measure].undefined is not None)
        missing = frame.loc[frame[measure].isna(), "subject"]
        kept = frame if missing.empty else frame[~frame["subject"].isin(set(missing))]
        if not kept.empty:
            yield measure, kept


def undefined(table: pd.DataFrame) -> list[dict[str, Any]]:
    """Per measure the analysis tests that some trials of ``table`` (the trial table) have no
    value of: those ``trials`` and the ``subjects`` (reward draws) they belong to, which
    :func:`measured` leaves out of its statistics. Empty when every trial has every value."""
    found = []
    for measure in analysed_measures():
        missing = table[table[measure].isna()]
        if not missing.empty:
            found.append(
                {
                    "measure": measure,
                    "trials": len(missing),
                    "subjects": int(missing["subject"].nunique()),
                }
            )
    return found


def rows(frame: pd.DataFrame) -> list[dict[str, Any]]:
    """The rows of ``frame`` as a list of plain dicts."""
    return [plain(row) for row in frame.to_dict(orient="records")]


def paired_rows(frame: pd.DataFrame, factor: str, baseline: str, by: list[str]) -> list[dict]:
    """:func:`~cirl_study.analysis.statistics.paired_differences` for every measure, one Holm
    family per measure."""
    return rows(
        pd.concat(
            statistics.paired_differences(kept, m, factor, baseline, by)
            for m, kept in measured(frame)
        )
    )


def anova_rows(frame: pd.DataFrame, within: list[str]) -> list[dict[str, Any]]:
    """:func:`~cirl_study.analysis.anova.repeated_measures_anova` of every measure, with
    ``num_features`` between subjects where the measure's trials have two levels or more of
    it."""
    return [
        plain(msgspec.to_builtins(row))
        for m, kept in measured(frame)
        for row in repeated_measures_anova(
            kept, m, within, "num_features" if kept["num_features"].nunique() > 1 else None
        )
    ]


def pairwise_rows(frame: pd.DataFrame, factors: Mapping[str, tuple[str, ...]]) -> list[dict]:
    """:func:`~cirl_study.analysis.statistics.pairwise_differences` for every measure and
    every factor of ``factors`` (its levels, in order) with two levels or more."""
    return [
        plain(msgspec.to_builtins(row))
        for m, kept in measured(frame)
        for factor, levels in factors.items()
        if levels[1:]
        for row in statistics.pairwise_differences(kept, m, factor, levels)
    ]
