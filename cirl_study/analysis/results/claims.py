"""Published claims as data, each judged on a run's results by a fixed rule.

A claim (:class:`Claim`) is one declarative entry of :data:`CLAIMS`: its source, the
statement, the rule that decides it in words, the cells of the design it needs
(:class:`~cirl_study.analysis.results.cells.Cells`), the results it reads (``evidence``: keys of
``results.json`` and figures) and the function that applies the rule. A report judges every
claim whose cells the run has and lists the others as not tested; a new claim is one entry.
:func:`evaluate_claims` judges them on a study's typed results
(:class:`~cirl_study.analysis.results.types.StudyResults`) and returns one
:class:`~cirl_study.analysis.results.types.ClaimRow` per claim.
``reproduced`` is the verdict (never written by hand): ``True`` or ``False``, ``None`` for a
claim that asks a question the measurement answers; a claim that is not tested is not
reproduced. Claims from another analysis (the office-supplies theory results) are appended
with :func:`external_claims`.

A row's ``kind`` says what it is about: ``"data"`` (every claim of :data:`CLAIMS`), the run's
data, judged on its cells; ``"theory"`` (the office-supplies theorems), exact results that do
not depend on the run. A judged data claim's row gives the fewest subjects in its cells
(``subjects``); below :data:`MIN_SUBJECTS` its verdict means little. :func:`count_claims`
counts the three kinds of row apart (:class:`ClaimCounts`): the claims on the run's data, the
theorems, and the claims not tested, as the report and ``analyze`` summarise them.

The rules, on the paper's tests (results ``paper``, the reference robot's trials of the expert
and the best response) unless they say otherwise, and on the paper's three measures
(:data:`~cirl_study.measure_registry.PAPER_MEASURES`, each a loss), the measures every
claim was made on, whatever else is registered:

1. ``human_effect``: for every measure the human effect has ``p < .0001`` and the best
   response's mean over the main block is below the expert's.
2. ``human_f_above_962``: every measure's human ``F`` exceeds 962.
3. ``interaction_kl_l2``: for KL and L2, the human x num_features interaction has
   ``p < .05`` and the gap ``mean(expert) - mean(best_response)`` is larger at the smallest
   feature level than at the largest.
4. ``cronbach_alpha``: the paper's .47 lies inside the 95% (Feldt) interval of our raw alpha.
5. ``tukey_br_ahead``: for every measure and feature level, Tukey HSD (as the paper ran it,
   ignoring the pairing) compares best response and expert at that level with ``p < .05``
   and the best response's mean is lower.
6. ``lambda_intermediate``: at every feature level of the lambda sweep (at least three
   lambdas) the lambda with the lowest mean best-response regret (reference robot) is neither
   the smallest nor the largest, and the upper end of its 95% CI lies below the mean at both
   ends.
7. ``paper_best_response``: with the MAP robot (else the first), the best response against
   the expert baseline (``against_baseline``) is significant (Holm) and negative on every
   measure and feature level.
8. ``milli_dragan_crossover``: on every measure, the pragmatic robot's simple effect against
   the literal observer, pooled over the feature levels, is significantly negative with the
   pedagogic human and significantly positive with the literal one (Holm).
9. ``milli_dragan_robustness``: on every measure, the robot main effect of the 2 x 2 ANOVA
   has ``p < .05`` and the mean of the two simple effects is positive (the literal observer
   ahead).
10. ``best_response_vs_pedagogic`` and ``regret_optimal_gap``: questions, answered by the
    measurement without a verdict.
11. ``showing_beats_doing``, on the participants of a run whose conditions include ``do``
    and ``show`` (results ``participants``): for every robot, each
    participant's mean reward L2 distance over her tasks is lower under ``show`` than under
    ``do`` (Welch's t-test, or
    the paired one within participants), Holm p < .05.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal, TypeVar

import numpy as np

from cirl_study.analysis.report.markdown import measure_name, number, p_text, p_value
from cirl_study.analysis.results.cells import (
    MILLI_DRAGAN,
    PAPER,
    REGRET_OPTIMAL_GAP,
    SHOW_AND_DO,
    VERSUS_PEDAGOGIC,
    Cells,
    Design,
)
from cirl_study.analysis.results.per_measure import plain
from cirl_study.analysis.results.types import (
    AnovaEffect,
    CellMean,
    ClaimRow,
    PairedDifference,
    StudyResults,
)
from cirl_study.errors import UserError
from cirl_study.measure_registry import PAPER_MEASURES
from cirl_study.record import (
    BEST_RESPONSE,
    EXPERT,
    LAMBDA_SWEEP,
    LITERAL,
    MAIN,
    MAP,
    PEDAGOGIC,
)

Row = TypeVar("Row", AnovaEffect, PairedDifference)
"""A row :func:`_effect` picks."""

SIGNIFICANCE = 0.05
"""Significance level of the rules that their source states without a level (on
Holm-adjusted p-values where a rule compares several cells)."""

PAPER_P = 1e-4
"""The paper's bound on the p-values of the human effect."""

