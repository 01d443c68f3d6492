"""The sections of ``report.md`` on the paper's own analyses and on the robots: the paper's
mixed ANOVA, the simple effects of human, Tukey HSD as the paper ran it, the Wilcoxon checks,
Cronbach's alpha and Figure 1 (results ``paper``), and every other robot against the
reference (results ``robots``). Each is a function of the results alone and returns its
lines, or none when the run has nothing for it; the renderers of the paper's registered tests
(:mod:`cirl_study.analysis.results.registry`) take their rows and the results and return the lines
below their headings.
"""

from __future__ import annotations

from cirl_study.analysis.report import markdown as md
from cirl_study.analysis.report.sections import FIGURE1, ROBOTS_LAMBDA, heading
from cirl_study.analysis.report.study_sections import anova_table
from cirl_study.analysis.results.claims import SIGNIFICANCE
from cirl_study.analysis.results.types import (
    AnovaEffect,
    PairedDifference,
    RobotComparison,
    SimpleEffect,
    StudyResults,
    Table,
    TukeyRow,
    WilcoxonRow,
)


def paper_anova(rows: Table[AnovaEffect], results: StudyResults) -> list[str]:
    """The paper's mixed ANOVA, on the reference robot's trials of its two humans (in the
    paper's own design, the ANOVA of the whole design)."""
    return [
        f"On the trials of `expert` and `best_response` watched by "
        f"`{results.design.reference_robot}`, per measure: within subjects `human`, "
        "between subjects `num_features` (a subject is one reward draw, at one feature level "
        "only). With two humans sphericity holds, so the p-values are uncorrected. The "
        "paper's claims are judged on it.",
        "",
        anova_table(rows),
    ]


def simple_effects(rows: Table[SimpleEffect], results: StudyResults) -> list[str]:
    """The paired simple effects of human within each feature level."""
    columns: list[md.Column] = [
        "measure",
        "num_features",
        "n",
        "mean_expert",
        "mean_best_response",
        "mean_diff",
        lambda row: md.interval(row.ci95_low, row.ci95_high),
        lambda row: md.interval(row.boot_diff_low, row.boot_diff_high),
        lambda row: f"t({row.df}) = {md.number(row.t)}",
        "p_holm",
        lambda row: f"{md.number(row.d_z)} {md.interval(row.boot_d_z_low, row.boot_d_z_high, 3)}",
    ]
    header = [
        "measure",
        "features",
        "n",
        "expert",
        "best response",
        "difference",
        "95% CI (t)",
        "95% CI (bootstrap)",
        "paired t",
        "p (Holm)",
        "d_z [bootstrap CI]",
    ]
    return [
        "Paired t-tests of the difference best response minus expert (negative: the best "
        "response did better) within each feature level, Holm-adjusted over the feature "
        "levels of each measure; `d_z` = mean difference / SD of the differences; bootstrap "
        "intervals are BCa with a fixed seed.",
        "",
        md.table(
            header,
            md.formatted(rows, columns),
            [False, True, True, True, True, True, True, True, True, True, True],
        ),
    ]


def tukey(rows: Table[TukeyRow], results: StudyResults) -> list[str]:
    """Tukey HSD over the human x features cells, as the paper ran it."""

    def cell(side: str) -> md.Column:
        def label(row: TukeyRow) -> str:
            human = getattr(row, f"{side}_human")
            return f"{md.name(human)}, {getattr(row, f'{side}_num_features')}"

        return label

    columns = [
        "measure", cell("a"), cell("b"), "diff", "se", "T",
        lambda row: md.p_text(row.log10_p_tukey), "hedges",
    ]  # fmt: skip
    header = ["measure", "cell A", "cell B", "mean A − mean B", "SE", "T", "p (Tukey)", "Hedges g"]
    return [
        "As the paper ran it: all pairs of the human × features cells, error pooled over the "
        "cells. **This ignores the pairing** of the two humans within a reward draw, so it "
        "treats within-subject comparisons as if they were between independent groups; the "
        "simple effects above are the paired analysis. Cells are named `human, features`. "
        "p (Tukey) is the studentized range's upper tail computed in log space without "
        "cancellation, accurate to about 1e-13 relative, also below the smallest double "
        "(scipy's tail, used by pingouin, is 0 from q = 10.5 on).",
        "",
        md.table(
            header, md.formatted(rows, columns), [False, False, False, True, True, True, True, True]
        ),
    ]


def wilcoxon(rows: Table[WilcoxonRow], results: StudyResults) -> list[str]:
    """The Wilcoxon signed-rank checks of the simple effects."""
    columns: list[md.Column] = ["measure", "num_features", "n", "W", "p", "rbc", "cles"]
    header = ["measure", "features", "n", "W", "p", "rank-biserial r", "CLES"]
    return [
        "Non-parametric check of the simple effects: best response against expert, paired.",
        "",
        md.table(header, md.formatted(rows, columns), [False, True, True, True, True, True, True]),
    ]


def cronbach(results: StudyResults) -> list[str]:
    """Cronbach's alpha across the three measures, raw and standardised."""
    alpha = results.paper.cronbach_alpha
    rows = [
        ["raw", md.number(alpha.raw), md.interval(*alpha.ci95)],
        [
            "standardised",
            md.number(alpha.standardised),
            md.interval(*alpha.ci95_standardised),
        ],
    ]
    return [
        heading(3, "paper.cronbach_alpha"),
        "",
        f"Across the measures {', '.join(alpha.items)}; rows: {alpha.rows}. "
        "Standardised alpha uses z-scored measures; intervals are Feldt's.",
        "",
        md.table(["alpha", "value", "95% CI"], rows, [False, True, True]),
    ]


