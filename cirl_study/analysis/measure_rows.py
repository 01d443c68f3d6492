"""Each test of every measure, as JSON-ready rows: the shape ``results.json`` stores.

:func:`plain` turns numpy scalars and NaN into JSON data; the others run one test of
:mod:`cirl_study.analysis.statistics` or :mod:`cirl_study.analysis.anova` for each measure the
analysis tests (:func:`~cirl_study.core.measure_registry.analysed_measures`) and return its
rows, measures in the registry's order.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import msgspec
import numpy as np
import pandas as pd

from cirl_study.analysis import statistics
from cirl_study.analysis.anova import repeated_measures_anova
from cirl_study.core.measure_registry import analysed_measures
from cirl_study.errors import UserError


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


def rows(frame: pd.DataFrame) -> list[dict[str, Any]]:
    """The rows of ``frame`` as a list of plain dicts."""
    return [plain(row) for row in frame.to_dict(orient="records")]


def paired_rows(frame: pd.DataFrame, factor: str, baseline: str, by: list[str]) -> list[dict]:
    """:func:`~cirl_study.analysis.statistics.paired_differences` for every measure, one Holm
    family per measure."""
    return rows(
        pd.concat(
            statistics.paired_differences(frame, m, factor, baseline, by)
            for m in analysed_measures()
        )
    )


def anova_rows(frame: pd.DataFrame, within: list[str]) -> list[dict[str, Any]]:
    """:func:`~cirl_study.analysis.anova.repeated_measures_anova` of every measure, with
    ``num_features`` between subjects where the frame has two levels or more of it."""
    between = "num_features" if frame["num_features"].nunique() > 1 else None
    return [
        plain(msgspec.to_builtins(row))
        for m in analysed_measures()
        for row in repeated_measures_anova(frame, m, within, between)
    ]


def pairwise_rows(frame: pd.DataFrame, factors: Mapping[str, tuple[str, ...]]) -> list[dict]:
    """:func:`~cirl_study.analysis.statistics.pairwise_differences` for every measure and
    every factor of ``factors`` (its levels, in order) with two levels or more."""
    return [
        plain(msgspec.to_builtins(row))
        for m in analysed_measures()
        for factor, levels in factors.items()
        if levels[1:]
        for row in statistics.pairwise_differences(frame, m, factor, levels)
    ]