PAPER_F = 962.0
"""The paper's lower bound on the F statistics of the human effect."""

PAPER_ALPHA = 0.47
"""The paper's Cronbach's alpha across the three measures."""

Kind = Literal["data", "theory"]
"""What a claim is about (:class:`~cirl_study.analysis.results.types.ClaimRow` ``kind``)."""

DATA: Kind = "data"
"""A claim on the run's data, judged on its cells: every claim of :data:`CLAIMS`."""

THEORY: Kind = "theory"
"""A theorem checked exactly (the office-supplies results): it does not depend on the run."""

MIN_SUBJECTS = 20
"""The fewest subjects (reward draws) per cell on which a claim's verdict means something;
the report and ``analyze`` say when a judged claim's cells have fewer.

The rules read tests of paired differences across subjects. Below 20 subjects per cell such a
test misses even a large effect often: a paired t test at .05 detects Cohen's d = 0.8 with
probability 0.92 at 20 subjects, 0.62 at 10 and 0.21 at 4, where its critical t has grown from
2.09 to 3.18. A claim not reproduced on so few draws says more about the run's size than about
the claim, and one reproduced rests on a handful of draws (a smoke run plays 4 per feature
level)."""

SECTION_HUMAN = "paper, section 4.2"
SECTION_LAMBDA = "paper, section 4.3"
MILLI_DRAGAN_2019 = "Milli & Dragan (2019)"
HO_2016 = "Ho et al. (2016), against the paper's best response"
HO_SHOWING = "Ho et al. (2016), showing versus doing, on this run's participants"
REGRET_OPTIMAL_SOURCE = "this study: the regret-optimal demonstration"


@dataclass(frozen=True)
class Verdict:
    """What a rule found: the measurement in words, its numbers, and whether the claim is
    reproduced (``None``: the claim asks a question, which the measurement answers)."""

    measurement: str
    values: Mapping[str, Any]
    reproduced: bool | None


@dataclass(frozen=True)
class Claim:
    """One published claim and the rule that judges it (see the module docstring)."""

    id: str
    source: str
    statement: str
    rule: str
    needs: Cells
    evidence: tuple[str, ...]
    judge: Callable[[StudyResults], Verdict]
    block: str = MAIN
    """The block whose cells the rule reads: ``main`` or ``lambda_sweep``."""


def _num(value: float | None) -> str:
    return number(value)


def _reference(results: StudyResults) -> str:
    return results.design.reference_robot


def _anova(results: StudyResults, measure: str, effect: str) -> AnovaEffect:
    return next(
        row for row in results.paper.anova if row.measure == measure and row.effect == effect
    )


def _paper_cells(results: StudyResults, measure: str) -> list[CellMean]:
    """The cell means of ``measure`` of the paper's humans with the reference robot."""
    robot = _reference(results)
    return [
        row
        for row in results.cells
        if row.measure == measure and row.robot == robot and row.human in (EXPERT, BEST_RESPONSE)
    ]


def _human_mean(results: StudyResults, measure: str, human: str) -> float:
    cells = [row for row in _paper_cells(results, measure) if row.human == human]
    return sum(row.n * row.mean for row in cells) / sum(row.n for row in cells)


def _gap(results: StudyResults, measure: str, level: int) -> float:
    means = {(r.num_features, r.human): r.mean for r in _paper_cells(results, measure)}
    return means[(level, EXPERT)] - means[(level, BEST_RESPONSE)]


