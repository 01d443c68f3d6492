"""The report of a teaching run: ``report.md``, ``results.json``, ``trials.csv``, a figure.

:func:`write_teaching_report` turns the rows of a run of a pipeline with ``[teaching]``
(:mod:`cirl_study.analysis.teaching`) into a directory that reads well on GitHub: the study's
questions with what we measured and a verdict, the cell means of every human with every
robot, each human against the expert, Milli & Dragan's 2 x 2, the paper's best response
against the pedagogic human and against the regret-optimal demonstration. Like the paper
report it is a deterministic function of the trials (their order does not matter).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import pandas as pd

from cirl_study.analysis import figures
from cirl_study.analysis.markdown import document, image, interval, number, table
from cirl_study.analysis.output import write_report_directory
from cirl_study.analysis.report import formatted
from cirl_study.analysis.results import Results
from cirl_study.analysis.table import trial_table
from cirl_study.analysis.teaching import ALPHA, analyse_teaching
from cirl_study.record import TrialRow
from cirl_study.study.spec import Pipeline

FIGURE = "teaching_measures.png"
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
    space = "no hypothesis space"
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
        f"# Teaching study: `{results['pipeline']}`",
        "",
        "Humans who teach and robots who read them, on the gridworld of Hadfield-Menell et "
        "al. (2016, section 4.1) with the paper's measures, within subjects: every human "
        "demonstrates to every robot on the same reward draws. All three measures are "
        "losses: lower is better.",
        "",
        f"- Humans: {', '.join(f'`{h}`' for h in design['humans'])}; robots: "
        f"{', '.join(f'`{r}`' for r in design['robots'])}; rationality λ = "
        f"{number(design['rationality'])}.",
        f"- Reward draws: {subjects}. Trials: {trials}.",
        f"- Hypothesis space: {space}.",
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
        "direction asked. Milli & Dragan's result has two parts: the *crossover* (the "
        "pragmatic robot better with a pedagogic human, worse with a literal one) and "
        "*robustness* (averaged over both humans the literal robot is better: the robot main "
        "effect of the 2 x 2 ANOVA, literal ahead).",
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


def _against_expert(results: Results) -> list[str]:
    return [
        "## Every human against the expert",
        "",
        "Paired by reward draw: the human's measure minus the expert's (negative: the human "
        "teaches better), per robot and number of features; Holm over each measure's rows.",
        "",
        _paired_table(results["against_expert"], "robot", "human"),
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
    """``report.md`` of a teaching study: every section, from the results alone."""
    sections = [
        _header(results),
        _questions(results),
        _cells(results),
        _against_expert(results),
        _milli_dragan(results),
        _versus(results),
        _regret_optimal(results),
        _eta(results),
        ["Every number at full precision is in `results.json`; every trial in `trials.csv`."],
    ]
    return document(sections)


def write_teaching_report(
    trials: Sequence[TrialRow],
    out_dir: Path | str,
    pipeline: Pipeline,
    *,
    run_id: str,
    provenance: Mapping[str, Any] | None = None,
    progress: Callable[[str], None] = lambda stage: None,
) -> Results:
    """Analyse a teaching run's trials and write its report directory.

    Writes ``report.md``, ``results.json`` (every number at full precision), ``trials.csv``
    and the figure (PNG and SVG) into ``out_dir``, and ``provenance`` (if given) as
    ``provenance.json``.

    Returns:
        The content of ``results.json``.

    Raises:
        UserError: the run's design cannot be analysed, or the report cannot be written.
    """
    progress("statistics")
    results = analyse_teaching(trials, pipeline)
    results["run_id"] = run_id
    progress("figures")
    cells, design = pd.DataFrame(results["cells"]), results["design"]
    drawn = figures.draw_all(
        {FIGURE: (figures.teaching_bars, (cells, design["humans"], design["robots"]))}
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
