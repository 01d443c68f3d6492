"""Every number of the report, computed from the trials' rows as JSON-ready data.

:func:`analyse` runs every test of :mod:`cirl_study.analysis.statistics` on the blocks
they belong to, takes the cross-validated eta from the function the run chose it with
(:func:`cirl_study.study.eta_cv.choose_etas`), and returns plain Python data (dicts,
lists, ints, floats at full precision, ``None`` for an undefined number), which
``results.json`` stores as is and the claims and the report read from. Its halves,
:func:`estimates` (everything the figures draw) and :func:`tests`, depend only on the trials,
so the report draws its figures in worker processes while it computes the tests.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import msgspec
import numpy as np
import pandas as pd

from cirl_study.analysis import statistics
from cirl_study.analysis.anova import repeated_measures_anova
from cirl_study.analysis.table import trial_table
from cirl_study.core.players import reference_robot
from cirl_study.errors import UserError
from cirl_study.record import (
    BEST_RESPONSE,
    BLOCKS,
    ETA_CV,
    EXPERT,
    LAMBDA_SWEEP,
    MAIN,
    MEASURES,
    TrialRow,
)
from cirl_study.study.eta_cv import choose_etas

Results = dict[str, Any]
"""The JSON-ready results of :func:`analyse` (the content of ``results.json``)."""


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


def _concat(frames: list[pd.DataFrame]) -> pd.DataFrame:
    return pd.concat(frames, ignore_index=True)


def figure1_subject(main: pd.DataFrame) -> dict[str, Any]:
    """The reward draw shown in Figure 1: a typical one at the smallest feature level.

    Among the subjects at the smallest feature level, the one whose regret improvement
    ``regret(expert) - regret(best_response)`` is the median (the lower median for an
    even count; ties broken by subject id).
    """
    level = int(main["num_features"].min())
    paired = statistics.paired_by_subject(main, "regret", level)
    improvement = (paired[EXPERT] - paired[BEST_RESPONSE]).rename("improvement")
    ordered = improvement.reset_index().sort_values(["improvement", "subject"], kind="mergesort")
    chosen = ordered.iloc[(len(ordered) - 1) // 2]
    subject = str(chosen["subject"])
    return {
        "subject": subject,
        "num_features": level,
        "regret_expert": float(paired.at[subject, EXPERT]),
        "regret_best_response": float(paired.at[subject, BEST_RESPONSE]),
        "rule": (
            f"the subject at num_features={level} whose regret improvement "
            "(expert minus best response) is the median of its feature level"
        ),
    }


def _trial_counts(table: pd.DataFrame) -> dict[str, int]:
    """Trials in total and per block: the blocks of docs/design.md §5 first, then any other."""
    sizes = table.groupby("block").size()
    order = [b for b in BLOCKS if b in sizes.index]
    order += [b for b in sizes.index if b not in order]
    return {"total": len(table), **{str(block): int(sizes[block]) for block in order}}


def _design(main: pd.DataFrame) -> dict[str, Any]:
    subjects = main.groupby("num_features")["subject"].nunique()
    return {
        "feature_levels": [int(level) for level in subjects.index],
        "subjects_per_level": {str(level): int(n) for level, n in subjects.items()},
        "main_rationality": sorted({float(value) for value in main["rationality"]}),
        "main_eta": {
            str(level): sorted({float(value) for value in etas.dropna()})
            for level, etas in main.groupby("num_features")["eta"]
        },
    }


def eta_cv(trials: Sequence[TrialRow], table: pd.DataFrame) -> dict[str, Any]:
    """The cross-validation of the best response's eta, and whether the main block used it.

    ``means``: mean best-response regret with its CI per feature level and eta
    (:func:`~cirl_study.analysis.statistics.eta_means`). ``uncertainty``: how clear-cut each
    choice is (:func:`~cirl_study.analysis.statistics.eta_choice_uncertainty`). ``chosen``:
    per feature level, the eta :func:`~cirl_study.study.eta_cv.choose_etas` picks from the
    ``eta_cv`` rows of ``trials`` (the choice the run made) and its mean regret. ``main_block``: per
    feature level of the ``main`` block, the etas its best-response trials were played with
    (``main_etas``, one in a sound run), the cross-validated eta (``chosen_eta``, ``None`` without
    cross-validation at that level) and whether they agree (``None`` when there is nothing
    to compare with).

    Raises:
        UserError: the ``eta_cv`` trials admit no choice (see ``choose_etas``).
    """
    cv = table[table["block"] == ETA_CV]
    try:
        choices = choose_etas(trials)
    except ValueError as error:
        raise UserError(f"eta cross-validation: {error}") from None
    chosen = {k: choice for (_, policy, k), choice in choices.items() if policy == BEST_RESPONSE}
    played: dict[int, set[float]] = {}
    for row in trials:
        if row.block == MAIN and row.policy == BEST_RESPONSE and row.eta is not None:
            played.setdefault(row.num_features, set()).add(row.eta)
    levels = sorted({row.num_features for row in trials if row.block == MAIN})
    main_block = []
    for k in levels:
        main_etas = sorted(played.get(k, ()))
        chosen_eta = chosen[k].eta if k in chosen else None
        agree = None if chosen_eta is None else main_etas == [chosen_eta]
        main_block.append(
            {"num_features": k, "main_etas": main_etas, "chosen_eta": chosen_eta, "agree": agree}
        )
    chosen_etas = {k: choice.eta for k, choice in chosen.items()}
    uncertainty = statistics.eta_choice_uncertainty(cv, chosen_etas) if not cv.empty else None
    return {
        "means": rows(statistics.eta_means(cv)) if not cv.empty else [],
        "uncertainty": rows(uncertainty) if uncertainty is not None else [],
        "chosen": [
            {"num_features": k, "eta": choice.eta, "mean": choice.mean_regret[choice.eta]}
            for k, choice in sorted(chosen.items())
        ],
        "main_block": plain(main_block),
    }


def _certified(table: pd.DataFrame) -> list[dict[str, Any]]:
    """Per robot, block and rationality: trials, and those whose estimate the robot certified."""
    keys = ["robot", "block", "rationality"]
    counts = table.groupby(keys, sort=True)["certified"].agg(["size", "sum"])
    return [
        {
            "robot": str(robot),
            "block": str(block),
            "rationality": float(rationality),
            "trials": int(n),
            "certified": int(k),
        }
        for (robot, block, rationality), (n, k) in counts.iterrows()
    ]


def robot_comparison(table: pd.DataFrame, reference: str) -> dict[str, Any]:
    """The robots study: the other robot against the reference, on the same demonstrations.

    ``anova``: per measure, the 2 x 2 x K split-plot ANOVA of the ``main`` block with
    ``robot`` and ``policy`` within subjects and ``num_features`` between
    (:func:`~cirl_study.analysis.anova.repeated_measures_anova`). ``main``: per measure, the
    paired difference ``other - reference`` within each feature level and policy, Holm over
    the measure's cells (:func:`~cirl_study.analysis.statistics.paired_differences`).
    ``lambda_sweep``: the same per rationality, feature level and policy of the sweep, Holm
    over the measure's whole sweep. Every measure is a loss: a negative difference means
    the other robot did better.
    """
    main = table[table["block"] == MAIN]
    sweep = table[table["block"] == LAMBDA_SWEEP]
    (other,) = sorted(set(main["robot"]) - {reference})
    cells = ["num_features", "policy"]
    return {
        "reference": reference,
        "other": other,
        "anova": [
            msgspec.to_builtins(row)
            for m in MEASURES
            for row in repeated_measures_anova(main, m, ["robot", "policy"], "num_features")
        ],
        "main": rows(
            _concat(
                [
                    statistics.paired_differences(main, m, "robot", reference, cells)
                    for m in MEASURES
                ]
            )
        ),
        "lambda_sweep": rows(
            _concat(
                [
                    statistics.paired_differences(
                        sweep, m, "robot", reference, ["rationality", *cells]
                    )
                    for m in MEASURES
                ]
            )
        )
        if not sweep.empty
        else [],
    }


RESULT_KEYS: tuple[str, ...] = (
    "pipeline",
    "trials",
    "design",
    "anova",
    "simple_effects",
    "tukey_hsd",
    "wilcoxon",
    "cells",
    "cronbach_alpha",
    "lambda_sweep",
    "certified",
    "eta_cv",
    "figure1",
    "robots",
)
"""The keys of :func:`analyse`'s results, in the order ``results.json`` lists them."""


