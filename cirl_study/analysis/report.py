"""The report of a run: ``report.md``, ``results.json``, ``trials.csv`` and the figures.

:func:`write_report` turns trial records into a directory that reads well on GitHub:
every claim of the paper with its verdict and links to the tables and figures that
support it. The output is a deterministic function of the records (their order does
not matter): no timestamps, no machine paths, and byte-identical files for identical
input.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from cirl_study.analysis import figures
from cirl_study.analysis.claims import MEASURE_NAMES, SIGNIFICANCE, evaluate_claims
from cirl_study.analysis.markdown import (
    anchor,
    document,
    image,
    interval,
    number,
    p_value,
    svg_name,
    table,
)
from cirl_study.analysis.output import csv_file, write_report_directory
from cirl_study.analysis.results import (
    Results,
    combined,
    estimates,
    plain,
    reference_main_block,
    tests,
)
from cirl_study.analysis.table import check_design, trial_table
from cirl_study.record import (
    BEST_RESPONSE,
    EXPERT,
    LAMBDA_SWEEP,
    MAIN,
    PAPER_POLICIES,
    TrialRecord,
    TrialRow,
)
from cirl_study.workers import Call

HEADINGS = {
    "claims": "Claims",
    "cells": "Cell means",
    "anova": "Mixed ANOVA",
    "simple_effects": "Simple effects of policy",
    "tukey_hsd": "Tukey HSD",
    "wilcoxon": "Wilcoxon signed-rank tests",
    "cronbach_alpha": "Cronbach's alpha",
    "lambda_sweep": "Lambda sweep",
    "eta_cv": "Eta cross-validation",
    "figure1": "Figure 1",
    "robots": "Robots",
    "rules": "How the verdicts are decided",
}
"""Section headings of ``report.md``, by the ``results.json`` key they present."""

FIGURES = {
    "figure1": ("figure1_reward_maps.png", "Figure 1"),
    "figure2_measures": ("figure2_measures.png", "Figure 2, left"),
    "figure2_lambda": ("figure2_lambda.png", "Figure 2, right"),
    "eta_cv_curve": ("eta_cv.png", "eta curve"),
    "robots": ("robots_lambda.png", "robots against lambda"),
}
"""File name and link text of each figure, by key."""

POLICY_NAMES = {"expert": "expert", "best_response": "best response"}
VERDICTS = {True: "✅ reproduced", False: "❌ not reproduced", None: "➖ not tested"}

P_VALUES = ("p", "p_holm", "p_tukey")
"""Fields of the results shown as p-values."""

Column = str | Callable[[Mapping[str, Any]], str]
"""A column of a statistics table: a field of the results, or a function of the row."""


def _link(key: str) -> str:
    if key in HEADINGS:
        return f"[{HEADINGS[key]}](#{anchor(HEADINGS[key])})"
    if key in FIGURES:
        name, label = FIGURES[key]
        return f"[{label}]({name})"
    return f"[{key}]({key})"


def _heading(level: int, key: str) -> str:
    return f"{'#' * level} {HEADINGS[key]}"


def formatted(rows: Sequence[Mapping[str, Any]], columns: Sequence[Column]) -> list[list[str]]:
    """The cells of ``rows``: a measure by its short name, a p-value, a text, or a number (every
    report's tables; a column is a field of the rows or a function of a row)."""

    def cell(row: Mapping[str, Any], column: Column) -> str:
        if callable(column):
            return column(row)
        value = row[column]
        if column == "measure":
            return MEASURE_NAMES[value]
        if column in P_VALUES:
            return p_value(value)
        return value if isinstance(value, str) else number(value)

    return [[cell(row, column) for column in columns] for row in rows]


def _verdict(claim: Mapping[str, Any]) -> str:
    return VERDICTS[claim["reproduced"] if claim["tested"] else None]


def _claims(results: Results) -> list[str]:
    rows = [
        [
            str(position),
            claim["claim"],
            claim["measurement"],
            _verdict(claim),
            ", ".join(_link(key) for key in claim["evidence"]),
        ]
        for position, claim in enumerate(results["claims"], start=1)
    ]
    header = ["#", "The paper says", "We measured", "Verdict", "Evidence"]
    return [
        _heading(2, "claims"),
        "",
        table(header, rows, [True, False, False, False, False]),
        "",
        f"Each verdict is computed from the data by a fixed rule; see "
        f"[{HEADINGS['rules']}](#{anchor(HEADINGS['rules'])}).",
    ]


def _cells(results: Results) -> list[str]:
    rows = [
        [
            MEASURE_NAMES[row["measure"]],
            str(row["num_features"]),
            POLICY_NAMES[row["policy"]],
            str(row["n"]),
            number(row["mean"]),
            interval(row["ci95_low"], row["ci95_high"]),
        ]
        for row in results["cells"]
    ]
    header = ["measure", "features", "policy", "n", "mean", "95% CI (t)"]
    name, _ = FIGURES["figure2_measures"]
    return [
        _heading(3, "cells"),
        "",
        table(header, rows, [False, True, False, True, True, True]),
        "",
        image("Figure 2, left: the three measures by policy and number of features", name),
    ]


def _anova_table(rows: Sequence[Mapping[str, Any]]) -> str:
    """An ANOVA table: effect, degrees of freedom, F, p and both effect sizes per row."""

    def degrees(row: Mapping[str, Any]) -> str:
        return f"{row['df1']}, {row['df2']}"

    cells = formatted(rows, ["measure", "effect", degrees, "F", "p", "np2", "ges"])
    header = ["measure", "effect", "df", "F", "p", "partial η²", "generalised η²"]
    return table(header, cells, [False, False, True, True, True, True, True])


def _anova(results: Results) -> list[str]:
    return [
        _heading(3, "anova"),
        "",
        "Per measure: within subjects `policy`, between subjects `num_features` (a subject is "
        "one reward draw, at one feature level only). With two policies sphericity holds, so "
        "the p-values are uncorrected.",
        "",
        _anova_table(results["anova"]),
    ]


def _simple_effects(results: Results) -> list[str]:
    columns: list[Column] = [
        "measure",
        "num_features",
        "n",
        "mean_expert",
        "mean_best_response",
        "mean_diff",
        lambda row: interval(row["ci95_low"], row["ci95_high"]),
        lambda row: interval(row["boot_diff_low"], row["boot_diff_high"]),
        lambda row: f"t({row['df']}) = {number(row['t'])}",
        "p_holm",
        lambda row: (
            f"{number(row['d_z'])} {interval(row['boot_d_z_low'], row['boot_d_z_high'], 3)}"
        ),
    ]
    rows = formatted(results["simple_effects"], columns)
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
        _heading(3, "simple_effects"),
        "",
        "Paired t-tests of the difference best response minus expert (negative: the best "
        "response did better) within each feature level, Holm-adjusted over the feature "
        "levels of each measure; `d_z` = mean difference / SD of the differences; bootstrap "
        "intervals are BCa with a fixed seed.",
        "",
        table(header, rows, [False, True, True, True, True, True, True, True, True, True, True]),
    ]


