"""Every number of a study's report: any humans x robots x feature levels, analysed alike.

:func:`analyse_study` takes the rows of a run whose ``main`` block plays every human policy
of ``main.policies`` (within subjects) with every robot of ``main.robots`` (within subjects)
at every feature level (between subjects), any number of each (at least two cells in all),
and returns plain JSON-ready data, all measures being losses (lower is better):

* ``cells``: each measure's mean with its t-based 95% CI per feature level, human and robot
  (:func:`cirl_study.analysis.statistics.group_means`);
* ``anova``: per measure, the repeated-measures ANOVA with ``policy`` (and ``robot``, with
  two robots or more) within subjects and ``num_features`` between (with two levels or
  more): Mauchly's test and the Greenhouse-Geisser and Huynh-Feldt corrections for every
  within effect on two degrees of freedom or more
  (:func:`cirl_study.analysis.anova.repeated_measures_anova`);
* ``pairwise``: per measure and within factor, every pair of its levels in every cell of the
  other factors, paired by subject, Holm over the measure's and factor's rows
  (:func:`cirl_study.analysis.statistics.pairwise_differences`);
* ``against_baseline``: per robot and feature level, each human against the baseline, the
  pipeline's first human (:func:`cirl_study.analysis.statistics.paired_differences`; Holm
  over the family of a measure);
* where the run has their cells, the teaching questions' numbers: ``milli_dragan``, the 2 x 2
  of Milli & Dragan (2019), human {literal, pedagogic} x robot {literal, pragmatic}: its
  split-plot ANOVA and the simple effect of the robot, ``pragmatic - literal``, under each
  human, pooled over the feature levels and at each (paired t, Holm);
  ``best_response_vs_pedagogic``: per robot and feature level, ``best_response -
  pedagogic``, paired (Holm); ``regret_optimal``: with the MAP robot, every human's regret
  gap to the regret-optimal demonstration, ``regret(human) - regret(regret_optimal)``, per
  feature level (paired t, its smallest value, and the share of subjects at which the
  human's demonstration is as good as the best found);
* ``questions``: the questions the study answers, each with what we measured and a verdict
  by a fixed rule (:data:`ALPHA` = .05 on Holm-adjusted p-values), or not tested when the
  run lacks a question's cells.

Milli & Dragan's result has two parts. The *crossover*: the pragmatic robot beats the literal
one with a pedagogic human and loses to it with a literal human (both simple effects
significant, in those directions). *Robustness*: averaged over the two humans the literal
robot does better, i.e. what the pragmatic robot loses under a misspecified (literal) human
exceeds what it gains under the human it assumes: the ANOVA's robot main effect, significant
with the literal robot ahead.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import msgspec
import numpy as np
import pandas as pd

from cirl_study.analysis import statistics
from cirl_study.analysis.anova import repeated_measures_anova
from cirl_study.analysis.claims import MEASURE_NAMES
from cirl_study.analysis.results import eta_cv, plain, rows
from cirl_study.analysis.table import trial_table
from cirl_study.errors import UserError
from cirl_study.logs.run_checks import design_faults
from cirl_study.record import (
    BEST_RESPONSE,
    ETA_CV,
    EXPERT,
    LAMBDA_SWEEP,
    LITERAL,
    LITERAL_ROBOT,
    MAIN,
    MAP,
    MEASURES,
    PEDAGOGIC,
    PRAGMATIC,
    REGRET_OPTIMAL,
    TrialRow,
)
from cirl_study.study.spec import Pipeline

ALPHA = 0.05
"""Significance level of every verdict (on Holm-adjusted p-values within a measure)."""

SAME_REGRET = 1e-9
"""Regret gap (absolute) below which a demonstration counts as good as the best found: the
MAP robot certifies its estimate to 1e-6, and two demonstrations with the same visit class
give the same estimate bit for bit."""


def check_study_design(rows_: Sequence[TrialRow]) -> None:
    """Refuse trials whose design the analysis cannot use (one line, every fault).

    The run's design must be sound (:func:`cirl_study.logs.run_checks.design_faults`: among
    others, a non-empty ``main`` block complete within subjects), with at least two cells of
    humans x robots x feature levels.
    """
    faults = design_faults(rows_)
    main = [row for row in rows_ if row.block == MAIN]
    cells = {(row.policy, row.robot, row.num_features) for row in main}
    if main and len(cells) < 2:
        faults.append("the main block has one cell (one human, one robot, one feature level)")
    if faults:
        raise UserError(f"the run's design cannot be analysed: {'; '.join(faults)}")


def analyse_study(trials: Sequence[TrialRow], pipeline: Pipeline) -> dict[str, Any]:
    """Every number of the study's report (see the module docstring), JSON-ready."""
    check_study_design(trials)
    table = trial_table(trials)
    main = table[table["block"] == MAIN]
    humans = [p for p in pipeline.main.policies if p in set(main["policy"])]
    robots = [r for r in pipeline.main.robots if r in set(main["robot"])]
    levels = sorted(int(k) for k in main["num_features"].unique())
    teaching = pipeline.teaching
    baseline = humans[0]
    results: dict[str, Any] = {
        "pipeline": pipeline.name,
        "design": {
            "humans": humans,
            "baseline": baseline,
            "robots": robots,
            "feature_levels": levels,
            "subjects_per_level": {
                str(k): int(main.loc[main["num_features"] == k, "subject"].nunique())
                for k in levels
            },
            "trials": {block: int(n) for block, n in table["block"].value_counts().items()},
            "rationality": pipeline.main.rationality,
            "teaching": None if teaching is None else vars(teaching),
        },
        "eta_cv": eta_cv(trials, table) if (table["block"] == ETA_CV).any() else None,
        "cells": rows(
            pd.concat(
                statistics.group_means(main, m, ["num_features", "policy", "robot"])
                for m in MEASURES
            )
        ),
        "anova": _anova(main, [f for f, n in (("policy", humans), ("robot", robots)) if n[1:]]),
        "pairwise": [
            msgspec.to_builtins(row)
            for m in MEASURES
            for factor, order in (("policy", humans), ("robot", robots))
            if len(order) > 1
            for row in statistics.pairwise_differences(main, m, factor, order)
        ],
        "against_baseline": _paired(main, "policy", baseline, ["robot", "num_features"])
        if len(humans) > 1
        else [],
    }
    if {LITERAL, PEDAGOGIC} <= set(humans) and {LITERAL_ROBOT, PRAGMATIC} <= set(robots):
        results["milli_dragan"] = _milli_dragan(main)
    if {BEST_RESPONSE, PEDAGOGIC} <= set(humans):
        pair = main[main["policy"].isin([BEST_RESPONSE, PEDAGOGIC])]
        results["best_response_vs_pedagogic"] = _paired(
            pair, "policy", PEDAGOGIC, ["robot", "num_features"]
        )
    if REGRET_OPTIMAL in humans and MAP in robots:
        results["regret_optimal"] = _regret_optimal(main[main["robot"] == MAP])
    sweep = table[table["block"] == LAMBDA_SWEEP]
    if not sweep.empty:
        by = ["rationality", "policy", "robot", "num_features"]
        results["lambda_sweep"] = rows(
            pd.concat(statistics.group_means(sweep, m, by) for m in MEASURES)
        )
    results["questions"] = _questions(results)
    return plain(results)