def _f_text(row: AnovaEffect) -> str:
    return f"F({row.df1}, {row.df2}) = {_num(row.F)}, p = {p_text(row.log10_p)}"


def _human_effect(results: StudyResults) -> Verdict:
    values, parts, holds = {}, [], True
    for measure in PAPER_MEASURES:
        row = _anova(results, measure, "human")
        expert = _human_mean(results, measure, EXPERT)
        best = _human_mean(results, measure, BEST_RESPONSE)
        values[measure] = {
            "F": row.F, "p": row.p, "log10_p": row.log10_p, "mean_expert": expert, "mean_br": best,
        }  # fmt: skip
        holds &= _below(row.p, PAPER_P) and best < expert
        parts.append(
            f"{measure_name(measure)}: best response {_num(best)} vs expert {_num(expert)}, "
            f"{_f_text(row)}"
        )
    return Verdict("; ".join(parts), values, holds)


def _human_f(results: StudyResults) -> Verdict:
    values = {m: _anova(results, m, "human").F for m in PAPER_MEASURES}
    return Verdict(
        "; ".join(f"{measure_name(m)}: F = {_num(f)}" for m, f in values.items()),
        values,
        all(f is not None and f > PAPER_F for f in values.values()),
    )


def _interaction(results: StudyResults) -> Verdict:
    levels = results.design.feature_levels
    low, high = min(levels), max(levels)
    values, parts, holds = {}, [], True
    for measure in PAPER_MEASURES:
        row = _anova(results, measure, "human:num_features")
        gaps = {low: _gap(results, measure, low), high: _gap(results, measure, high)}
        values[measure] = {
            "F": row.F, "p": row.p, "log10_p": row.log10_p,
            **{f"gap_{k}": g for k, g in gaps.items()},
        }  # fmt: skip
        if measure != "regret":
            holds &= _below(row.p, SIGNIFICANCE) and gaps[low] > gaps[high]
        parts.append(
            f"{measure_name(measure)}: interaction {_f_text(row)}; gap {_num(gaps[low])} at "
            f"{low} vs {_num(gaps[high])} at {high} features"
        )
    return Verdict("; ".join(parts), values, holds)


def _cronbach(results: StudyResults) -> Verdict:
    alpha = results.paper.cronbach_alpha
    low, high = alpha.ci95
    return Verdict(
        f"raw alpha {_num(alpha.raw)} [{_num(low)}, {_num(high)}], standardised "
        f"{_num(alpha.standardised)}, over {alpha.n_rows} main-block trials",
        {"raw": alpha.raw, "ci95": [low, high], "standardised": alpha.standardised},
        low is not None and high is not None and low <= PAPER_ALPHA <= high,
    )


def _tukey(results: StudyResults) -> Verdict:
    values, parts, holds = {}, [], True
    for row in results.paper.tukey_hsd:
        level = row.a_num_features
        if level != row.b_num_features or row.measure not in PAPER_MEASURES:
            continue
        means = {row.a_human: row.mean_a, row.b_human: row.mean_b}
        holds &= means[BEST_RESPONSE] < means[EXPERT] and _below(row.p_tukey, SIGNIFICANCE)
        values[f"{row.measure}@{level}"] = {
            "diff_br_minus_expert": means[BEST_RESPONSE] - means[EXPERT],
            "p_tukey": row.p_tukey,
            "log10_p_tukey": row.log10_p_tukey,
        }
        parts.append(
            f"{measure_name(row.measure)} at {level}: best response minus expert "
            f"{_num(means[BEST_RESPONSE] - means[EXPERT])}, p = {p_text(row.log10_p_tukey)}"
        )
    return Verdict("; ".join(parts), values, holds)


