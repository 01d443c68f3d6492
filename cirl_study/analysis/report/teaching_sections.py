"""The teaching sections of ``report.md``: Milli & Dragan's 2 x 2, the paper's best response
against the pedagogic human, and every human against the regret-optimal demonstration
(:mod:`cirl_study.analysis.results.teaching`). Each is a function of the results alone and returns
its lines, or none when the run lacks the section's cells.
"""

from __future__ import annotations

from cirl_study.analysis.report.markdown import ci, formatted, table
from cirl_study.analysis.report.sections import heading
from cirl_study.analysis.report.study_sections import anova_table, paired_table
from cirl_study.analysis.results.types import StudyResults


def _section(key: str, *blocks: str) -> list[str]:
    """The section of ``key``: its heading, then ``blocks`` (paragraphs, tables), a blank line
    between each."""
    lines = [heading(2, key)]
    for block in blocks:
        lines += ["", block]
    return lines


def milli_dragan(results: StudyResults) -> list[str]:
    """The 2 x 2 of human {literal, pedagogic} x robot {literal_observer, pragmatic}."""
    square = results.milli_dragan
    if square is None:
        return []
    return _section(
        "milli_dragan",
        "Repeated-measures ANOVA per measure: human (`literal`, `pedagogic`) and robot "
        "(`literal_observer`, `pragmatic`) within subjects, the number of features between.",
        anova_table(square.anova),
        "The robot's simple effect, `pragmatic - literal_observer`, under each human (negative: "
        "the pragmatic robot does better), pooled over the feature levels and at each:",
        paired_table([*square.robot_effect, *square.robot_effect_by_level], "human", "robot"),
    )


def versus(results: StudyResults) -> list[str]:
    """The best response minus the pedagogic human, per robot and feature level."""
    versus = results.best_response_vs_pedagogic
    if versus is None:
        return []
    return _section(
        "best_response_vs_pedagogic",
        "Paired by reward draw: `best_response - pedagogic` (negative: the best response "
        "teaches better), per robot and number of features.",
        paired_table(versus, "robot", "human"),
    )


def regret_optimal(results: StudyResults) -> list[str]:
    """Every human's regret gap to the regret-optimal demonstration, MAP robot."""
    optimal = results.regret_optimal
    if optimal is None:
        return []
    return _section(
        "regret_optimal",
        "With the MAP robot, each human's regret minus that of the best demonstration the "
        "regret-optimal search found for the same reward draw (`regret_optimal`, "
        "cirl_study.core.teaching). The search starts from the expert's path, the best "
        "response at every eta of the cross-validation grid and the pedagogic human's most "
        "telling paths, then improves by single-move changes; so the gap is a lower bound on "
        "the distance to the true optimum, never negative for the expert or the best response.",
        table(
            ["K", "human", "n", "mean regret", "regret-optimal", "gap", "95% CI", "p",
             "smallest gap", "as good as the best found"],
            formatted(
                optimal.gaps,
                [
                    "num_features", "human", "n", "mean_human", "mean_regret_optimal",
                    "mean_gap", ci, "p", "smallest_gap",
                    lambda g: f"{100 * g.share_optimal:.1f}%",
                ],
            ),
            [True, False, True, True, True, True, True, True, True, True],
        ),
    )  # fmt: skip