def _anova(frame: pd.DataFrame, within: list[str]) -> list[dict[str, Any]]:
    """:func:`~cirl_study.analysis.anova.repeated_measures_anova` of every measure, with
    ``num_features`` between subjects where the frame has two levels or more of it."""
    between = "num_features" if frame["num_features"].nunique() > 1 else None
    return [
        msgspec.to_builtins(row)
        for m in MEASURES
        for row in repeated_measures_anova(frame, m, within, between)
    ]


def _paired(frame: pd.DataFrame, factor: str, baseline: str, by: list[str]) -> list[dict]:
    """:func:`~cirl_study.analysis.statistics.paired_differences` for every measure, one Holm
    family per measure."""
    return rows(
        pd.concat(statistics.paired_differences(frame, m, factor, baseline, by) for m in MEASURES)
    )


def _milli_dragan(main: pd.DataFrame) -> dict[str, Any]:
    """The 2 x 2 of human {literal, pedagogic} x robot {literal, pragmatic}."""
    square = main[
        main["policy"].isin([LITERAL, PEDAGOGIC]) & main["robot"].isin([LITERAL_ROBOT, PRAGMATIC])
    ]
    pooled = square.assign(pooled="all")
    return {
        "anova": _anova(square, ["policy", "robot"]),
        "robot_effect": _paired(pooled, "robot", LITERAL_ROBOT, ["policy", "pooled"]),
        "robot_effect_by_level": _paired(
            square, "robot", LITERAL_ROBOT, ["policy", "num_features"]
        ),
    }


