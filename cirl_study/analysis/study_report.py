"""The report of a study of any humans x robots x feature levels: ``report.md``,
``results.json``, ``trials.csv``, a figure.

:func:`write_study_report` turns the rows of a run (:mod:`cirl_study.analysis.study`) into a
directory that reads well on GitHub: the study's questions with what we measured and a
verdict, the cell means of every human with every robot, the repeated-measures ANOVA with its
sphericity corrections, every pairwise comparison, each human against the baseline human,
and where the run has their cells Milli & Dragan's 2 x 2, the paper's best response against
the pedagogic human and against the regret-optimal demonstration, and the rationality sweep.
Like the paper report it is a deterministic function of the trials (their order does not
matter).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from cirl_study.analysis import figures
from cirl_study.analysis.markdown import document, image, interval, number, p_from_log10, table
from cirl_study.analysis.output import write_report_directory
from cirl_study.analysis.report import formatted
from cirl_study.analysis.results import Results
from cirl_study.analysis.study import ALPHA, analyse_study
from cirl_study.analysis.table import trial_table
from cirl_study.record import TrialRow
from cirl_study.study.spec import Pipeline

FIGURE = "cell_means.png"
"""The figure of every measure by human, robot and feature level."""


def _verdict(question: Mapping[str, Any]) -> str:
    if not question["tested"]:
        return "not tested"
    if question["holds"] is None:
        return "answer"
    return "✅ holds" if question["holds"] else "❌ does not hold"


def _header(results: Results) -> list[str]:
    design = results["design"]
    teaching = design["teaching"]
    subjects = ", ".join(f"{n} at K = {k}" for k, n in design["subjects_per_level"].items())
    space = ""
    if teaching:
        hypotheses = teaching["hypotheses"]
        members = (
            f"the true theta and {hypotheses - 1} prior draws"
            if teaching["includes_truth"]
            else "all prior draws, the true theta not among them"
        )
        shows = (
            "draws her demonstration"
            if teaching["demonstration"] == "draw"
            else "shows her most likely demonstration"
        )
        space = (
            f"{hypotheses} reward hypotheses per reward draw ({members}), pedagogic exponent "
            f"alpha = {number(teaching['alpha'])}, the pedagogic human {shows}"
        )
    trials = ", ".join(f"{n} in `{block}`" for block, n in sorted(design["trials"].items()))
    return [
        f"# Study: `{results['pipeline']}`",
        "",
        "Humans and robots on the gridworld of Hadfield-Menell et al. (2016, section 4.1) "
        "with the paper's measures, within subjects: every human demonstrates to every robot "
        "on the same reward draws; the number of features varies between them. All three "
        "measures are losses: lower is better.",
        "",
        f"- Humans: {', '.join(f'`{h}`' for h in design['humans'])} (baseline "
        f"`{design['baseline']}`); robots: "
        f"{', '.join(f'`{r}`' for r in design['robots'])}; rationality λ = "
        f"{number(design['rationality'])}.",
        f"- Reward draws: {subjects}. Trials: {trials}.",
        *([f"- Hypothesis space: {space}."] if teaching else []),
    ]


def _questions(results: Results) -> list[str]:
    return [
        "## Questions",
        "",
        table(
            ["question", "we measured", "verdict"],
            [[q["question"], q["measured"], _verdict(q)] for q in results["questions"]],
            [False, False, False],
        ),
        "",
        f"A verdict needs p < {ALPHA} after Holm's adjustment within a measure, in the "
        "direction asked; a question whose humans or robots the run does not play is not "
        "tested."
        + (
            " Milli & Dragan's result has two parts: the *crossover* (the pragmatic robot "
            "better with a pedagogic human, worse with a literal one) and *robustness* "
            "(averaged over both humans the literal robot is better: the robot main effect of "
            "the 2 x 2 ANOVA, literal ahead)."
            if "milli_dragan" in results
            else ""
        ),
    ]


def _cells(results: Results) -> list[str]:
    return [
        "## Cell means",
        "",
        table(
            ["measure", "K", "human", "robot", "n", "mean", "95% CI (t)"],
            formatted(
                results["cells"],
                ["measure", "num_features", "policy", "robot", "n", "mean", _interval],
            ),
            [False, True, False, False, True, True, True],
        ),
        "",
        image("Every measure by human, robot and number of features", FIGURE),
    ]


def _interval(row: Mapping[str, Any]) -> str:
    return interval(row["ci95_low"], row["ci95_high"])


def _paired_table(rows: Sequence[Mapping[str, Any]], group: str, label: str) -> str:
    """Paired differences of ``label`` against its baseline per ``group`` and feature level."""
    return table(
        [
            "measure", group, "K", label, "n", "mean difference", "95% CI", "t", "p",
            "p (Holm)", "d_z",
        ],
        formatted(
            rows,
            [
                "measure", group, "num_features", "level", "n", "mean_diff", _interval, "t",
                "p", "p_holm", "d_z",
            ],
        ),
        [False, False, True, False, True, True, True, True, True, True, True],
    )  # fmt: skip


def _against_baseline(results: Results) -> list[str]:
    if not results["against_baseline"]:
        return []
    baseline = results["design"]["baseline"]
    return [
        f"## Every human against the baseline, `{baseline}`",
        "",
        f"Paired by reward draw: the human's measure minus `{baseline}`'s (negative: the "
        "human teaches better), per robot and number of features; Holm over each measure's "
        "rows.",
        "",
        _paired_table(results["against_baseline"], "robot", "human"),
    ]


def _corrected(row: Mapping[str, Any], name: str) -> str:
    sphericity = row["sphericity"]
    if sphericity is None:
        return "–"
    epsilon = number(sphericity[f"{name}_epsilon"], 3)
    return f"{p_from_log10(sphericity[name]['log10_p'])} (ε {epsilon})"


def _anova(results: Results) -> list[str]:
    if not results["anova"]:
        return []
    return [
        "## Repeated-measures ANOVA",
        "",
        "Per measure: human (and robot) within subjects, the number of features between. "
        "For a within effect on two degrees of freedom or more, Mauchly's test of sphericity "
        "and the p-values corrected by the Greenhouse-Geisser and Huynh-Feldt epsilons "
        "(Huynh-Feldt capped at 1); `ges` is the generalised eta squared.",
        "",
        table(
            [
                "measure", "effect", "df", "F", "p", "Mauchly W (p)", "p (GG)", "p (HF)",
                "partial η²", "ges",
            ],
            formatted(
                results["anova"],
                [
                    "measure", "effect", lambda r: f"{r['df1']}, {r['df2']}", "F",
                    lambda r: p_from_log10(r["log10_p"]),
                    lambda r: "–" if r["sphericity"] is None else (
                        f"{number(r['sphericity']['mauchly_w'], 3)} "
                        f"({p_from_log10(r['sphericity']['mauchly']['log10_p'])})"
                    ),
                    lambda r: _corrected(r, "gg"), lambda r: _corrected(r, "hf"), "np2", "ges",
                ],
            ),
            [False, False, True, True, True, True, True, True, True, True],
        ),
    ]  # fmt: skip


def _pairwise(results: Results) -> list[str]:
    if not results["pairwise"]:
        return []

    def cell(row: Mapping[str, Any]) -> str:
        other = "robot" if row["factor"] == "policy" else "human"
        return f"{other} `{row['robot'] if other == 'robot' else row['policy']}`"

    return [
        "## Pairwise comparisons",
        "",
        "Every pair of humans (and of robots) within each cell of the other factors, paired "
        "by reward draw: `a - b` (negative: `a` does better); Holm over each measure's rows "
        "of one factor.",
        "",
        table(
            ["measure", "K", "in", "a", "b", "n", "a - b", "95% CI", "t", "p", "p (Holm)", "d_z"],
            formatted(
                results["pairwise"],
                [
                    "measure", "num_features", cell, "level_a", "level_b", "n", "mean_diff",
                    _interval, "t", lambda r: p_from_log10(r["log10_p"]),
                    lambda r: p_from_log10(r["log10_p_holm"]), "d_z",
                ],
            ),
            [False, True, False, False, False, True, True, True, True, True, True, True],
        ),
    ]  # fmt: skip


def _lambda_sweep(results: Results) -> list[str]:
    sweep = results.get("lambda_sweep")
    if not sweep:
        return []
    return [
        "## The rationality sweep",
        "",
        "Each measure's mean (95% CI, t) per rationality λ, human, robot and number of features.",
        "",
        table(
            ["measure", "λ", "K", "human", "robot", "n", "mean", "95% CI (t)"],
            formatted(
                sweep,
                [
                    "measure",
                    "rationality",
                    "num_features",
                    "policy",
                    "robot",
                    "n",
                    "mean",
                    _interval,
                ],
            ),
            [False, True, True, False, False, True, True, True],
        ),
    ]


def _milli_dragan(results: Results) -> list[str]:
    square = results.get("milli_dragan")
    if square is None:
        return []
    anova = table(
        ["measure", "effect", "df", "F", "p", "partial η²"],
        formatted(
            square["anova"],
            ["measure", "effect", lambda r: f"{r['df1']}, {r['df2']}", "F", "p", "np2"],
        ),
        [False, False, True, True, True, True],
    )
    pooled = [
        {**r, "num_features": "all"} for r in square["robot_effect"]
    ]  # pooled over the feature levels
    return [
        "## Milli & Dragan's 2 x 2: literal or pedagogic human, literal or pragmatic robot",
        "",
        "Split-plot ANOVA per measure: human (`literal`, `pedagogic`) and robot (`literal`, "
        "`pragmatic`) within subjects, the number of features between.",
        "",
        anova,
        "",
        "The robot's simple effect, `pragmatic - literal`, under each human (negative: the "
        "pragmatic robot does better), pooled over the feature levels and at each:",
        "",
        _paired_table(pooled + list(square["robot_effect_by_level"]), "policy", "robot"),
    ]


def _versus(results: Results) -> list[str]:
    versus = results.get("best_response_vs_pedagogic")
    if versus is None:
        return []
    return [
        "## The paper's best response against the pedagogic human",
        "",
        "Paired by reward draw: `best_response - pedagogic` (negative: the best response "
        "teaches better), per robot and number of features.",
        "",
        _paired_table(versus, "robot", "human"),
    ]


def _regret_optimal(results: Results) -> list[str]:
    optimal = results.get("regret_optimal")
    if optimal is None:
        return []
    return [
        "## How far from the regret-optimal demonstration",
        "",
        "With the MAP robot, each human's regret minus that of the best demonstration the "
        "regret-optimal search found for the same reward draw (`regret_optimal`, "
        "cirl_study.core.teaching). The search starts from the expert's path, the best "
        "response at every eta of the cross-validation grid and the pedagogic human's most "
        "telling paths, then improves by single-move changes; so the gap is a lower bound on "
        "the distance to the true optimum, never negative for the expert or the best response.",
        "",
        table(
            ["K", "human", "n", "mean regret", "regret-optimal", "gap", "95% CI", "p",
             "smallest gap", "as good as the best found"],
            formatted(
                optimal["gaps"],
                [
                    "num_features", "policy", "n", "mean_policy", "mean_regret_optimal",
                    "mean_gap", _interval, "p", "smallest_gap",
                    lambda g: f"{100 * g['share_optimal']:.1f}%",
                ],
            ),
            [True, False, True, True, True, True, True, True, True, True],
        ),
    ]  # fmt: skip


def _eta(results: Results) -> list[str]:
    cv = results.get("eta_cv")
    if not cv or not cv["chosen"]:
        return []
    chosen = "; ".join(
        f"K = {c['num_features']}: η = {number(c['eta'])} (mean regret {number(c['mean'])})"
        for c in cv["chosen"]
    )
    return [
        "## The best response's eta",
        "",
        f"Cross-validated as in the paper study, with the MAP robot: {chosen}. Every number "
        "of the cross-validation is in `results.json`.",
    ]


def render_markdown(results: Results) -> str:
    """``report.md`` of a study: every section, from the results alone."""
    sections = [
        _header(results),
        _questions(results),
        _cells(results),
        _anova(results),
        _against_baseline(results),
        _pairwise(results),
        _milli_dragan(results),
        _versus(results),
        _regret_optimal(results),
        _lambda_sweep(results),
        _eta(results),
        ["Every number at full precision is in `results.json`; every trial in `trials.csv`."],
    ]
    return document(sections)


def write_study_report(
    trials: Sequence[TrialRow],
    out_dir: Path | str,
    pipeline: Pipeline,
    *,
    run_id: str,
    provenance: Mapping[str, Any] | None = None,
    progress: Callable[[str], None] = lambda stage: None,
) -> Results:
    """Analyse a study run's trials and write its report directory.

    Writes ``report.md``, ``results.json`` (every number at full precision), ``trials.csv``
    and the figure (PNG and SVG) into ``out_dir``, and ``provenance`` (if given) as
    ``provenance.json``.

    Returns:
        The content of ``results.json``.

    Raises:
        UserError: the run's design cannot be analysed, or the report cannot be written.
    """
    progress("statistics")
    results = analyse_study(trials, pipeline)
    results["run_id"] = run_id
    progress("figures")
    cells, design = pd.DataFrame(results["cells"]), results["design"]
    drawn = figures.draw_all(
        {FIGURE: (figures.cell_bars, (cells, design["humans"], design["robots"]))}
    )
    write_report_directory(
        out_dir,
        markdown=render_markdown(results),
        results=results,
        tables={"trials.csv": trial_table(trials)},
        figures=drawn,
        provenance=provenance,
    )
    return results
