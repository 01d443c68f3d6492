"""The sections of ``report.md`` that every study has, whatever its humans, robots and feature
levels: the cell means, the repeated-measures ANOVA with its sphericity corrections, every
pairwise comparison, every human against the baseline, the lambda sweep and the eta
cross-validation. Each is a function of the results alone (:mod:`cirl_study.analysis.results.study`)
and returns its lines, or none when the run has nothing for it; a registered test's renderer
(:mod:`cirl_study.analysis.results.registry`) takes its rows and the results and returns the lines
below its heading.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import Any

from cirl_study.analysis.report.markdown import (
    ci,
    formatted,
    image,
    interval,
    name,
    number,
    p_text,
    p_value,
    table,
)
from cirl_study.analysis.report.sections import (
    CELL_MEANS,
    ETA_CV_CURVE,
    FIGURE2_LAMBDA,
    FIGURE2_MEASURES,
    OTHER_MEASURES,
    heading,
)
from cirl_study.analysis.results.cells import papers_own
from cirl_study.analysis.results.types import (
    AnovaEffect,
    EtaUncertainty,
    PairedComparison,
    PairedDifference,
    StudyResults,
    Table,
)
from cirl_study.measure_registry import PAPER_MEASURES, analysed_measures
from cirl_study.record import LAMBDA_SWEEP


def paper_only(results: StudyResults) -> bool:
    """Whether the run's design is the paper's own (:func:`.cells.papers_own`)."""
    return papers_own(results.design.humans, results.design.robots)


def other_measures(measures: Iterable[str]) -> tuple[str, ...]:
    """The measures the analysis tests beyond the paper's three that are among ``measures``
    (those of a study's cells), in the registry's order: those the figure beside Figure 2 (left)
    draws (:data:`~cirl_study.analysis.report.sections.OTHER_MEASURES`)."""
    present = set(measures)
    return tuple(m for m in analysed_measures() if m not in PAPER_MEASURES and m in present)


def cells(results: StudyResults) -> list[str]:
    """The cell means; the paper's Figure 2 (left) and the figure of the other measures beside
    it, and, beyond the paper's design, the cell figure of every human and robot."""
    figures = []
    if results.paper is not None:
        file_name = FIGURE2_MEASURES.file
        robot = results.design.reference_robot
        figures += [
            "",
            image(
                "Figure 2, left: the three measures by human and number of features "
                f"(robot {robot})",
                file_name,
            ),
        ]
        if other_measures(row.measure for row in results.cells if row.robot == robot):
            file_name = OTHER_MEASURES.file
            figures += [
                "",
                image(
                    f"The other measures by human and number of features (robot {robot})",
                    file_name,
                ),
            ]
    if not paper_only(results):
        file_name = CELL_MEANS.file
        figures += ["", image("Every measure by human, robot and number of features", file_name)]
    return [
        heading(3, "cells"),
        "",
        table(
            ["measure", "features", "human", "robot", "n", "mean", "95% CI (t)"],
            formatted(
                results.cells,
                [
                    "measure", "num_features", lambda r: name(r.human), "robot", "n", "mean",
                    ci,
                ],
            ),
            [False, True, False, False, True, True, True],
        ),
        *figures,
    ]  # fmt: skip


def _corrected(row: AnovaEffect, key: str) -> str:
    sphericity = row.sphericity
    if sphericity is None or getattr(sphericity, f"{key}_epsilon") is None:
        return "–"
    epsilon = number(getattr(sphericity, f"{key}_epsilon"), 3)
    return f"{p_text(getattr(sphericity, key).log10_p)} (ε {epsilon})"


def _mauchly(row: AnovaEffect) -> str:
    sphericity = row.sphericity
    if sphericity is None or sphericity.mauchly_w is None:
        return "–"
    w = number(sphericity.mauchly_w, 3)
    return f"{w} ({p_text(sphericity.mauchly.log10_p)})"


def anova_table(rows: Sequence[AnovaEffect]) -> str:
    """An ANOVA table: effect, degrees of freedom, F, p, both effect sizes, and Mauchly's test
    with the corrected p-values where any effect has them."""
    columns: list = [
        "measure", "effect", lambda r: f"{r.df1}, {r.df2}", "F",
        lambda r: p_text(r.log10_p),
    ]  # fmt: skip
    header = ["measure", "effect", "df", "F", "p"]
    if any(row.sphericity is not None for row in rows):
        columns += [_mauchly, lambda r: _corrected(r, "gg"), lambda r: _corrected(r, "hf")]
        header += ["Mauchly W (p)", "p (GG)", "p (HF)"]
    columns += ["np2", "ges"]
    header += ["partial η²", "generalised η²"]
    return table(header, formatted(rows, columns), [False, False, *[True] * (len(header) - 2)])


def anova(rows: Table[AnovaEffect], results: StudyResults) -> list[str]:
    """The repeated-measures ANOVA of every human (and robot) and feature level, beyond the
    paper's design (where it is the paper's mixed ANOVA)."""
    if paper_only(results):
        return []
    within = "`human`" + (", `robot`" if results.design.robots[1:] else "")
    between = (
        ", between subjects `num_features` (a subject is one reward draw, at one feature level "
        "only)"
        if results.design.feature_levels[1:]
        else ""
    )
    return [
        f"Per measure: within subjects {within}{between}. For a within effect on two degrees "
        "of freedom or more, Mauchly's test of sphericity and the p-values corrected by the "
        "Greenhouse-Geisser and Huynh-Feldt epsilons (Huynh-Feldt capped at 1); with two "
        "levels per within factor sphericity holds, so the p-values are uncorrected.",
        "",
        anova_table(rows),
    ]


def pairwise(rows: Table[PairedComparison], results: StudyResults) -> list[str]:
    """Every pair of humans (and of robots) in every cell of the other factors, beyond the
    paper's design (where it is the simple effects of human)."""
    if not rows or paper_only(results):
        return []

    def cell(row: PairedComparison) -> str:
        if row.factor == "human":
            return f"robot `{row.robot}`"
        return f"human `{row.human}`"

    return [
        "Every pair of humans (and of robots) within each cell of the other factors, paired "
        "by reward draw: `a - b` (negative: `a` did better); Holm over each measure's rows "
        "of one factor.",
        "",
        table(
            ["measure", "features", "in", "a", "b", "n", "a - b", "95% CI (t)", "t", "p",
             "p (Holm)", "d_z"],
            formatted(
                rows,
                [
                    "measure", "num_features", cell, "level_a", "level_b", "n", "mean_diff",
                    ci, "t", lambda r: p_text(r.log10_p),
                    lambda r: p_text(r.log10_p_holm), "d_z",
                ],
            ),
            [False, True, False, False, False, True, True, True, True, True, True, True],
        ),
    ]  # fmt: skip


def _features(row: PairedDifference) -> str:
    """A row's feature level, or what it is pooled over (``all``)."""
    return number(row.num_features) if row.pooled is None else row.pooled


def paired_table(rows: Sequence[PairedDifference], group: str, label: str) -> str:
    """Paired differences of ``label`` against its baseline per ``group`` and feature level
    (or pooled over the levels)."""
    return table(
        [
            "measure", group, "features", label, "n", "mean difference", "95% CI", "t", "p",
            "p (Holm)", "d_z",
        ],
        formatted(
            rows,
            [
                "measure", group, _features, "level", "n", "mean_diff", ci, "t",
                "p", "p_holm", "d_z",
            ],
        ),
        [False, False, True, False, True, True, True, True, True, True, True],
    )  # fmt: skip


def against_baseline(rows: Table[PairedDifference], results: StudyResults) -> list[str]:
    """Every human against the baseline."""
    if not rows:
        return []
    baseline = results.design.baseline
    return [
        f"Paired by reward draw: the human's measure minus `{baseline}`'s (negative: the "
        "human did better), per robot and number of features; Holm over each measure's rows.",
        "",
        paired_table(rows, "robot", "human"),
    ]


def grid_table(
    rows: Sequence[Any], x: str, x_label: str, columns: Sequence[tuple[str, Callable[[Any], bool]]]
) -> str:
    """One row per value of the field ``x`` of ``rows`` (rows of means with their CIs), in
    order; one column per selector of ``columns``: ``mean [CI]`` of the first row at that value
    it selects, an en dash where it selects none."""
    lines = []
    for value in sorted({getattr(row, x) for row in rows}):
        at = [row for row in rows if getattr(row, x) == value]
        shown = []
        for _, select in columns:
            match = next((row for row in at if select(row)), None)
            shown.append(
                "–"
                if match is None
                else f"{number(match.mean)} {interval(match.ci95_low, match.ci95_high, 3)}"
            )
        lines.append([f"{value:g}", *shown])
    header = [x_label, *(label for label, _ in columns)]
    return table(header, lines, [True] * len(header))


def lambda_sweep(results: StudyResults) -> list[str]:
    """Mean regret of every human at each rationality, with the reference robot."""
    lines = [heading(2, "lambda_sweep"), ""]
    if not results.lambda_sweep:
        return [*lines, "This run has no trials in the `lambda_sweep` block."]
    robot = results.design.reference_robot
    regret = results.lambda_sweep.filter(lambda row: row.measure == "regret" and row.robot == robot)
    columns = [
        (
            f"{name(human)}, {level}",
            lambda row, level=level, human=human: row.num_features == level and row.human == human,
        )
        for level in sorted({row.num_features for row in regret})
        for human in results.design.humans
    ]
    figure = []
    if results.paper is not None:
        file_name = FIGURE2_LAMBDA.file
        figure = ["", image("Figure 2, right: regret against lambda", file_name)]
    others = " and of every other robot" if results.design.robots[1:] else ""
    return [
        *lines,
        f"Mean regret [95% CI] of each human at each rationality λ the robot `{robot}` "
        f"assumes (columns: `human, features`); KL and L2{others} at every λ are in "
        "`results.json` (`lambda_sweep`).",
        "",
        grid_table(regret, "rationality", "λ", columns),
        "",
        _certification(results),
        *figure,
    ]


def _certification(results: StudyResults) -> str:
    """One sentence: at which lambdas the reference robot could not certify every estimate."""
    short = [
        f"{row.converged} of {row.trials} at λ = {number(row.rationality)}"
        for row in results.converged
        if row.block == LAMBDA_SWEEP
        and row.robot == results.design.reference_robot
        and row.converged < row.trials
    ]
    if not short:
        return "Every estimate of the sweep converged to within 1e-6 of the MAP."
    return (
        "Estimates converged to within 1e-6 of the MAP (the others lie where the likelihood is "
        "flat to double-precision rounding in some direction, and stay where the robot "
        f"stopped): {'; '.join(short)}; every other λ: all."
    )


def _eta_check(results: StudyResults) -> str:
    """One sentence: whether the main block was played with the cross-validated eta."""
    faults = [
        f"η = {', '.join(f'{eta:g}' for eta in row.main_etas) or '–'} at "
        f"{row.num_features} features "
        + (
            "(not cross-validated)"
            if row.chosen_eta is None
            else f"(cross-validated: η = {row.chosen_eta:g})"
        )
        for row in results.eta_cv.main_block
        if not row.agree
    ]
    if not faults:
        return "The main block used the cross-validated η."
    return (
        "**The main block's best response was not played with the cross-validated η**: "
        f"{'; '.join(faults)}."
    )


def _eta_uncertainty(rows: Sequence[EtaUncertainty]) -> list[str]:
    """Per feature level, how clear-cut the chosen eta is (one bullet each)."""
    lines = ["How clear-cut each choice is:", ""]
    for row in rows:
        one_se = ", ".join(f"{eta:g}" for eta in row.within_one_se)
        text = (
            f"- {row.num_features} features: η = {row.eta:g} (mean regret "
            f"{number(row.mean)}, standard error {number(row.se)}, {row.n} draws)"
        )
        if row.runner_up is not None:
            separated = row.ci95_low > 0
            text += (
                f" against the runner-up η = {row.runner_up:g} "
                f"({number(row.runner_up_mean)}): paired difference "
                f"{number(row.mean_diff)} {interval(row.ci95_low, row.ci95_high)}, "
                f"p {p_value(row.p)}, "
                + ("the runner-up is worse" if separated else "not distinguishable")
            )
        lines.append(
            f"{text}. By the one-standard-error rule (means within one standard error of the "
            f"lowest) η ∈ {{{one_se}}} are all as good."
        )
    return lines


def eta_cv(results: StudyResults) -> list[str]:
    """The cross-validation of the best response's eta."""
    lines = [heading(2, "eta_cv"), ""]
    if not results.eta_cv.means:
        return [*lines, "This run has no trials in the `eta_cv` block."]
    means = results.eta_cv.means
    columns = [
        (f"{level} features", lambda row, level=level: row.num_features == level)
        for level in sorted({row.num_features for row in means})
    ]
    chosen = ", ".join(
        f"η = {row.eta:g} at {row.num_features} features (mean regret {number(row.mean)})"
        for row in results.eta_cv.chosen
    )
    file_name = ETA_CV_CURVE.file
    return [
        *lines,
        f"Mean best-response regret [95% CI] per η, on reward draws disjoint from the main "
        f"block's. Chosen (lowest mean regret): {chosen}. {_eta_check(results)}",
        "",
        *_eta_uncertainty(results.eta_cv.uncertainty),
        "",
        grid_table(means, "eta", "η", columns),
        "",
        image("eta cross-validation", file_name),
    ]