def analyse(trials: Sequence[TrialRow], pipeline_name: str) -> Results:
    """Run every analysis of docs/design.md §5 on checked trials: :func:`estimates` and
    :func:`tests`, in this process.

    Args:
        trials: the trials' rows (:class:`~cirl_study.record.TrialRow`), already accepted by
            :func:`~cirl_study.analysis.table.check_design`, in any order.
        pipeline_name: the pipeline's name, recorded in the results.

    Returns:
        Plain data with the keys of :data:`RESULT_KEYS`. Every statistic but ``robots`` and
        ``certified`` is computed on the trials of the reference robot
        (:func:`cirl_study.core.robot.reference_robot`: the paper's, ``map``, when the run has
        it), so the paper's analysis of a run with two robots is that of its reference robot
        alone. ``robots`` is the comparison of the two (:func:`robot_comparison`), ``None``
        for a run with one robot. ``lambda_sweep`` is an empty list and ``eta_cv`` has empty
        ``means`` and ``chosen`` when the run has no trials in that block (see
        :func:`eta_cv`).
    """
    everything = trial_table(trials)
    estimated = estimates(trials, everything, pipeline_name)
    return combined(estimated, tests(reference_main_block(everything)))


def reference_main_block(everything: pd.DataFrame) -> pd.DataFrame:
    """The ``main`` block's trials of the reference robot: the table the paper's tests read."""
    main = everything[everything["block"] == MAIN]
    return main[main["robot"] == reference_robot(sorted(set(main["robot"])))]