def _lambda_minimum(results: StudyResults) -> Verdict:
    robot = _reference(results)
    curves: dict[int, list[CellMean]] = {}
    for row in results.lambda_sweep:
        if row.measure == "regret" and row.human == BEST_RESPONSE and row.robot == robot:
            curves.setdefault(row.num_features, []).append(row)
    values, parts, holds = {}, [], True
    for level, curve in sorted(curves.items()):
        curve = sorted(curve, key=lambda row: row.rationality)
        best = min(curve, key=lambda row: (row.mean, row.rationality))
        ends = (curve[0].mean, curve[-1].mean)
        interior = best is not curve[0] and best is not curve[-1]
        holds &= interior and best.ci95_high < min(ends)
        values[str(level)] = {
            "argmin_lambda": best.rationality,
            "min_mean": best.mean,
            "min_ci95_high": best.ci95_high,
            "mean_at_smallest_lambda": ends[0],
            "mean_at_largest_lambda": ends[1],
        }
        parts.append(
            f"{level} features: lowest {_num(best.mean)} (CI upper {_num(best.ci95_high)}) "
            f"at lambda = {best.rationality:g}; {_num(ends[0])} at {curve[0].rationality:g}, "
            f"{_num(ends[1])} at {curve[-1].rationality:g}"
        )
    return Verdict("; ".join(parts), values, holds)


def _effect(rows: list[Row], measure: str, **where: Any) -> Row:
    """The one row of ``rows`` for ``measure`` that matches ``where``."""
    found = [
        r
        for r in rows
        if r.measure == measure and all(getattr(r, k, None) == v for k, v in where.items())
    ]
    if len(found) != 1:
        raise ValueError(f"expected one row for {measure} {where}, found {len(found)}")
    return found[0]


def _below(p: float | None, level: float) -> bool:
    """Whether the p-value ``p`` is below ``level``; an undefined p (a test of no variance)
    never is."""
    return p is not None and p < level


def _signed(row: PairedDifference, sign: int) -> bool:
    """Significant (Holm) with ``mean_diff`` of the given sign."""
    if row.mean_diff is None:
        return False
    return bool(_below(row.p_holm, SIGNIFICANCE) and np.sign(row.mean_diff) == sign)


def _paper_robot(results: StudyResults) -> str:
    robots = results.design.robots
    return MAP if MAP in robots else robots[0]


def _best_response_beats_expert(results: StudyResults) -> Verdict:
    robot = _paper_robot(results)
    effects = [
        _effect(results.against_baseline, m, robot=robot, num_features=k, level=BEST_RESPONSE)
        for m in PAPER_MEASURES
        for k in results.design.feature_levels
    ]
    return Verdict(
        "; ".join(
            f"{measure_name(e.measure)} at K={e.num_features}: {_num(e.mean_diff)} "
            f"(p_holm {p_value(e.p_holm)})"
            for e in effects
        ),
        {},
        all(_signed(e, -1) for e in effects),
    )


def _robot_effects(
    results: StudyResults, measure: str
) -> tuple[PairedDifference, PairedDifference]:
    """The 2 x 2's simple effects of the robot on ``measure``: with the pedagogic human, and
    with the literal one (pooled over the feature levels)."""
    effects = results.milli_dragan.robot_effect
    return _effect(effects, measure, human=PEDAGOGIC), _effect(effects, measure, human=LITERAL)


def _crossover(results: StudyResults) -> Verdict:
    crossover, measured = {}, []
    for m in PAPER_MEASURES:
        with_pedagogic, with_literal = _robot_effects(results, m)
        crossover[m] = _signed(with_pedagogic, -1) and _signed(with_literal, 1)
        measured.append(
            f"{measure_name(m)}: pragmatic - literal_observer {_num(with_pedagogic.mean_diff)} "
            f"(p_holm {p_value(with_pedagogic.p_holm)}) with a pedagogic human, "
            f"{_num(with_literal.mean_diff)} (p_holm {p_value(with_literal.p_holm)}) with a "
            "literal one"
        )
    return Verdict("; ".join(measured), {"by_measure": crossover}, all(crossover.values()))


def _robustness(results: StudyResults) -> Verdict:
    robust, measured = {}, []
    for m in PAPER_MEASURES:
        with_pedagogic, with_literal = _robot_effects(results, m)
        anova = _effect(results.milli_dragan.anova, m, effect="robot")
        mean_effect = (with_pedagogic.mean_diff + with_literal.mean_diff) / 2
        robust[m] = bool(_below(anova.p, SIGNIFICANCE) and mean_effect > 0)
        measured.append(
            f"{measure_name(m)}: mean pragmatic - literal_observer {_num(mean_effect)}, robot "
            f"F({anova.df1}, {anova.df2}) = {_num(anova.F)}, p = {p_value(anova.p)}"
        )
    return Verdict("; ".join(measured), {"by_measure": robust}, all(robust.values()))


