"""The tidy trial table: one row per trial record (docs/design.md §7).

:func:`trial_table` projects the typed records (:class:`~cirl_study.record.TrialRecord`,
already validated when they were decoded) into a :class:`pandas.DataFrame` whose row order
depends only on the trials, never on the order the records came in, so every statistic
computed from it is reproducible to the bit. :func:`check_design` refuses records whose
study design the analysis cannot use.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import pandas as pd

from cirl_study.errors import UserError
from cirl_study.logs.run_checks import design_faults, incomplete_main_subjects
from cirl_study.record import MAIN, MEASURES, PAPER_POLICIES, TrialRecord

COLUMNS: tuple[str, ...] = (
    "trial_id",
    "run_id",
    "block",
    "subject",
    "policy",
    "robot",
    "num_features",
    "rationality",
    "eta",
    "seed",
    *MEASURES,
    "certified",
)
"""Columns of the trial table, in order. ``certified``: the robot certified its estimate
(``irl.converged``; a record without a fit report counts as certified)."""

SORT_KEYS: tuple[str, ...] = (
    "block",
    "num_features",
    "subject",
    "policy",
    "robot",
    "rationality",
    "eta",
    "trial_id",
)
"""Row order of the trial table (``trial_id`` breaks any remaining tie)."""


def _row(record: TrialRecord) -> dict[str, Any]:
    """The table row of one record: its identity, inputs and measures."""
    return {
        "trial_id": record.trial_id,
        "run_id": record.run_id,
        "block": record.block,
        "subject": record.subject,
        "policy": record.policy,
        "robot": record.robot,
        "num_features": record.num_features,
        "rationality": record.rationality,
        "eta": math.nan if record.eta is None else record.eta,
        "seed": record.seed,
        **{measure: getattr(record.measures, measure) for measure in MEASURES},
        "certified": record.irl is None or record.irl.converged,
    }


def trial_table(records: Sequence[TrialRecord]) -> pd.DataFrame:
    """Project trial records into the tidy trial table, one row per trial.

    Args:
        records: the trial records, in any order.

    Returns:
        A frame with the columns :data:`COLUMNS` (``eta`` is NaN for the expert),
        sorted by :data:`SORT_KEYS` and indexed ``0 .. n-1``.
    """
    table = pd.DataFrame([_row(record) for record in records], columns=list(COLUMNS))
    return table.sort_values(list(SORT_KEYS), kind="mergesort").reset_index(drop=True)


def complete_main_subjects(
    records: Sequence[TrialRecord],
) -> tuple[list[TrialRecord], list[str]]:
    """The records without the ``main``-block trials of subjects that lack a cell.

    For a partial run: a ``main`` subject must have exactly one trial in every (policy,
    robot) cell the block plays to enter the within-subjects analysis
    (:func:`~cirl_study.logs.run_checks.incomplete_main_subjects`). Returns the records kept
    and the ids of the subjects whose ``main`` trials were left out.
    """
    _, incomplete = incomplete_main_subjects(records)
    kept = [r for r in records if not (r.block == MAIN and r.subject in incomplete)]
    return kept, sorted(incomplete)


def check_design(records: Sequence[TrialRecord]) -> None:
    """Check that the records hold a study design the analysis can use.

    The run's design must be sound (:func:`cirl_study.logs.run_checks.design_faults`: unique
    trial ids, one reward draw per subject, a non-empty ``main`` block complete within
    subjects, cross-validation draws disjoint from the test draws), and the analysis needs
    more of the ``main`` block: it plays exactly the policies :data:`PAPER_POLICIES`, at
    least two feature levels and at most two robots (a comparison of a robot with the
    reference).

    Raises:
        UserError: one line naming every fault found.
    """
    faults = design_faults(records)
    main = [record for record in records if record.block == MAIN]
    policies = sorted({record.policy for record in main})
    if main and policies != sorted(PAPER_POLICIES):
        faults.append(
            f"the main block plays {', '.join(policies)}; the analysis needs exactly "
            f"{', '.join(PAPER_POLICIES)}"
        )
    levels = sorted({record.num_features for record in main})
    if len(levels) == 1:
        faults.append(
            f"the main block has only num_features={levels[0]}; the analysis needs at least "
            "two feature levels"
        )
    robots = sorted({record.robot for record in main})
    if len(robots) > 2:
        faults.append(
            f"the main block has {len(robots)} robots ({', '.join(robots)}); the analysis "
            "compares at most two"
        )
    if faults:
        raise UserError(f"the run's design cannot be analysed: {'; '.join(faults)}")