def _tukey(results: Results) -> list[str]:
    def cell(side: str) -> Column:
        return lambda row: f"{POLICY_NAMES[row[f'{side}_policy']]}, {row[f'{side}_num_features']}"

    columns = ["measure", cell("a"), cell("b"), "diff", "se", "T", "p_tukey", "hedges"]
    rows = formatted(results["tukey_hsd"], columns)
    header = ["measure", "cell A", "cell B", "mean A − mean B", "SE", "T", "p (Tukey)", "Hedges g"]
    return [
        _heading(3, "tukey_hsd"),
        "",
        "As the paper ran it: all pairs of the policy × features cells, error pooled over the "
        "cells. **This ignores the pairing** of the two policies within a reward draw, so it "
        "treats within-subject comparisons as if they were between independent groups; the "
        "simple effects above are the paired analysis. Cells are named `policy, features`. "
        "p (Tukey) is the studentized range's upper tail computed without cancellation, "
        "accurate to about 1e-13 relative wherever it is a normal double; `< 1e-300` means "
        "the true value is below 2.2e-308 (scipy's tail, used by pingouin, is 0 from q = 10.5 "
        "on).",
        "",
        table(header, rows, [False, False, False, True, True, True, True, True]),
    ]


def _wilcoxon(results: Results) -> list[str]:
    rows = formatted(results["wilcoxon"], ["measure", "num_features", "n", "W", "p", "rbc", "cles"])
    header = ["measure", "features", "n", "W", "p", "rank-biserial r", "CLES"]
    return [
        _heading(3, "wilcoxon"),
        "",
        "Non-parametric check of the simple effects: best response against expert, paired.",
        "",
        table(header, rows, [False, True, True, True, True, True, True]),
    ]