def _versus(results: StudyResults) -> Verdict:
    ahead: dict[str, str] = {}
    measured = []
    for row in results.best_response_vs_pedagogic:
        if row.measure not in PAPER_MEASURES:
            continue
        key = f"{row.measure}:{row.robot}:{row.num_features}"
        if row.p_holm is None or row.p_holm >= SIGNIFICANCE:
            ahead[key] = "neither"
        else:
            ahead[key] = BEST_RESPONSE if row.mean_diff < 0 else PEDAGOGIC
        if row.measure == "regret":
            measured.append(
                f"robot {row.robot}, K={row.num_features}: best response - pedagogic "
                f"{_num(row.mean_diff)} (p_holm {p_value(row.p_holm)})"
            )
    return Verdict("regret: " + "; ".join(measured), {"ahead": ahead}, None)


def _optimal_gap(results: StudyResults) -> Verdict:
    gaps = [g for g in results.regret_optimal.gaps if g.human == BEST_RESPONSE]
    return Verdict(
        "; ".join(
            f"K={g.num_features}: regret {_num(g.mean_human)} vs "
            f"{_num(g.mean_regret_optimal)}, gap {_num(g.mean_gap)} "
            f"[{_num(g.ci95_low)}, {_num(g.ci95_high)}], "
            f"as good as the best found for {100 * g.share_optimal:.1f}% of draws"
            for g in gaps
        )
        or "the best response was not played",
        {},
        None,
    )


def _showing(results: StudyResults) -> Verdict:
    people = results.participants
    assert people is not None  # the claim's cells are the participants'
    rows = [
        row
        for row in people.conditions
        if row.measure == "reward_l2" and row.baseline == "do" and row.level == "show"
    ]
    ahead = {row.robot: bool(_below(row.p_holm, SIGNIFICANCE) and (row.mean_diff or 0) < 0)
             for row in rows}  # fmt: skip
    parts = [
        f"{row.robot}: show - do {_num(row.mean_diff)} (Holm {p_text(row.log10_p_holm)})"
        for row in rows
    ]
    values = {row.robot: {"mean_diff": row.mean_diff, "p_holm": row.p_holm,
                          "log10_p_holm": row.log10_p_holm} for row in rows}  # fmt: skip
    return Verdict("reward L2, " + "; ".join(parts), values, bool(ahead) and all(ahead.values()))