def _regret_optimal(with_map: pd.DataFrame) -> dict[str, Any]:
    """Each human's regret gap to the regret-optimal demonstration (MAP robot), per level."""
    gaps = []
    for (level,), group in with_map.groupby(["num_features"], sort=True):
        paired = group.pivot(index="subject", columns="policy", values="regret").sort_index()
        best = paired[REGRET_OPTIMAL].to_numpy()
        for human in paired.columns:
            if human == REGRET_OPTIMAL:
                continue
            gap = paired[human].to_numpy() - best
            test = statistics.paired_differences(
                group[group["policy"].isin([human, REGRET_OPTIMAL])],
                "regret",
                "policy",
                REGRET_OPTIMAL,
                ["num_features"],
            ).iloc[0]
            gaps.append(
                {
                    "num_features": int(level),
                    "policy": human,
                    "n": len(gap),
                    "mean_regret_optimal": float(best.mean()),
                    "mean_policy": float(paired[human].mean()),
                    "mean_gap": float(gap.mean()),
                    "ci95_low": float(test["ci95_low"]),
                    "ci95_high": float(test["ci95_high"]),
                    "p": float(test["p"]),
                    "smallest_gap": float(gap.min()),
                    "share_optimal": float(np.mean(np.abs(gap) <= SAME_REGRET)),
                }
            )
    return {"gaps": gaps}


def _effect(rows_: list[dict], measure: str, **where: Any) -> dict[str, Any]:
    """The one row of ``rows_`` for ``measure`` that matches ``where``."""
    found = [
        r for r in rows_ if r["measure"] == measure and all(r.get(k) == v for k, v in where.items())
    ]
    if len(found) != 1:
        raise ValueError(f"expected one row for {measure} {where}, found {len(found)}")
    return found[0]


def _signed(row: dict[str, Any], sign: int) -> bool:
    """Significant (Holm) with ``mean_diff`` of the given sign."""
    return bool(row["p_holm"] < ALPHA and np.sign(row["mean_diff"]) == sign)


def _questions(results: dict[str, Any]) -> list[dict[str, Any]]:
    """The study's questions with a fixed-rule verdict each (``None`` when not played)."""
    questions = [_paper_question(results)]
    square = results.get("milli_dragan")
    if square is not None:
        questions += _milli_dragan_questions(square)
    versus = results.get("best_response_vs_pedagogic")
    if versus is not None:
        questions.append(_versus_question(versus, results["design"]["robots"]))
    optimal = results.get("regret_optimal")
    if optimal is not None:
        questions.append(_optimal_question(optimal))
    return questions


def _paper_question(results: dict[str, Any]) -> dict[str, Any]:
    """The paper's own claim, replayed here: best response beats expert (MAP robot)."""
    robots = results["design"]["robots"]
    robot = MAP if MAP in robots else robots[0]
    effects = [
        _effect(r_rows, m, robot=robot, num_features=k, level=BEST_RESPONSE)
        for m in MEASURES
        for k in results["design"]["feature_levels"]
        for r_rows in [results["against_baseline"]]
        if results["design"]["baseline"] == EXPERT and BEST_RESPONSE in results["design"]["humans"]
    ]
    holds = bool(effects) and all(_signed(e, -1) for e in effects)
    return {
        "id": "paper_best_response",
        "question": f"Does the best response beat the expert on every measure and level "
        f"(robot {robot}), as the paper finds?",
        "measured": "; ".join(
            f"{MEASURE_NAMES[e['measure']]} at K={e['num_features']}: {e['mean_diff']:.4g} "
            f"(p_holm {e['p_holm']:.3g})"
            for e in effects
        )
        or "not played",
        "tested": bool(effects),
        "holds": holds,
    }