def figure1(results: StudyResults) -> list[str]:
    """Figure 1: the true reward and both demonstrations of one typical reward draw."""
    chosen = results.paper.figure1
    name = FIGURE1.file
    return [
        heading(2, "paper.figure1"),
        "",
        md.image("Figure 1: true reward and both demonstrations over their MAP rewards", name),
        "",
        f"Reward draw `{chosen.subject}` ({chosen.num_features} features), chosen as "
        f"{chosen.rule}: regret {md.number(chosen.regret_expert)} after the expert's "
        f"demonstration, {md.number(chosen.regret_best_response)} after the best response's. "
        "Left: the true reward of each cell; middle and right: each demonstration (from the "
        "white dot to the white square) over the MAP reward the robot inferred from it; crosses: "
        "RBF centers.",
    ]


def _robot_verdict(row: PairedDifference) -> str:
    """``better``, ``worse`` (Holm-adjusted p below :data:`SIGNIFICANCE`) or ``no difference``."""
    if row.p_holm is None or row.p_holm >= SIGNIFICANCE:
        return "no difference"
    return "better" if row.mean_diff < 0 else "worse"


def _robot_sweep_summary(robots: RobotComparison, humans: list[str]) -> list[str]:
    """Per other robot, feature level and human, the lambdas at which the other robot's
    regret is lower, and those at which it is higher, than the reference's."""
    regret = [row for row in robots.lambda_sweep if row.measure == "regret"]
    lines = []
    for other in robots.others:
        for level in sorted({row.num_features for row in regret}):
            for human in humans:
                cell = [
                    r
                    for r in regret
                    if r.level == other and r.num_features == level and r.human == human
                ]
                better, worse = (
                    ", ".join(f"{r.rationality:g}" for r in cell if _robot_verdict(r) == verdict)
                    or "none"
                    for verdict in ("better", "worse")
                )
                lines.append(
                    f"- `{other}`, {md.name(human)}, {level} features: lower regret at λ = "
                    f"{better}; higher at λ = {worse}."
                )
    return lines


def robots(results: StudyResults) -> list[str]:
    """Every other robot against the reference, paired, in the main block and the sweep."""
    compared = results.robots
    if compared is None:
        return []
    reference, others = compared.reference, compared.others
    named = ", ".join(f"`{other}`" for other in others)
    lambdas = ", ".join(f"{value:g}" for value in results.design.main_rationality)
    main_regret = [row for row in compared.main if row.measure == "regret"]
    answers = [
        f"- `{row.level}`, {md.name(row.human)}, {row.num_features} features: "
        f"{_robot_verdict(row)} (regret {md.number(row.mean_level)} against "
        f"{md.number(row.mean_baseline)}; difference {md.number(row.mean_diff)} "
        f"{md.interval(row.ci95_low, row.ci95_high)}, Holm p {md.p_value(row.p_holm)})"
        for row in main_regret
    ]
    paired_columns: list[md.Column] = [
        "measure",
        "num_features",
        lambda row: md.name(row.human),
        "level",
        "n",
        "mean_baseline",
        "mean_level",
        "mean_diff",
        lambda row: md.interval(row.ci95_low, row.ci95_high),
        lambda row: f"t({row.df}) = {md.number(row.t)}",
        "p_holm",
        "d_z",
    ]
    paired_header = [
        "measure", "features", "human", "robot", "n", reference, "robot's mean", "difference",
        "95% CI (t)", "paired t", "p (Holm)", "d_z",
    ]  # fmt: skip
    lines = [
        heading(2, "robots"),
        "",
        f"Does {named} beat `{reference}`, for which human, at which λ? The robots watch "
        "the very same demonstrations (the robot is a within-subjects factor; η is "
        f"cross-validated with `{reference}`), so every comparison below is paired by reward "
        f"draw. Differences are the robot minus `{reference}`: negative means the robot did "
        f"better. The paper's analyses are computed on `{reference}`'s trials alone; the "
        "ANOVA of the whole design, robot within subjects, is above. Verdicts: Holm-adjusted "
        f"p < {SIGNIFICANCE:g}.",
        "",
        f"At the main block's λ = {lambdas}, against `{reference}` on regret:",
        "",
        *answers,
        "",
        "### Paired differences in the main block",
        "",
        "Holm-adjusted over the feature levels, humans and robots of each measure.",
        "",
        md.table(
            paired_header,
            md.formatted(compared.main, paired_columns),
            [False, True, False, False, *[True] * 8],
        ),
    ]
    if not compared.lambda_sweep:
        return [*lines, "", "This run has no trials in the `lambda_sweep` block."]
    regret = [row for row in compared.lambda_sweep if row.measure == "regret"]
    sweep_columns: list[md.Column] = [
        lambda row: f"{row.rationality:g}",
        *paired_columns[1:9],
        "p_holm",
    ]
    file_name = ROBOTS_LAMBDA.file
    return [
        *lines,
        "",
        "### Across the lambda sweep",
        "",
        f"Regret against `{reference}`, Holm-adjusted over the whole sweep (KL and L2 are in "
        "`results.json`, `robots.lambda_sweep`):",
        "",
        *_robot_sweep_summary(compared, results.design.humans),
        "",
        md.table(
            ["λ", *paired_header[1:9], "p (Holm)"],
            md.formatted(regret, sweep_columns),
            [True, True, False, False, *[True] * 6],
        ),
        "",
        md.image("Regret difference of the robots against lambda", file_name),
    ]