CLAIMS: tuple[Claim, ...] = (
    Claim(
        "human_effect",
        SECTION_HUMAN,
        "Best response outperforms demonstration-by-expert on all three measures "
        "(significant effect of human, p < .0001).",
        f"every measure: human effect p < {PAPER_P:g} and the best response's mean below "
        "the expert's",
        PAPER,
        ("paper.anova", "cells", "figure2_measures"),
        _human_effect,
    ),
    Claim(
        "human_f_above_962",
        SECTION_HUMAN,
        "The effect of human has F > 962 on every measure.",
        f"every measure: human effect F > {PAPER_F:g}",
        PAPER,
        ("paper.anova",),
        _human_f,
    ),
    Claim(
        "interaction_kl_l2",
        SECTION_HUMAN,
        "An interaction of human with num_features for KL and L2: the gap between the "
        "humans is larger with fewer features.",
        f"KL and L2: interaction p < {SIGNIFICANCE:g} and the gap mean(expert) - "
        "mean(best response) larger at the smallest feature level than at the largest "
        "(regret shown for context)",
        Cells(humans=PAPER.humans, feature_levels=2),
        ("paper.anova", "paper.simple_effects", "cells", "figure2_measures"),
        _interaction,
    ),
    Claim(
        "cronbach_alpha",
        SECTION_HUMAN,
        "Relatively little correlation between the measures: Cronbach's alpha of .47.",
        f"{PAPER_ALPHA:g} inside the 95% Feldt interval of our raw alpha",
        PAPER,
        ("paper.cronbach_alpha",),
        _cronbach,
    ),
    Claim(
        "tukey_br_ahead",
        SECTION_HUMAN,
        "Post-hoc Tukey HSD shows the best response outperforming the expert in every cell.",
        f"every measure and feature level: Tukey HSD (ignoring the pairing) p < {SIGNIFICANCE:g} "
        "and the best response's mean lower",
        PAPER,
        ("paper.tukey_hsd", "figure2_measures"),
        _tukey,
    ),
    Claim(
        "lambda_intermediate",
        SECTION_LAMBDA,
        "The best response's regret is lowest at an intermediate lambda.",
        "every feature level: the lambda of lowest mean best-response regret is neither the "
        "smallest nor the largest of the sweep, and its 95% CI's upper end is below the mean "
        "at both ends",
        Cells(humans=(BEST_RESPONSE,), rationalities=3),
        ("lambda_sweep", "figure2_lambda"),
        _lambda_minimum,
        block=LAMBDA_SWEEP,
    ),
    Claim(
        "paper_best_response",
        "paper, section 4.2, replayed against every human",
        "The best response beats the expert on every measure and feature level (robot map), "
        "paired by reward draw.",
        "every measure and feature level: best response minus expert negative, Holm p < "
        f"{SIGNIFICANCE:g} over the measure's comparisons of every human with the expert",
        Cells(humans=PAPER.humans, baseline=EXPERT),
        ("against_baseline",),
        _best_response_beats_expert,
    ),
    Claim(
        "milli_dragan_crossover",
        MILLI_DRAGAN_2019,
        "The pragmatic robot does better than the literal observer with a pedagogic human and "
        "worse with a literal human.",
        "every measure: the robot's simple effect (pragmatic - literal_observer, pooled over "
        "the feature levels) negative with the pedagogic human and positive with the literal "
        f"one, each Holm p < {SIGNIFICANCE:g}",
        MILLI_DRAGAN,
        ("milli_dragan",),
        _crossover,
    ),
    Claim(
        "milli_dragan_robustness",
        MILLI_DRAGAN_2019,
        "The literal observer is the more robust choice: the pragmatic robot loses more with a "
        "literal human than it gains with a pedagogic one.",
        f"every measure: the 2 x 2 ANOVA's robot effect p < {SIGNIFICANCE:g} and the mean of "
        "the two simple effects positive (the literal observer ahead)",
        MILLI_DRAGAN,
        ("milli_dragan",),
        _robustness,
    ),
    Claim(
        "best_response_vs_pedagogic",
        HO_2016,
        "How does the paper's best response compare with the pedagogic human, robot by robot?",
        "a question: per measure, robot and feature level, which human is ahead (Holm p < "
        f"{SIGNIFICANCE:g}), or neither",
        VERSUS_PEDAGOGIC,
        ("best_response_vs_pedagogic",),
        _versus,
    ),
    Claim(
        "regret_optimal_gap",
        REGRET_OPTIMAL_SOURCE,
        "How far is the best response from the regret-optimal demonstration (MAP robot)?",
        "a question: the mean regret gap with its 95% CI per feature level, and the share of "
        "reward draws at which the best response is as good as the best demonstration found",
        REGRET_OPTIMAL_GAP,
        ("regret_optimal",),
        _optimal_gap,
    ),
    Claim(
        "showing_beats_doing",
        HO_SHOWING,
        "Showing leads a learner to a better estimate of the reward than doing.",
        "every robot: each participant's mean reward L2 over her tasks lower under show than "
        f"under do, Holm p < {SIGNIFICANCE:g}",
        SHOW_AND_DO,
        ("participants",),
        _showing,
    ),
)
"""Every claim a study's report judges, in the order it lists them."""


def design_of_results(results: StudyResults) -> Design:
    """The :class:`~cirl_study.analysis.results.cells.Design` of a run's results."""
    design = results.design
    people = results.participants
    return Design(
        humans=tuple(design.humans),
        robots=tuple(design.robots),
        feature_levels=tuple(design.feature_levels),
        sweep_rationalities=tuple(design.sweep_rationalities),
        conditions=() if people is None else tuple(people.design.conditions),
    )


