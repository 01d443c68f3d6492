"""Each test of every measure: the computations of the registered tests
(:mod:`cirl_study.analysis.results.registry`), and the per-measure tests of the teaching sections.

A registered test's computation (``anova``, ``pairwise``, ``against_baseline``; the paper's
``paper_anova``, ``simple_effects``, ``tukey_hsd``, ``wilcoxon``) returns its rows of one
measure; :func:`run_tests` runs every test a record registers for each measure the analysis
tests (:func:`~cirl_study.measure_registry.analysed_measures`), in the registry's order, each
on the trials that have a value of it (:func:`measured`). :func:`plain` turns numpy scalars
and NaN into JSON data, for the results' free-form mappings (a claim's values, a universe's
settings).
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np
import pandas as pd

from cirl_study.analysis.results.cells import Design
from cirl_study.analysis.results.registry import registered
from cirl_study.analysis.results.types import (
    AnovaEffect,
    PairedComparison,
    PairedDifference,
    Record,
    SimpleEffect,
    Table,
    TukeyRow,
    Undefined,
    WilcoxonRow,
)
from cirl_study.analysis.statistics import procedures as statistics
from cirl_study.analysis.statistics.anova import refuse_non_finite, repeated_measures_anova
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
    (:func:`~cirl_study.analysis.statistics.anova.refuse_non_finite`), as the record checks refuse
    it (:func:`~cirl_study.measure_registry.measure_faults`): an infinity, and NaN where the
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


def undefined(table: pd.DataFrame) -> Table[Undefined] | None:
    """Per measure the analysis tests that some trials of ``table`` (the trial table) have no
    value of: those ``trials`` and the ``subjects`` (reward draws) they belong to, which
    :func:`measured` leaves out of its statistics. ``None`` when every trial has every value."""
    found = Table(Undefined)
    for measure in analysed_measures():
        missing = table[table[measure].isna()]
        if not missing.empty:
            found.append(
                Undefined(
                    measure=measure,
                    trials=len(missing),
                    subjects=int(missing["subject"].nunique()),
                )
            )
    return found or None


def run_tests(record: type[Record], frame: pd.DataFrame, design: Design) -> dict[str, Table]:
    """The rows of every test ``record`` registers, by field name: each computed on ``frame``
    for every measure (:func:`measured`), the measures in the registry's order."""
    by_measure = list(measured(frame))
    return {
        test.name: Table(
            test.row_type,
            (
                row
                for measure, kept in by_measure
                for row in test.test.computed(kept, measure, design)
            ),
        )
        for test in registered(record)
    }


def paired_rows(
    frame: pd.DataFrame, factor: str, baseline: str, by: list[str]
) -> Table[PairedDifference]:
    """:func:`~cirl_study.analysis.statistics.procedures.paired_differences` for every measure, one
    Holm family per measure."""
    return Table(
        PairedDifference,
        (
            row
            for m, kept in measured(frame)
            for row in statistics.paired_differences(kept, m, factor, baseline, by)
        ),
    )


def _anova(frame: pd.DataFrame, measure: str, within: list[str]) -> list[AnovaEffect]:
    """:func:`~cirl_study.analysis.statistics.anova.repeated_measures_anova` of ``measure`` with
    ``num_features`` between subjects where ``frame`` has two levels or more of it."""
    between = ("num_features",) if frame["num_features"].nunique() > 1 else ()
    return repeated_measures_anova(frame, measure, within, between)


def anova_rows(frame: pd.DataFrame, within: list[str]) -> Table[AnovaEffect]:
    """The ANOVA (:func:`_anova`) of every measure with the within factors ``within``."""
    return Table(
        AnovaEffect, (row for m, kept in measured(frame) for row in _anova(kept, m, within))
    )


def anova(frame: pd.DataFrame, measure: str, design: Design) -> list[AnovaEffect]:
    """The registered ``anova``: the ANOVA of the whole design, ``human`` and ``robot`` within
    subjects where they have two levels or more."""
    within = [f for f, levels in (("human", design.humans), ("robot", design.robots)) if levels[1:]]
    return _anova(frame, measure, within)


def pairwise(frame: pd.DataFrame, measure: str, design: Design) -> list[PairedComparison]:
    """The registered ``pairwise``: every pair of humans, and of robots, in every cell of the
    other factors (:func:`~cirl_study.analysis.statistics.procedures.pairwise_differences`; one
    Holm family per factor)."""
    factors = (("human", design.humans), ("robot", design.robots))
    return [
        row
        for factor, levels in factors
        if levels[1:]
        for row in statistics.pairwise_differences(frame, measure, factor, levels)
    ]


def against_baseline(frame: pd.DataFrame, measure: str, design: Design) -> list[PairedDifference]:
    """The registered ``against_baseline``: every other human against the baseline per robot
    and feature level (:func:`~cirl_study.analysis.statistics.procedures.paired_differences`); none
    with one human."""
    if not design.humans[1:]:
        return []
    return statistics.paired_differences(
        frame, measure, "human", design.baseline, ["robot", "num_features"]
    )


def paper_anova(frame: pd.DataFrame, measure: str, design: Design) -> list[AnovaEffect]:
    """The registered ``paper.anova``: the paper's mixed ANOVA, ``human`` within subjects."""
    return _anova(frame, measure, ["human"])


def simple_effects(frame: pd.DataFrame, measure: str, design: Design) -> list[SimpleEffect]:
    """The registered ``paper.simple_effects``
    (:func:`~cirl_study.analysis.statistics.procedures.simple_effects`)."""
    return statistics.simple_effects(frame, measure)


def tukey_hsd(frame: pd.DataFrame, measure: str, design: Design) -> list[TukeyRow]:
    """The registered ``paper.tukey_hsd``
    (:func:`~cirl_study.analysis.statistics.procedures.tukey_hsd`)."""
    return statistics.tukey_hsd(frame, measure)


def wilcoxon(frame: pd.DataFrame, measure: str, design: Design) -> list[WilcoxonRow]:
    """The registered ``paper.wilcoxon``
    (:func:`~cirl_study.analysis.statistics.procedures.wilcoxon`)."""
    return statistics.wilcoxon(frame, measure)
