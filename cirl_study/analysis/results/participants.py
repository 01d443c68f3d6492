"""The people of a run: participants' demonstrations, watched by the robots, analysed alike.

A run with ``[participants]`` (:mod:`cirl_study.study.participants`) has, beside the simulated
humans' trials, the ``recorded`` human's: one per participant, task (and condition, within)
and robot. Each participant is a subject. :func:`participants_section` computes, per measure
the analysis tests (:func:`~cirl_study.measure_registry.analysed_measures`):

* ``cells``: the mean with its t-based 95% CI per condition, robot and task, and per
  condition and robot of each participant's mean over her tasks (``task`` null); ``means``,
  those participants' means;
* ``anova``: the mixed ANOVA of the complete participants (every task, in every condition of a
  within design): ``task`` (and ``robot``, with two robots or more) within, ``condition``
  between participants (``design = "between"``) or within (``"within"``)
  (:func:`~cirl_study.analysis.statistics.anova.repeated_measures_anova`, sphericity tested
  and corrected; sums of squares of type 2, or 3 where ``participants.sums_of_squares`` says);
* ``conditions``: every condition against the baseline, per robot, on each participant's mean
  over her tasks: Welch's t-test between participants, the paired t-test within, Holm over
  the measure's rows;
* ``robots``: with two robots or more, every other robot against the first, paired by
  participant on her mean over her tasks, per condition (Holm per measure);
* ``cronbach_alpha``: of the paper's three measures, over the participants' trials;
* ``closest``: for each participant, which simulated human of the run her demonstrations
  are closest to, task by task: the L1 distance of the paths' feature counts
  ``sum_{t >= 1} phi(s_t)`` (the quantity MaxEnt IRL matches) and the Jaccard overlap of
  their cells (:class:`~cirl_study.analysis.results.types.ClosestModel`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Literal

import numpy as np
import pandas as pd
from scipy import stats

from cirl_study.analysis.results.per_measure import measured
from cirl_study.analysis.results.types import (
    AnovaEffect,
    ClosestModel,
    ConditionCell,
    ConditionDifference,
    CronbachAlpha,
    PairedDifference,
    ParticipantMean,
    ParticipantsDesign,
    ParticipantsSection,
    Table,
)
from cirl_study.analysis.statistics import procedures
from cirl_study.analysis.statistics.anova import repeated_measures_anova
from cirl_study.analysis.statistics.tails import t_tail
from cirl_study.measure_registry import PAPER_MEASURES
from cirl_study.record import MAIN, Cell, TrialRow
from cirl_study.study.spec import Pipeline

CONFIDENCE = 0.95


def people(table: pd.DataFrame) -> pd.DataFrame:
    """The ``main`` block's trials of participants (rows of the trial table)."""
    if "participant" not in table:
        return table.iloc[0:0]
    return table[(table["block"] == MAIN) & table["participant"].notna()]


def participants_section(
    trials: Sequence[TrialRow], table: pd.DataFrame, pipeline: Pipeline
) -> ParticipantsSection | None:
    """The people's section of the results (the module docstring); ``None`` for a run
    without participants."""
    spec = pipeline.participants
    frame = people(table)
    if spec is None or frame.empty:
        return None
    robots = [robot for robot in pipeline.main.robots if robot in set(frame["robot"])]
    tasks = [task.name for task in pipeline.tasks or () if task.name in set(frame["task"])]
    complete, left_out = _complete(frame, spec.within)
    per_condition = frame.groupby("condition")["participant"].nunique()
    kept = complete.groupby("condition")["participant"].nunique()
    design = ParticipantsDesign(
        conditions=list(spec.conditions),
        baseline=spec.conditions[0],
        design=spec.design,
        sums_of_squares=spec.sums_of_squares,
        tasks=tasks,
        robots=robots,
        participants={c: int(per_condition.get(c, 0)) for c in spec.conditions},
        complete={c: int(kept.get(c, 0)) for c in spec.conditions},
        left_out=left_out,
    )
    cells, means = Table(ConditionCell), Table(ParticipantMean)
    conditions, robot_pairs = Table(ConditionDifference), Table(PairedDifference)
    for measure, kept in measured(frame):
        averaged = _participant_means(kept, measure)
        cells += procedures.group_mean_rows(
            kept, measure, ["condition", "robot", "task"], ConditionCell
        )
        cells += procedures.group_mean_rows(
            averaged, measure, ["condition", "robot"], ConditionCell
        )
        means += _means(averaged, measure)
        conditions += _conditions(averaged, measure, spec.conditions, spec.within)
        if len(robots) > 1:
            robot_pairs += procedures.paired_differences(
                averaged, measure, "robot", robots[0], ["condition"]
            )
    return ParticipantsSection(
        design=design,
        cells=cells,
        means=means,
        anova=_anova(complete, spec.within, len(robots) > 1, spec.sums_of_squares),
        conditions=conditions,
        robots=robot_pairs,
        cronbach_alpha=_alpha(frame),
        closest=_closest(trials, pipeline),
    )