def cell_subjects(claim: Claim, results: StudyResults) -> int | None:
    """The fewest subjects (reward draws) in a cell of ``results`` that ``claim`` reads
    (``None`` when there is none): in the ``main`` block, the fewest of a feature level (every
    human and robot plays a level's draws); in the ``lambda_sweep``, the fewest trials of a
    cell of the claim's humans (one per draw and lambda); of a claim on participants, the
    fewest participants of a condition it compares."""
    if claim.needs.conditions and results.participants is not None:
        counts = results.participants.design.participants
        return min((counts.get(c, 0) for c in claim.needs.conditions), default=None)
    if claim.block == LAMBDA_SWEEP:
        humans = claim.needs.humans
        counts = [row.n for row in results.lambda_sweep if not humans or row.human in humans]
    else:
        counts = list(results.design.subjects_per_level.values())
    return min(counts, default=None)


NOT_TESTED = "not tested: "
"""How the measurement of a claim not tested begins: what the run lacks follows."""


def judged(claim: Claim, results: StudyResults) -> ClaimRow:
    """The row of one claim on ``results``: judged where the run has its cells."""
    lacking = claim.needs.lacking(design_of_results(results))
    verdict = (
        Verdict(f"{NOT_TESTED}the run lacks {lacking}", {}, False)
        if lacking
        else claim.judge(results)
    )
    return ClaimRow(
        id=claim.id,
        kind=DATA,
        source=claim.source,
        claim=claim.statement,
        rule=claim.rule,
        measurement=verdict.measurement,
        values=plain(verdict.values),
        tested=lacking is None,
        reproduced=None if verdict.reproduced is None else bool(verdict.reproduced),
        subjects=None if lacking else cell_subjects(claim, results),
        evidence=list(claim.evidence),
    )


_EXTERNAL_TEXT = ("id", "source", "claim", "rule", "measurement")


def external_claims(theory: Mapping[str, Any]) -> list[ClaimRow]:
    """Claim rows supplied by another analysis (e.g. the office-supplies theory results).

    ``theory["claims"]`` must be a list of rows with the string fields ``id, source, claim,
    rule, measurement``, a boolean ``reproduced`` computed by that analysis, and optionally
    ``kind`` (``"theory"``, the default: a result checked exactly, independent of the run; or
    ``"data"``), ``tested`` (boolean, default true), ``values`` (JSON data) and ``evidence``
    (list of strings: keys of ``results.json``, figure names or relative links). Such a row
    counts no subjects.

    Raises:
        UserError: ``theory`` does not have that shape.
    """
    entries = theory.get("claims") if isinstance(theory, Mapping) else None
    if not isinstance(entries, list):
        raise UserError("theory results: expected a dict with a list under 'claims'")
    claims = []
    for position, entry in enumerate(entries):
        where = f"theory results: claim {position}"
        if not isinstance(entry, Mapping):
            raise UserError(f"{where}: expected a dict, got {type(entry).__name__}")
        for key in _EXTERNAL_TEXT:
            if not isinstance(entry.get(key), str) or not entry[key]:
                raise UserError(f"{where}: '{key}' must be a non-empty string")
        tested = entry.get("tested", True)
        if not isinstance(entry.get("reproduced"), bool) or not isinstance(tested, bool):
            raise UserError(f"{where}: 'reproduced' and 'tested' must be booleans")
        kind = entry.get("kind", THEORY)
        if kind not in (DATA, THEORY):
            raise UserError(f"{where}: 'kind' must be {DATA!r} or {THEORY!r}")
        evidence = entry.get("evidence", [])
        if not isinstance(evidence, list) or not all(isinstance(e, str) for e in evidence):
            raise UserError(f"{where}: 'evidence' must be a list of strings")
        claims.append(
            ClaimRow(
                **{key: entry[key] for key in _EXTERNAL_TEXT},
                kind=kind,
                values=plain(entry.get("values", {})),
                tested=tested,
                reproduced=bool(tested and entry["reproduced"]),
                subjects=None,
                evidence=list(evidence),
            )
        )
    return claims