def _milli_dragan_questions(square: dict[str, Any]) -> list[dict[str, Any]]:
    crossover, robust, measured_cross, measured_robust = {}, {}, [], []
    for m in MEASURES:
        with_pedagogic = _effect(square["robot_effect"], m, policy=PEDAGOGIC)
        with_literal = _effect(square["robot_effect"], m, policy=LITERAL)
        crossover[m] = _signed(with_pedagogic, -1) and _signed(with_literal, 1)
        measured_cross.append(
            f"{MEASURE_NAMES[m]}: pragmatic - literal robot {with_pedagogic['mean_diff']:.4g} "
            f"(p_holm {with_pedagogic['p_holm']:.3g}) with a pedagogic human, "
            f"{with_literal['mean_diff']:.4g} (p_holm {with_literal['p_holm']:.3g}) with a "
            "literal one"
        )
        anova = _effect(square["anova"], m, effect="robot")
        mean_effect = (with_pedagogic["mean_diff"] + with_literal["mean_diff"]) / 2
        robust[m] = bool(anova["p"] < ALPHA and mean_effect > 0)
        measured_robust.append(
            f"{MEASURE_NAMES[m]}: mean pragmatic - literal {mean_effect:.4g}, robot "
            f"F({anova['df1']}, {anova['df2']}) = {anova['F']:.4g}, p = {anova['p']:.3g}"
        )
    return [
        {
            "id": "milli_dragan_crossover",
            "question": "Does the pragmatic robot win with a pedagogic human and lose with a "
            "literal one (Milli & Dragan 2019)?",
            "measured": "; ".join(measured_cross),
            "tested": True,
            "holds": all(crossover.values()),
            "by_measure": crossover,
        },
        {
            "id": "milli_dragan_robustness",
            "question": "Is the literal robot the more robust choice: does the pragmatic "
            "robot lose more with a literal human than it gains with a pedagogic one?",
            "measured": "; ".join(measured_robust),
            "tested": True,
            "holds": all(robust.values()),
            "by_measure": robust,
        },
    ]


def _versus_question(versus: list[dict], robots: list[str]) -> dict[str, Any]:
    ahead: dict[str, str] = {}
    measured = []
    for row in versus:
        key = f"{row['measure']}:{row['robot']}:{row['num_features']}"
        if row["p_holm"] >= ALPHA:
            ahead[key] = "neither"
        else:
            ahead[key] = BEST_RESPONSE if row["mean_diff"] < 0 else PEDAGOGIC
        if row["measure"] == "regret":
            measured.append(
                f"robot {row['robot']}, K={row['num_features']}: best response - pedagogic "
                f"{row['mean_diff']:.4g} (p_holm {row['p_holm']:.3g})"
            )
    return {
        "id": "best_response_vs_pedagogic",
        "question": "How does the paper's best response compare with the pedagogic human "
        f"(robots {', '.join(robots)})?",
        "measured": "regret: " + "; ".join(measured),
        "tested": True,
        "holds": None,
        "ahead": ahead,
    }


def _optimal_question(optimal: dict[str, Any]) -> dict[str, Any]:
    gaps = [g for g in optimal["gaps"] if g["policy"] == BEST_RESPONSE]
    return {
        "id": "regret_optimal_gap",
        "question": "How far is the best response from the regret-optimal demonstration "
        "(MAP robot)?",
        "measured": "; ".join(
            f"K={g['num_features']}: regret {g['mean_policy']:.4g} vs "
            f"{g['mean_regret_optimal']:.4g}, gap {g['mean_gap']:.4g} "
            f"[{g['ci95_low']:.4g}, {g['ci95_high']:.4g}], "
            f"as good as the best found for {100 * g['share_optimal']:.1f}% of draws"
            for g in gaps
        )
        or "the best response was not played",
        "tested": bool(gaps),
        "holds": None,
    }
