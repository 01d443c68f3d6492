"""The tidy trial table: one row per trial record (DESIGN.md section 7).

:func:`trial_table` flattens the records into a :class:`pandas.DataFrame` whose row
order depends only on the trials, never on the order the records came in, so every
statistic computed from it is reproducible to the bit. :func:`check_design` refuses
a table whose ``main`` block is not a complete split-plot design.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from numbers import Integral, Real
from typing import Any

import pandas as pd

from cirl_study.errors import UserError

MEASURES: tuple[str, ...] = ("regret", "kl", "reward_l2")
"""The three dependent measures of DESIGN.md section 4, in the paper's order."""

POLICIES: tuple[str, ...] = ("expert", "best_response")
"""The levels of the within-subjects factor ``policy``."""

MAIN, ETA_CV, LAMBDA_SWEEP = "main", "eta_cv", "lambda_sweep"
"""The blocks of DESIGN.md section 5."""

COLUMNS: tuple[str, ...] = (
    "trial_id",
    "run_id",
    "block",
    "subject",
    "policy",
    "num_features",
    "rationality",
    "eta",
    "seed",
    *MEASURES,
)
"""Columns of the trial table, in order."""

SORT_KEYS: tuple[str, ...] = (
    "block",
    "num_features",
    "subject",
    "policy",
    "rationality",
    "eta",
    "trial_id",
)
"""Row order of the trial table (``trial_id`` breaks any remaining tie)."""

_LISTED = 5
"""How many offending items an error message lists before summarising."""


def _is_integer(value: Any) -> bool:
    return isinstance(value, Integral) and not isinstance(value, bool)


def _is_real(value: Any) -> bool:
    return isinstance(value, Real) and not isinstance(value, bool) and math.isfinite(value)


def _field(record: Mapping[str, Any], dotted: str, where: str) -> Any:
    value: Any = record
    for part in dotted.split("."):
        if not isinstance(value, Mapping) or part not in value:
            raise UserError(f"{where}: missing field '{dotted}'")
        value = value[part]
    return value


def _identifier(record: Mapping[str, Any], name: str, where: str) -> str:
    value = _field(record, name, where)
    if isinstance(value, bool) or not isinstance(value, str | Integral) or value == "":
        raise UserError(f"{where}: '{name}' must be a non-empty string, got {value!r}")
    return str(value)


def _row(record: Any, position: int) -> dict[str, Any]:
    """Validate one record and flatten it into a table row."""
    where = f"trial record {position}"
    if not isinstance(record, Mapping):
        raise UserError(f"{where}: expected a JSON object, got {type(record).__name__}")
    trial_id = _identifier(record, "trial_id", where)
    where = f"trial record {position} (trial_id {trial_id!r})"
    row: dict[str, Any] = {"trial_id": trial_id}
    for name in ("run_id", "block", "subject", "policy"):
        row[name] = _identifier(record, name, where)
    num_features = _field(record, "num_features", where)
    if not _is_integer(num_features) or num_features < 1:
        raise UserError(f"{where}: 'num_features' must be a positive integer, got {num_features!r}")
    rationality = _field(record, "rationality", where)
    if not _is_real(rationality) or rationality <= 0:
        raise UserError(f"{where}: 'rationality' must be a positive number, got {rationality!r}")
    eta = _field(record, "eta", where)
    if eta is not None and not _is_real(eta):
        raise UserError(f"{where}: 'eta' must be a number or null, got {eta!r}")
    seed = _field(record, "seed", where)
    if not _is_integer(seed):
        raise UserError(f"{where}: 'seed' must be an integer, got {seed!r}")
    row.update(
        num_features=int(num_features),
        rationality=float(rationality),
        eta=math.nan if eta is None else float(eta),
        seed=int(seed),
    )
    for measure in MEASURES:
        value = _field(record, f"measures.{measure}", where)
        if not _is_real(value):
            raise UserError(f"{where}: 'measures.{measure}' must be a finite number, got {value!r}")
        row[measure] = float(value)
    return row


def trial_table(records: Sequence[Mapping[str, Any]]) -> pd.DataFrame:
    """Flatten trial records into the tidy trial table, one row per trial.

    Args:
        records: trial records shaped like DESIGN.md section 7.

    Returns:
        A frame with the columns :data:`COLUMNS` (``eta`` is NaN for the expert),
        sorted by :data:`SORT_KEYS` and indexed ``0 .. n-1``.

    Raises:
        UserError: a record lacks a field or has a value of the wrong type.
    """
    rows = [_row(record, position) for position, record in enumerate(records)]
    table = pd.DataFrame(rows, columns=list(COLUMNS))
    return table.sort_values(list(SORT_KEYS), kind="mergesort").reset_index(drop=True)


def _listing(items: Sequence[str]) -> str:
    shown = ", ".join(items[:_LISTED])
    return shown if len(items) <= _LISTED else f"{shown} and {len(items) - _LISTED} more"


def check_design(table: pd.DataFrame) -> None:
    """Check that the trial table holds a complete study design.

    The ``main`` block must be a complete split-plot design: both policies of
    :data:`POLICIES` and nothing else, at least two feature levels, every
    ``policy x num_features`` cell filled, every subject (reward draw) at exactly
    one feature level with exactly one trial per policy. Trial ids must be unique.

    Raises:
        UserError: naming what is missing or duplicated.
    """
    duplicated = sorted(set(table.loc[table["trial_id"].duplicated(), "trial_id"]))
    if duplicated:
        raise UserError(f"duplicated trial ids: {_listing(duplicated)}")
    main = table[table["block"] == MAIN]
    if main.empty:
        raise UserError("no trials in the 'main' block: the policy x num_features study is missing")
    unknown = sorted(set(main["policy"]) - set(POLICIES))
    if unknown:
        raise UserError(
            f"main block: unknown policies {_listing(unknown)} (expected {', '.join(POLICIES)})"
        )
    levels = sorted(set(main["num_features"]))
    missing = [
        f"policy={policy}, num_features={level}"
        for level in levels
        for policy in POLICIES
        if not ((main["policy"] == policy) & (main["num_features"] == level)).any()
    ]
    if missing:
        raise UserError(f"main block: missing cells of the design: {'; '.join(missing)}")
    if len(levels) < 2:
        raise UserError(
            f"main block: only num_features={levels[0]}; the design needs at least two levels"
        )
    spread = main.groupby("subject")["num_features"].nunique()
    crossing = sorted(spread.index[spread > 1])
    if crossing:
        raise UserError(
            f"main block: subjects at more than one feature level: {_listing(crossing)} "
            "(subject ids must be unique across feature levels)"
        )
    counts = main.groupby(["subject", "policy"]).size().unstack("policy", fill_value=0)
    counts = counts.reindex(columns=list(POLICIES), fill_value=0)
    unpaired = [
        f"{subject} ({', '.join(f'{policy} x{counts.at[subject, policy]}' for policy in POLICIES)})"
        for subject in counts.index
        if (counts.loc[subject] != 1).any()
    ]
    if unpaired:
        raise UserError(
            f"main block: subjects without exactly one trial per policy: {_listing(unpaired)}"
        )