def _complete(frame: pd.DataFrame, within: bool) -> tuple[pd.DataFrame, list[str]]:
    """The trials of the participants with a trial in every cell of task x robot (x
    condition, within) that the run's participants play, and the ids of the others."""
    factors = ["task", "robot"] + (["condition"] if within else [])
    cells = frame[factors].drop_duplicates().shape[0]
    counts = frame.groupby("subject").size()
    full = counts[counts == cells].index
    return frame[frame["subject"].isin(full)], sorted(set(counts.index) - set(full))


def _participant_means(frame: pd.DataFrame, measure: str) -> pd.DataFrame:
    """Each participant's mean of ``measure`` over her tasks, per condition and robot."""
    keys = ["subject", "condition", "robot"]
    return frame.groupby(keys, as_index=False, sort=True)[measure].mean()


def _means(averaged: pd.DataFrame, measure: str) -> Table[ParticipantMean]:
    """The rows of ``averaged`` (:func:`_participant_means` of ``measure``)."""
    records = averaged.rename(columns={measure: "mean"}).to_dict(orient="records")
    return Table(ParticipantMean, (ParticipantMean(measure=measure, **row) for row in records))


def _anova(
    complete: pd.DataFrame, within: bool, robots: bool, sums_of_squares: Literal[2, 3]
) -> Table[AnovaEffect]:
    """The mixed ANOVA of each measure on the complete participants (see the module
    docstring); none where fewer than two participants are complete in some condition."""
    rows = Table(AnovaEffect)
    factors = ["task"] + (["robot"] if robots else []) + (["condition"] if within else [])
    between = () if within else ("condition",)
    sizes = complete.groupby("condition")["subject"].nunique()
    if complete.empty or sizes.min() < 2 or (within and len(sizes) < 2):
        return rows
    for measure, kept in measured(complete):
        rows += repeated_measures_anova(
            kept, measure, factors, between, sums_of_squares=sums_of_squares
        )
    return rows


def _alpha(frame: pd.DataFrame) -> CronbachAlpha | None:
    """Cronbach's alpha of the paper's three measures over the participants' trials that have
    all three; none with fewer than two such trials."""
    items = frame[list(PAPER_MEASURES)].dropna().reset_index(drop=True)
    if len(items) < 2:
        return None
    rows = (
        f"all {len(items)} trials of the participants (every condition, task and robot), one "
        "row per trial, the three measures on their own scales"
    )
    return procedures.cronbach_alpha(items, rows)


def _conditions(
    averaged: pd.DataFrame, measure: str, conditions: Sequence[str], within: bool
) -> Table[ConditionDifference]:
    """Every condition against the baseline, per robot, on the participants' means of
    ``measure`` (``averaged``; see the module docstring), Holm over the rows."""
    rows = Table(ConditionDifference)
    baseline = conditions[0]
    found = []
    for robot, group in averaged.groupby("robot", sort=False):
        for level in conditions[1:]:
            if within:
                paired = group.pivot(index="subject", columns="condition", values=measure)
                both = paired.reindex(columns=[baseline, level]).dropna()
                first, second = both[level].to_numpy(), both[baseline].to_numpy()
            else:
                first = group.loc[group["condition"] == level, measure].to_numpy()
                second = group.loc[group["condition"] == baseline, measure].to_numpy()
            found.append((robot, level, _difference(first, second, within)))
    adjusted = procedures.holm(np.array([test["p"] for _, _, test in found]))
    log10 = procedures.holm_log10(np.array([test["log10_p"] for _, _, test in found]))
    for (robot, level, test), p_holm, log10_p_holm in zip(found, adjusted, log10, strict=True):
        rows.append(
            ConditionDifference(
                measure=measure,
                robot=str(robot),
                level=level,
                baseline=baseline,
                paired=within,
                **test,
                p_holm=float(p_holm),
                log10_p_holm=float(log10_p_holm),
            )
        )
    return rows


