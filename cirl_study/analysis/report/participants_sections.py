"""The people's section of ``report.md``: the participants of a run with ``[participants]``
(:mod:`cirl_study.analysis.results.participants`), a function of the results alone.
"""

from __future__ import annotations

from collections import Counter

from cirl_study.analysis.report.markdown import ci, formatted, interval, name, number, table
from cirl_study.analysis.report.sections import heading
from cirl_study.analysis.report.study_sections import anova_table, paired_table
from cirl_study.analysis.results.types import StudyResults


def participants(results: StudyResults) -> list[str]:
    """The participants: design, means per condition, the mixed ANOVA, each condition against
    the baseline, and which model human each participant's demonstrations are closest to."""
    people = results.participants
    if people is None:
        return []
    design = people.design
    counts = ", ".join(f"{design.participants[c]} {c}" for c in design.conditions)
    complete = ", ".join(f"{design.complete[c]} {c}" for c in design.conditions)
    between = design.design == "between"
    factors = "task" + (" and robot" if len(design.robots) > 1 else "") + " within"
    factors += ", condition between participants" if between else " and condition within"
    lines = [
        heading(2, "participants"),
        "",
        f"Participants: {counts} (conditions {', '.join(design.conditions)}, baseline "
        f"{design.baseline}; {design.design} participants; type {design.sums_of_squares} sums "
        "of squares); each task a reward of the "
        f"pipeline ({len(design.tasks)}: {', '.join(design.tasks)}); watched by "
        f"{', '.join(name(r) for r in design.robots)}. Complete (every task): {complete}"
        + (f"; left out of the ANOVA: {len(design.left_out)}." if design.left_out else "."),
        "",
        "Each participant's mean over her tasks, by condition and robot:",
        "",
        table(
            ["measure", "condition", "robot", "n", "mean", "95% CI"],
            formatted(
                [cell for cell in people.cells if cell.task is None],
                ["measure", "condition", "robot", "n", "mean", ci],
            ),
            [False, False, False, True, True, True],
        ),
    ]
    if people.anova:
        lines += [
            "",
            f"Mixed ANOVA per measure of the complete participants: {factors}.",
            "",
            anova_table(people.anova),
        ]
    test = "Welch's t-test" if between else "the paired t-test"
    lines += [
        "",
        f"Each condition against {design.baseline}, on each participant's mean over her tasks "
        f"({test}; d: {'Cohen' if between else 'd_z'}; Holm per measure):",
        "",
        table(
            ["measure", "robot", "condition", "n", "mean", f"n {design.baseline}",
             f"mean {design.baseline}", "difference", "95% CI", "t", "df", "p", "d", "Holm p"],
            formatted(
                people.conditions,
                ["measure", "robot", "level", "n_level", "mean_level", "n_baseline",
                 "mean_baseline", "mean_diff", ci, "t", lambda r: number(r.df), "p", "d",
                 "p_holm"],
            ),
            [False, False, False, *[True] * 11],
        ),
    ]  # fmt: skip
    if people.robots:
        lines += [
            "",
            f"Every robot against {name(design.robots[0])}, paired by participant on her mean "
            "over her tasks, per condition (Holm per measure):",
            "",
            paired_table(people.robots, "condition", "robot"),
        ]
    alpha = people.cronbach_alpha
    if alpha is not None:
        lines += [
            "",
            f"Cronbach's alpha of the paper's three measures over {alpha.rows}: raw "
            f"{number(alpha.raw)} (95% CI {interval(*alpha.ci95)}), standardised "
            f"{number(alpha.standardised)} (95% CI {interval(*alpha.ci95_standardised)}).",
        ]
    if people.closest:
        tally = Counter((row.condition, row.closest) for row in people.closest)
        humans = sorted({human for row in people.closest for human in row.distance})
        lines += [
            "",
            "People beside the models: the simulated human whose demonstration of the same "
            "task is nearest to each participant's (L1 distance of the feature counts, mean "
            "over her tasks); participants per condition:",
            "",
            table(
                ["condition", *(name(h) for h in humans)],
                [
                    [c, *(str(tally[c, h]) for h in humans)]
                    for c in design.conditions
                    if any(row.condition == c for row in people.closest)
                ],
                [False, *[True] * len(humans)],
            ),
        ]
    return lines
