"""The tidy trial table: one row per trial record (docs/design.md §7).

:func:`trial_table` turns the trials' rows (:class:`~cirl_study.record.TrialRow`, projected
from records already validated when they were decoded) into a :class:`pandas.DataFrame`
whose row order depends only on the trials, never on the order the records came in, so
every statistic computed from it is reproducible to the bit. :func:`check_design` refuses
trials whose study design the analysis cannot use.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import pandas as pd

from cirl_study.errors import UserError
from cirl_study.logs.run_checks import (
    design_faults,
)
from cirl_study.measure_registry import MEASURES
from cirl_study.record import MAIN, TrialRow

IDENTITY: tuple[str, ...] = (
    "trial_id",
    "run_id",
    "universe",
    "block",
    "subject",
    "human",
    "robot",
    "num_features",
    "rationality",
    "eta",
    "seed",
)
"""The trial table's first columns: the trial's identity and settings. ``universe``: the
trial's multiverse universe (empty in a single study)."""


PEOPLE: tuple[str, ...] = ("task", "participant", "condition")
"""The columns a run with participants adds after :data:`IDENTITY`: a trial's task, and the
participant who showed it, in which condition (empty for a simulated human's trial)."""


FILE = "file"
"""The trial table's last column: the name of the log file, in the run directory, that holds
the trial's record (:attr:`~cirl_study.record.TrialRow.file`). It depends on how the run was cut
into batches, not on the trial: comparisons of two reports pass over it."""


def columns(people: bool = False) -> tuple[str, ...]:
    """Columns of the trial table, in order: :data:`IDENTITY` (then :data:`PEOPLE` in a run
    with participants, ``people``), every registered measure
    (:data:`~cirl_study.measure_registry.MEASURES`; NaN where the trial has no value of it:
    undefined for it, or not logged by its log format), ``converged``: the robot's estimate
    met its stopping rule (``irl.converged``; a record without a fit report counts as
    converged), and :data:`FILE`, the log file that holds the trial."""
    return (*IDENTITY, *(PEOPLE if people else ()), *MEASURES, "converged", FILE)


SORT_KEYS: tuple[str, ...] = (
    "universe",
    "block",
    "num_features",
    "subject",
    "human",
    "robot",
    "rationality",
    "eta",
    "trial_id",
)
"""Row order of the trial table (``trial_id`` breaks any remaining tie)."""


def _columns(rows: Sequence[TrialRow]) -> dict[str, list[Any]]:
    """The table's columns, filled row by row (no per-row dict: a run may have millions)."""
    named = IDENTITY + (PEOPLE if _with_people(rows) else ())
    data = {name: [getattr(row, name) for row in rows] for name in named if name != "eta"}
    data["eta"] = [math.nan if row.eta is None else row.eta for row in rows]
    for position, measure in enumerate(MEASURES):
        values = (row.measures[position] for row in rows)
        data[measure] = [math.nan if value is None else value for value in values]
    data["converged"] = [row.converged for row in rows]
    data[FILE] = [row.file for row in rows]
    return data


def _with_people(rows: Sequence[TrialRow]) -> bool:
    return any(row.participant is not None for row in rows)


def trial_table(rows: Sequence[TrialRow]) -> pd.DataFrame:
    """The tidy trial table, one row per trial.

    Args:
        rows: the trials' rows, in any order.

    Returns:
        A frame with the columns :func:`columns` (with :data:`PEOPLE` where a row is a
        participant's; ``eta`` is NaN for the expert, a measure
        where the trial has no value of it), sorted by :data:`SORT_KEYS` and indexed
        ``0 .. n-1``.
    """
    table = pd.DataFrame(_columns(rows), columns=list(columns(_with_people(rows))))
    return table.sort_values(list(SORT_KEYS), kind="mergesort").reset_index(drop=True)


def check_design(rows: Sequence[TrialRow]) -> None:
    """Check that the trials' ``rows`` hold a study design the analysis can use.

    The run's design must be sound (:func:`cirl_study.logs.run_checks.design_faults`: unique
    trial ids, one reward draw per subject, a non-empty ``main`` block complete within
    subjects, cross-validation draws disjoint from the test draws), with at least two cells
    of humans x robots x feature levels in its ``main`` block.

    Raises:
        UserError: one line naming every fault found.
    """
    faults = design_faults(rows)
    cells = {(row.human, row.robot, row.num_features) for row in rows if row.block == MAIN}
    if len(cells) == 1:
        faults.append("the main block has one cell (one human, one robot, one feature level)")
    if faults:
        raise UserError(f"the run's design cannot be analysed: {'; '.join(faults)}")