def _difference(level: np.ndarray, baseline: np.ndarray, paired: bool) -> dict[str, float]:
    """The test of ``mean(level) - mean(baseline)``: paired (``d_z``) or Welch's (Cohen's d
    on the pooled SD); NaN where a sample is too small to test."""
    nan = math.nan
    out = {
        "n_baseline": len(baseline),
        "n_level": len(level),
        "mean_baseline": float(baseline.mean()) if len(baseline) else nan,
        "mean_level": float(level.mean()) if len(level) else nan,
    }
    if paired:
        test = procedures.paired_t(level, baseline)
        return {**out, **{k: getattr(test, k) for k in (
            "mean_diff", "ci95_low", "ci95_high", "t", "p", "log10_p")},
            "df": float(test.df), "d": test.d_z}  # fmt: skip
    diff = out["mean_level"] - out["mean_baseline"]
    if len(level) < 2 or len(baseline) < 2:
        return {**out, "mean_diff": diff, "ci95_low": nan, "ci95_high": nan, "t": nan,
                "df": nan, "p": nan, "log10_p": nan, "d": nan}  # fmt: skip
    with procedures.undefined_as_nan():
        test = stats.ttest_ind(level, baseline, equal_var=False)
        interval = test.confidence_interval(CONFIDENCE)
    n1, n2 = len(level), len(baseline)
    pooled = math.sqrt(
        ((n1 - 1) * level.var(ddof=1) + (n2 - 1) * baseline.var(ddof=1)) / (n1 + n2 - 2)
    )
    t, df = float(test.statistic), float(test.df)
    return {
        **out,
        "mean_diff": diff,
        "ci95_low": float(interval.low),
        "ci95_high": float(interval.high),
        "t": t,
        "df": df,
        "p": float(test.pvalue),
        "log10_p": t_tail(t, df)[1] if math.isfinite(t) else nan,
        "d": diff / pooled if pooled > 0 else nan,
    }


def _closest(trials: Sequence[TrialRow], pipeline: Pipeline) -> Table[ClosestModel]:
    """Each participant's closest simulated human (the module docstring), from the paths of
    the ``main`` block's trials (one per demonstration: any robot's)."""
    features = pipeline.game.tile_features
    models: dict[tuple[str, str], tuple[Cell, ...]] = {}
    shown: dict[tuple[str, str], dict[str, tuple[Cell, ...]]] = {}
    condition_of: dict[str, str] = {}
    for row in trials:
        if row.block != MAIN or row.path is None:
            continue
        if row.participant is None:
            models.setdefault((row.human, str(row.task)), row.path)
        else:
            key = (row.participant, str(row.condition))
            shown.setdefault(key, {})[str(row.task)] = row.path
            condition_of[row.participant] = str(row.condition)
    humans = list(dict.fromkeys(human for human, _ in models))
    rows = Table(ClosestModel)
    if features is None or not humans:
        return rows
    width = pipeline.game.width
    phi = features.matrix(width, pipeline.game.height, np.exp)

    def counts(path: tuple[Cell, ...]) -> np.ndarray:
        return phi[[y * width + x for x, y in path[1:]]].sum(axis=0)

    for (participant, condition), by_task in shown.items():
        distance, overlap = {}, {}
        for human in humans:
            pairs = [(path, models[human, task]) for task, path in by_task.items()
                     if (human, task) in models]  # fmt: skip
            if not pairs:
                continue
            distance[human] = float(np.mean(
                [np.abs(counts(a) - counts(b)).sum() for a, b in pairs]))  # fmt: skip
            overlap[human] = float(np.mean(
                [len(set(a) & set(b)) / len(set(a) | set(b)) for a, b in pairs]))  # fmt: skip
        if distance:
            closest = min(distance, key=lambda h: (distance[h], -overlap[h]))
            rows.append(
                ClosestModel(
                    participant=participant,
                    condition=condition,
                    closest=closest,
                    distance=distance,
                    overlap=overlap,
                )
            )
    return rows