def _cronbach(results: Results) -> list[str]:
    alpha = results["cronbach_alpha"]
    rows = [
        ["raw", number(alpha["raw"]), interval(*alpha["ci95"])],
        ["standardised", number(alpha["standardized"]), interval(*alpha["ci95_standardized"])],
    ]
    return [
        _heading(3, "cronbach_alpha"),
        "",
        f"Across the measures {', '.join(alpha['items'])}; rows: {alpha['rows']}. "
        "Standardised alpha uses z-scored measures; intervals are Feldt's.",
        "",
        table(["alpha", "value", "95% CI"], rows, [False, True, True]),
    ]


def _grid_table(
    frame: pd.DataFrame, x: str, x_label: str, columns: Sequence[tuple[str, Callable]]
) -> str:
    """One row per value of ``x``, one column per selector in ``columns``: ``mean [CI]``."""
    rows = []
    for value in sorted(frame[x].unique()):
        at = frame[frame[x] == value]
        cells = []
        for _, select in columns:
            match = at[select(at)]
            cells.append(
                "–"
                if match.empty
                else f"{number(match['mean'].iloc[0])} "
                f"{interval(match['ci95_low'].iloc[0], match['ci95_high'].iloc[0], 3)}"
            )
        rows.append([f"{value:g}", *cells])
    header = [x_label, *(label for label, _ in columns)]
    return table(header, rows, [True] * len(header))


def _lambda_sweep(results: Results) -> list[str]:
    lines = [_heading(2, "lambda_sweep"), ""]
    if not results["lambda_sweep"]:
        return [*lines, "This run has no trials in the `lambda_sweep` block."]
    sweep = pd.DataFrame(results["lambda_sweep"])
    regret = sweep[sweep["measure"] == "regret"]
    columns = [
        (
            f"{POLICY_NAMES[policy]}, {level}",
            lambda at, level=level, policy=policy: (
                (at["num_features"] == level) & (at["policy"] == policy)
            ),
        )
        for level in sorted(regret["num_features"].unique())
        for policy in PAPER_POLICIES
    ]
    name, _ = FIGURES["figure2_lambda"]
    return [
        *lines,
        "Mean regret [95% CI] of each policy at each rationality λ the robot assumes "
        "(columns: `policy, features`); KL and L2 at every λ are in `results.json` "
        "(`lambda_sweep`).",
        "",
        _grid_table(regret, "rationality", "λ", columns),
        "",
        _certification(results),
        "",
        image("Figure 2, right: regret against lambda", name),
    ]


def _certification(results: Results) -> str:
    """One sentence: at which lambdas the robot could not certify every estimate."""
    short = [
        f"{row['certified']} of {row['trials']} at λ = {number(row['rationality'])}"
        for row in results["certified"]
        if row["block"] == LAMBDA_SWEEP
        and row["robot"] == results["design"]["reference_robot"]
        and row["certified"] < row["trials"]
    ]
    if not short:
        return "Every estimate of the sweep is certified within 1e-6 of the MAP."
    return (
        "Estimates certified within 1e-6 of the MAP (the others lie where the likelihood is "
        "flat to double-precision rounding in some direction, and stay where the robot "
        f"stopped): {'; '.join(short)}; every other λ: all."
    )


def _eta_check(results: Results) -> str:
    """One sentence: whether the main block was played with the cross-validated eta."""
    faults = [
        f"η = {', '.join(f'{eta:g}' for eta in row['main_etas']) or '–'} at "
        f"{row['num_features']} features "
        + (
            "(not cross-validated)"
            if row["chosen_eta"] is None
            else f"(cross-validated: η = {row['chosen_eta']:g})"
        )
        for row in results["eta_cv"]["main_block"]
        if not row["agree"]
    ]
    if not faults:
        return "The main block used the cross-validated η."
    return (
        "**The main block's best response was not played with the cross-validated η**: "
        f"{'; '.join(faults)}."
    )