def evaluate_claims(
    results: StudyResults, theory: Mapping[str, Any] | None = None
) -> list[ClaimRow]:
    """Every claim row: those of :data:`CLAIMS`, then those of ``theory``."""
    claims = [judged(claim, results) for claim in CLAIMS]
    ids = {claim.id for claim in claims}
    for claim in external_claims(theory) if theory is not None else []:
        if claim.id in ids:
            raise UserError(f"theory results: claim id {claim.id!r} is already used")
        ids.add(claim.id)
        claims.append(claim)
    return claims


def _count(n: int, word: str, plural: str | None = None) -> str:
    """``1 claim``, ``2 claims``."""
    return f"{n} {word if n == 1 else plural or word + 's'}"


@dataclass(frozen=True)
class ClaimCounts:
    """The claim rows of a report counted apart (:func:`count_claims`): the claims judged on
    the run's data and their verdicts, the theorems checked exactly (independent of the run),
    and the claims not tested (the run lacks their cells)."""

    data: int
    """Claims on the run's data that were judged."""
    reproduced: int
    not_reproduced: int
    answered: int
    """Of ``data``: questions, answered by the measurement without a verdict."""
    theorems: int
    """Theorems checked exactly."""
    theorems_hold: int
    not_tested: int
    """Claims of either kind not tested."""
    subjects: int | None
    """The fewest subjects in a cell of a judged data claim (``None``: none judged)."""

    @property
    def few_subjects(self) -> bool:
        """Whether a judged data claim's cells have fewer than :data:`MIN_SUBJECTS`."""
        return self.subjects is not None and self.subjects < MIN_SUBJECTS

    def data_text(self) -> str:
        """The claims on the run's data and their verdicts, in words."""
        if not self.data:
            return "no claim on this run's data judged"
        verdicts = [f"{self.reproduced} reproduced", f"{self.not_reproduced} not reproduced"]
        if self.answered:
            verdicts.append(_count(self.answered, "question") + " answered")
        return f"{_count(self.data, 'claim')} on this run's data: {', '.join(verdicts)}"

    def subjects_text(self) -> str | None:
        """The warning when the judged claims' cells are small (``None`` when they are not)."""
        if not self.few_subjects:
            return None
        return (
            f"judged on cells of {self.subjects} subjects, fewer than {MIN_SUBJECTS}: the "
            "verdicts mean little"
        )

    def theory_text(self) -> str | None:
        """The theorems and how many hold (``None`` when there is none)."""
        if not self.theorems:
            return None
        fail = self.theorems - self.theorems_hold
        holds = f"{self.theorems_hold} {'holds' if self.theorems_hold == 1 else 'hold'}"
        holds += f", {fail} {'does' if fail == 1 else 'do'} not" if fail else ""
        theorems = _count(self.theorems, "theorem")
        return f"{theorems} checked exactly, independent of the run: {holds}"

    def not_tested_text(self) -> str | None:
        """The claims not tested (``None`` when every claim is)."""
        if not self.not_tested:
            return None
        return f"{_count(self.not_tested, 'claim')} not tested, the run lacks their cells"

    def summary(self) -> str:
        """One line: the data claims (with the subjects warning), the theorems, the claims
        not tested, separated by semicolons."""
        data = self.data_text()
        if self.few_subjects:
            data += f" ({self.subjects_text()})"
        parts = [data, self.theory_text(), self.not_tested_text()]
        return "; ".join(part for part in parts if part)


def count_claims(claims: Sequence[ClaimRow]) -> ClaimCounts:
    """The rows ``claims`` counted apart by kind and verdict (:class:`ClaimCounts`)."""
    data = [c for c in claims if c.tested and c.kind == DATA]
    theorems = [c for c in claims if c.tested and c.kind == THEORY]
    subjects = [c.subjects for c in data if c.subjects is not None]
    return ClaimCounts(
        data=len(data),
        reproduced=sum(c.reproduced is True for c in data),
        not_reproduced=sum(c.reproduced is False for c in data),
        answered=sum(c.reproduced is None for c in data),
        theorems=len(theorems),
        theorems_hold=sum(c.reproduced is True for c in theorems),
        not_tested=sum(not c.tested for c in claims),
        subjects=min(subjects, default=None),
    )