def estimates(trials: Sequence[TrialRow], everything: pd.DataFrame, pipeline_name: str) -> Results:
    """What the trials measured, with confidence intervals: everything the figures draw.

    The keys ``pipeline, trials, design, cells, lambda_sweep, certified, eta_cv, figure1,
    robots`` of :func:`analyse`, from the rows and their table ``everything``
    (:func:`~cirl_study.analysis.table.trial_table`).
    """
    robots = sorted(set(everything.loc[everything["block"] == MAIN, "robot"]))
    reference = reference_robot(robots)
    table = everything[everything["robot"] == reference]
    main = reference_main_block(everything)
    sweep = table[table["block"] == LAMBDA_SWEEP]
    return {
        "pipeline": pipeline_name,
        "trials": _trial_counts(everything),
        "design": {**_design(main), "robots": robots, "reference_robot": reference},
        "cells": rows(
            _concat([statistics.group_means(main, m, ["num_features", "policy"]) for m in MEASURES])
        ),
        "lambda_sweep": rows(statistics.lambda_sweep(sweep, MEASURES)) if not sweep.empty else [],
        "certified": _certified(everything),
        "eta_cv": eta_cv(trials, table),
        "figure1": {**figure1_subject(main), "robot": reference},
        "robots": robot_comparison(everything, reference) if len(robots) > 1 else None,
    }


def tests(main: pd.DataFrame) -> Results:
    """The paper's tests on the ``main`` block of the reference robot
    (:func:`reference_main_block`): the keys ``anova, simple_effects, tukey_hsd, wilcoxon,
    cronbach_alpha`` of :func:`analyse`."""
    alpha = statistics.cronbach_alpha(main[list(MEASURES)].reset_index(drop=True))
    alpha["items"] = list(MEASURES)
    alpha["rows"] = (
        f"all {len(main)} trials of the main block, one row per trial (both policies, "
        "every feature level), the three measures on their own scales"
    )
    return {
        "anova": rows(_concat([statistics.mixed_anova(main, m) for m in MEASURES])),
        "simple_effects": rows(_concat([statistics.simple_effects(main, m) for m in MEASURES])),
        "tukey_hsd": rows(_concat([statistics.tukey_hsd(main, m) for m in MEASURES])),
        "wilcoxon": rows(_concat([statistics.wilcoxon(main, m) for m in MEASURES])),
        "cronbach_alpha": plain(alpha),
    }


def combined(estimated: Results, tested: Results) -> Results:
    """:func:`estimates` and :func:`tests` as :func:`analyse` returns them."""
    both = {**estimated, **tested}
    return {key: both[key] for key in RESULT_KEYS}