def _eta_uncertainty(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """Per feature level, how clear-cut the chosen eta is (one bullet each)."""
    lines = ["How clear-cut each choice is:", ""]
    for row in rows:
        one_se = ", ".join(f"{eta:g}" for eta in row["within_one_se"])
        text = (
            f"- {row['num_features']} features: η = {row['eta']:g} (mean regret "
            f"{number(row['mean'])}, standard error {number(row['se'])}, {row['n']} draws)"
        )
        if row.get("runner_up") is not None:
            separated = row["ci95_low"] > 0
            text += (
                f" against the runner-up η = {row['runner_up']:g} "
                f"({number(row['runner_up_mean'])}): paired difference "
                f"{number(row['mean_diff'])} {interval(row['ci95_low'], row['ci95_high'])}, "
                f"p {p_value(row['p'])}, "
                + ("the runner-up is worse" if separated else "not distinguishable")
            )
        lines.append(
            f"{text}. By the one-standard-error rule (means within one standard error of the "
            f"lowest) η ∈ {{{one_se}}} are all as good."
        )
    return lines


def _eta_cv(results: Results) -> list[str]:
    lines = [_heading(2, "eta_cv"), ""]
    if not results["eta_cv"]["means"]:
        return [*lines, "This run has no trials in the `eta_cv` block."]
    means = pd.DataFrame(results["eta_cv"]["means"])
    columns = [
        (f"{level} features", lambda at, level=level: at["num_features"] == level)
        for level in sorted(means["num_features"].unique())
    ]
    chosen = ", ".join(
        f"η = {row['eta']:g} at {row['num_features']} features (mean regret {number(row['mean'])})"
        for row in results["eta_cv"]["chosen"]
    )
    name, _ = FIGURES["eta_cv_curve"]
    return [
        *lines,
        f"Mean best-response regret [95% CI] per η, on reward draws disjoint from the main "
        f"block's. Chosen (lowest mean regret): {chosen}. {_eta_check(results)}",
        "",
        *_eta_uncertainty(results["eta_cv"]["uncertainty"]),
        "",
        _grid_table(means, "eta", "η", columns),
        "",
        image("eta cross-validation", name),
    ]


def _figure1(results: Results) -> list[str]:
    chosen = results["figure1"]
    name, _ = FIGURES["figure1"]
    return [
        _heading(2, "figure1"),
        "",
        image("Figure 1: true reward and both demonstrations over their MAP rewards", name),
        "",
        f"Reward draw `{chosen['subject']}` ({chosen['num_features']} features), chosen as "
        f"{chosen['rule']}: regret {number(chosen['regret_expert'])} after the expert's "
        f"demonstration, {number(chosen['regret_best_response'])} after the best response's. "
        "Left: the true reward of each cell; middle and right: each demonstration (from the "
        "white dot to the white square) over the MAP reward the robot inferred from it; crosses: "
        "RBF centres.",
    ]


def _robot_verdict(row: Mapping[str, Any]) -> str:
    """``better``, ``worse`` (Holm-adjusted p below :data:`SIGNIFICANCE`) or ``no difference``."""
    if row["p_holm"] is None or row["p_holm"] >= SIGNIFICANCE:
        return "no difference"
    return "better" if row["mean_diff"] < 0 else "worse"


def _robot_sweep_summary(robots: Mapping[str, Any]) -> list[str]:
    """Per feature level and policy, the lambdas at which the other robot's regret is
    lower, and those at which it is higher, than the reference's."""
    regret = [row for row in robots["lambda_sweep"] if row["measure"] == "regret"]
    lines = []
    for level in sorted({row["num_features"] for row in regret}):
        for policy in PAPER_POLICIES:
            cell = [r for r in regret if r["num_features"] == level and r["policy"] == policy]
            found = {
                verdict: ", ".join(
                    f"{r['rationality']:g}" for r in cell if _robot_verdict(r) == verdict
                )
                or "none"
                for verdict in ("better", "worse")
            }
            lines.append(
                f"- {POLICY_NAMES[policy]}, {level} features: lower regret at λ = "
                f"{found['better']}; higher at λ = {found['worse']}."
            )
    return lines


def _robots(results: Results) -> list[str]:
    robots = results["robots"]
    if robots is None:
        return []
    reference, other = robots["reference"], robots["other"]
    lambdas = ", ".join(f"{value:g}" for value in results["design"]["main_rationality"])
    main_regret = [row for row in robots["main"] if row["measure"] == "regret"]
    answers = [
        f"- {POLICY_NAMES[row['policy']]}, {row['num_features']} features: "
        f"{_robot_verdict(row)} (regret {number(row['mean_level'])} against "
        f"{number(row['mean_baseline'])}; difference {number(row['mean_diff'])} "
        f"{interval(row['ci95_low'], row['ci95_high'])}, Holm p {p_value(row['p_holm'])})"
        for row in main_regret
    ]

    paired_columns: list[Column] = [
        "measure",
        "num_features",
        lambda row: POLICY_NAMES[row["policy"]],
        "n",
        "mean_baseline",
        "mean_level",
        "mean_diff",
        lambda row: interval(row["ci95_low"], row["ci95_high"]),
        lambda row: f"t({row['df']}) = {number(row['t'])}",
        "p_holm",
        "d_z",
    ]
    paired_header = [
        "measure", "features", "human", "n", reference, other, "difference", "95% CI (t)",
        "paired t", "p (Holm)", "d_z",
    ]  # fmt: skip
    lines = [
        _heading(2, "robots"),
        "",
        f"Does `{other}` beat `{reference}`, for which human, at which λ? Both robots watch "
        "the very same demonstrations (the robot is a within-subjects factor; η is "
        f"cross-validated with `{reference}`), so every comparison below is paired by reward "
        f"draw. Differences are `{other}` minus `{reference}`: negative means `{other}` did "
        f"better. Every other section of this report is computed on `{reference}`'s trials "
        f"alone. Verdicts: Holm-adjusted p < {SIGNIFICANCE:g}.",
        "",
        f"At the main block's λ = {lambdas}, `{other}` against `{reference}` on regret:",
        "",
        *answers,
        "",
        "### Mixed ANOVA: robot x policy x features",
        "",
        "Per measure, on the main block: within subjects `robot` and `policy`, between "
        "subjects `num_features`. With two levels per within factor sphericity holds, so the "
        "p-values are uncorrected.",
        "",
        _anova_table(robots["anova"]),
        "",
        "### Paired differences in the main block",
        "",
        "Holm-adjusted over the feature levels and policies of each measure.",
        "",
        table(
            paired_header,
            formatted(robots["main"], paired_columns),
            [False, True, False, *[True] * 8],
        ),
    ]
    if not robots["lambda_sweep"]:
        return [*lines, "", "This run has no trials in the `lambda_sweep` block."]
    regret = [row for row in robots["lambda_sweep"] if row["measure"] == "regret"]
    sweep_columns: list[Column] = [
        lambda row: f"{row['rationality']:g}",
        *paired_columns[1:8],
        "p_holm",
    ]
    name, _ = FIGURES["robots"]
    return [
        *lines,
        "",
        "### Across the lambda sweep",
        "",
        f"Regret of `{other}` against `{reference}`, Holm-adjusted over the whole sweep "
        "(KL and L2 are in `results.json`, `robots.lambda_sweep`):",
        "",
        *_robot_sweep_summary(robots),
        "",
        table(
            ["λ", *paired_header[1:8], "p (Holm)"],
            formatted(regret, sweep_columns),
            [True, True, False, *[True] * 6],
        ),
        "",
        image("Regret difference of the two robots against lambda", name),
    ]


def _rules(results: Results) -> list[str]:
    return [
        _heading(2, "rules"),
        "",
        *(
            f"- `{claim['id']}` ({claim['source']}): {claim['rule']}."
            for claim in results["claims"]
        ),
        "",
        "A claim is *not tested* when the run has no data for it. Every number of this report "
        "is in [`results.json`](results.json) at full precision; the trials are in "
        "[`trials.csv`](trials.csv). What made the run and this report (commit, date, "
        "platform, CPU, BLAS and package versions) is in [`provenance.json`](provenance.json).",
    ]


def _partial_title(results: Results) -> list[str]:
    """The report's first lines for a partial run: what it lacks."""
    partial = results.get("partial")
    if partial is None:
        return []
    lacks = [
        partial["missing"],
        f"{partial['damaged_files']} damaged file(s) salvaged" if partial["damaged_files"] else "",
        f"{partial['main_subjects_left_out']} main-block subject(s) without every cell left out"
        if partial["main_subjects_left_out"]
        else "",
    ]
    return [
        f"**PARTIAL RUN: {partial['logged']} of {partial['planned']} planned trials logged; "
        f"{'; '.join(text for text in lacks if text)}. Every number below is provisional.**",
        "",
    ]


def render_markdown(results: Results) -> str:
    """The text of ``report.md`` for ``results`` (with their ``claims``)."""
    trials = results["trials"]
    design = results["design"]
    per_level = ", ".join(f"{n} at {k} features" for k, n in design["subjects_per_level"].items())
    blocks = ", ".join(f"{n} in `{block}`" for block, n in trials.items() if block != "total")
    lambdas = ", ".join(f"{value:g}" for value in design["main_rationality"])
    etas = (
        "; ".join(
            f"{', '.join(f'{eta:g}' for eta in values)} at {level} features"
            for level, values in design["main_eta"].items()
            if values
        )
        or "–"
    )
    robots = results["robots"]
    compared = "" if robots is None else f" (and `{robots['other']}`: see {_link('robots')})"
    sections = [
        [
            *_partial_title(results),
            f"# Reproduction report: `{results['pipeline']}`",
            "",
            "Cooperative Inverse Reinforcement Learning (Hadfield-Menell et al., NeurIPS 2016), "
            "section 4: the paper's claims beside what this run measured.",
            "",
            f"Trials: {trials['total']} ({blocks}). Main study: reward draws {per_level}, each "
            f"under both policies; robot `{design['reference_robot']}`{compared}, rationality "
            f"λ = {lambdas}; best-response η = {etas}. All three measures are losses: lower is "
            "better.",
        ],
        _claims(results),
        ["## Main study"],
        _cells(results),
        _anova(results),
        _simple_effects(results),
        _tukey(results),
        _wilcoxon(results),
        _cronbach(results),
        _lambda_sweep(results),
        _eta_cv(results),
        _figure1(results),
        _robots(results),
        _rules(results),
    ]
    return document(sections)


def _figure1_records(
    trials: Sequence[TrialRow],
    records_of: Callable[[set[str]], Sequence[TrialRecord]],
    subject: str,
    robot: str,
) -> dict[str, TrialRecord]:
    """The ``main``-block records of ``subject`` watched by ``robot``, by policy."""
    wanted = {
        row.trial_id
        for row in trials
        if row.block == MAIN and row.subject == subject and row.robot == robot
    }
    found = {record.policy: record for record in records_of(wanted)}
    return {policy: found[policy] for policy in PAPER_POLICIES}


def _drawings(
    trials: Sequence[TrialRow],
    records_of: Callable[[set[str]], Sequence[TrialRecord]],
    estimated: Results,
) -> dict[str, Call]:
    """The drawing of every figure the estimates (:func:`~cirl_study.analysis.results.estimates`)
    support, by PNG name. Figure 1 draws two whole records, fetched by trial id with
    ``records_of``."""
    chosen = estimated["figure1"]
    pair = _figure1_records(trials, records_of, chosen["subject"], chosen["robot"])
    title = f"Reward draw {chosen['subject']} ({chosen['num_features']} features)"
    drawings: dict[str, Call] = {
        FIGURES["figure1"][0]: (figures.reward_maps, (pair[EXPERT], pair[BEST_RESPONSE], title)),
        FIGURES["figure2_measures"][0]: (
            figures.measure_bars,
            (pd.DataFrame(estimated["cells"]),),
        ),
    }
    if estimated["lambda_sweep"]:
        sweep = pd.DataFrame(estimated["lambda_sweep"])
        drawings[FIGURES["figure2_lambda"][0]] = (figures.lambda_curve, (sweep,))
    if estimated["eta_cv"]["means"]:
        drawings[FIGURES["eta_cv_curve"][0]] = (
            figures.eta_curve,
            (
                pd.DataFrame(estimated["eta_cv"]["means"]),
                pd.DataFrame(estimated["eta_cv"]["uncertainty"]),
            ),
        )
    robots = estimated["robots"]
    if robots is not None and robots["lambda_sweep"]:
        drawings[FIGURES["robots"][0]] = (
            figures.robot_difference_curve,
            (pd.DataFrame(robots["lambda_sweep"]), robots["reference"], robots["other"]),
        )
    return drawings


CSV_IN_MEMORY_ROWS = 200_000
"""Up to this many trials, trials.csv is made here while the figures are drawn in workers,
after the tests, whose end would otherwise leave this process waiting for the figures. Its
text costs about 150 bytes a trial, so a larger run's table is written row by row at the
end, which keeps the analysis of a million trials within 2 GB. (Made in a worker, it also
cost a copy of the table sent there, and added to the figures' work, which ends last.)"""


def write_report(
    trials: Sequence[TrialRow],
    out_dir: Path | str,
    pipeline_name: str,
    *,
    records_of: Callable[[set[str]], Sequence[TrialRecord]],
    run_id: str | None = None,
    theory: Mapping[str, Any] | None = None,
    provenance: Mapping[str, Any] | None = None,
    partial: Mapping[str, Any] | None = None,
    progress: Callable[[str], None] = lambda stage: None,
) -> Results:
    """Analyse a run's trials and write the report directory.

    Writes ``report.md``, ``results.json`` (every number at full precision), ``trials.csv``
    (the trial table) and the figures of :data:`FIGURES`, each as PNG and SVG, into
    ``out_dir`` (created if needed); a figure the run has no data for is not written, and a
    stale copy of it is removed. ``provenance`` (what made the run and the report) goes to
    ``provenance.json``, apart from the numbers, since it differs from machine to machine
    while they must not.

    Args:
        trials: the rows of the trial records (:class:`~cirl_study.record.TrialRow`), in
            any order.
        out_dir: the report directory.
        pipeline_name: the pipeline's name, shown in the report.
        records_of: the whole records of the given trial ids (for Figure 1), e.g. read
            back from the logs with :func:`cirl_study.logs.read_trials`.
        run_id: the run's id, stored as ``run_id`` in ``results.json``.
        theory: optional extra claims (see :func:`cirl_study.analysis.claims.external_claims`);
            stored under ``theory`` in ``results.json``.
        provenance: optional provenance, written as ``provenance.json``.
        partial: for a report on an incomplete run, what it lacks (``planned``, ``logged``,
            ``missing``, ``damaged_files``, ``main_subjects_left_out``); stored under
            ``partial`` in ``results.json`` and stated in the report's first line.
        progress: called with the name of each stage as it begins.

    Returns:
        The content of ``results.json``.

    Raises:
        UserError: the design cannot be analysed (see
            :func:`~cirl_study.analysis.table.check_design`).
    """
    check_design(trials)
    progress("statistics and figures")
    everything = trial_table(trials)
    estimated = estimates(trials, everything, pipeline_name)
    # The figures need only the estimates: they are drawn in workers while the tests, the
    # claims, the markdown and, up to CSV_IN_MEMORY_ROWS, trials.csv are made here.
    with figures.drawing(_drawings(trials, records_of, estimated)) as drawn:
        results = combined(estimated, tests(reference_main_block(everything)))
        results["run_id"] = run_id
        results["partial"] = None if partial is None else plain(partial)
        results["claims"] = evaluate_claims(results, theory)
        if theory is not None:
            results["theory"] = plain(theory)
        markdown = render_markdown(results)
        table = csv_file(everything) if len(everything) <= CSV_IN_MEMORY_ROWS else everything
        made = drawn()
    names = [n for png_name, _ in FIGURES.values() for n in (png_name, svg_name(png_name))]
    write_report_directory(
        out_dir,
        markdown=markdown,
        results=results,
        tables={"trials.csv": table},
        figures={name: made.get(name) for name in names},
        provenance=provenance,
    )
    return results
