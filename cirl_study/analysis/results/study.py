"""Every number of a study's report, computed from the trials' rows as typed records.

One analysis serves every design of humans x robots x feature levels (``docs/pipelines.md``):
:func:`analyse` builds the study's typed results
(:class:`~cirl_study.analysis.results.types.StudyResults`, floats at full precision, ``None``
for an undefined number), statistic by statistic; :func:`with_claims` adds what the report
adds (its run's id, what a partial run lacks, the claims judged on them): what the report
reads and ``results.json`` stores. Its halves, :func:`estimates` (everything the figures
draw) and :func:`tests` (the rest, from the estimates), depend only on the trials, so the
report draws its figures in worker processes while it computes the tests. Every per-measure
section holds each
measure the analysis tests (:func:`~cirl_study.measure_registry.analysed_measures`, in
the registry's order), each on the trials that have a value of it
(:func:`~cirl_study.analysis.results.per_measure.measured`: a reward draw without a value of a
measure in some trial is left out of all that measure's statistics); Cronbach's alpha, the paper's
three (:data:`~cirl_study.measure_registry.PAPER_MEASURES`).

The sections, by key:

* ``design``: the humans (the first, ``baseline``, is the one every other is compared with),
  the robots (``reference_robot``, the paper's ``map`` when present, plays the eta
  cross-validation), the feature levels and subjects per level, the main block's rationality
  and etas, the sweep's rationalities, the teaching players' hypothesis space;
* ``cells``: each measure's mean with its t-based 95% CI per feature level, human and robot
  (:func:`cirl_study.analysis.statistics.procedures.group_means`);
* ``anova``: per measure, the repeated-measures ANOVA with ``human`` and, with
  two robots or more, ``robot`` within subjects and ``num_features`` between (with two levels
  or more), sphericity tested and corrected
  (:func:`cirl_study.analysis.statistics.anova.repeated_measures_anova`);
* ``pairwise``: per measure and within factor, every pair of its levels in every cell of the
  other factors, paired by subject, Holm over the measure's and factor's rows
  (:func:`cirl_study.analysis.statistics.procedures.pairwise_differences`);
* ``against_baseline``: per robot and feature level, each human against the baseline,
  paired (:func:`cirl_study.analysis.statistics.procedures.paired_differences`, Holm per measure);
  these three are the main block's registered tests (:mod:`cirl_study.analysis.results.registry`,
  computed in :mod:`cirl_study.analysis.results.per_measure`);
* ``lambda_sweep``: the means of the sweep per rationality, human, robot and feature level;
* ``eta_cv``: the cross-validation of the best response's eta (:func:`eta_cv`);
* ``converged``: per robot, block and rationality, the trials whose estimate met
  the robot's stopping rule;
* ``paper``, where the run has the paper's humans
  (:data:`~cirl_study.analysis.results.cells.PAPER`): the paper's analyses on the reference robot's
  trials of the expert and the best response: its registered tests, the mixed ANOVA, the simple
  effects of human, Tukey HSD as the paper ran it and the Wilcoxon checks (each per measure),
  Cronbach's alpha of the paper's three measures (:func:`paper_tests`), and the reward draw of
  Figure 1;
* ``robots``, with two robots or more: every other robot against the reference, paired, in
  the main block and at every rationality of the sweep (:func:`robot_comparison`);
* the teaching sections, where the run has their cells
  (:mod:`cirl_study.analysis.results.teaching`);
* ``undefined``, only where some trials have no value of a measure (``None`` otherwise): per
  such measure, those trials and their reward draws, left out of its statistics
  (:func:`~cirl_study.analysis.results.per_measure.undefined`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import msgspec
import pandas as pd

from cirl_study.analysis.results import teaching
from cirl_study.analysis.results.cells import (
    MILLI_DRAGAN,
    PAPER,
    REGRET_OPTIMAL_GAP,
    VERSUS_PEDAGOGIC,
    Design,
)
from cirl_study.analysis.results.participants import participants_section
from cirl_study.analysis.results.per_measure import (
    measured,
    paired_rows,
    plain,
    run_tests,
    undefined,
)
from cirl_study.analysis.results.types import (
    CellMean,
    ClaimRow,
    Converged,
    Estimates,
    EtaChoice,
    EtaCrossValidation,
    EtaMainBlock,
    EtaMean,
    EtaUncertainty,
    Figure1,
    PairedDifference,
    PaperSection,
    Partial,
    RobotComparison,
    StudyDesign,
    StudyResults,
    Table,
    Teaching,
)
from cirl_study.analysis.statistics import procedures as statistics
from cirl_study.analysis.table import trial_table
from cirl_study.core.players import reference_robot
from cirl_study.errors import UserError
from cirl_study.measure_registry import PAPER_MEASURES
from cirl_study.record import (
    BEST_RESPONSE,
    BLOCKS,
    ETA_CV,
    EXPERT,
    LAMBDA_SWEEP,
    MAIN,
    PAPER_HUMANS,
    TrialRow,
)
from cirl_study.study.eta_cv import etas_of_study
from cirl_study.study.spec import Pipeline, TeachingSpec


def design_of(table: pd.DataFrame, pipeline: Pipeline) -> Design:
    """The factors of the trials in ``table`` (:func:`~cirl_study.analysis.table.trial_table`),
    in the order of ``pipeline``: the humans and robots its ``main`` block plays (the simulated
    humans: the participants' are :mod:`cirl_study.analysis.results.participants`'), its feature
    levels, and the rationalities of its sweep."""
    main = table[table["block"] == MAIN]
    humans, robots = set(models(main)["human"]), set(main["robot"])
    sweep = table.loc[table["block"] == LAMBDA_SWEEP, "rationality"]
    return Design(
        humans=tuple(h for h in pipeline.main.humans if h in humans),
        robots=tuple(r for r in pipeline.main.robots if r in robots),
        feature_levels=tuple(sorted(int(k) for k in main["num_features"].unique())),
        sweep_rationalities=tuple(sorted(float(value) for value in sweep.unique())),
    )


FIGURE1_DIFFERENCE = 0.05
"""How far apart a reward draw's two regrets must be for Figure 1 to show it: by more than
this fraction of the larger (in absolute value), so the two demonstrations it sets side by
side visibly teach the robot differently (two equal regrets, often two identical paths, show
nothing of the paper's point)."""


def figure1_subject(paper_main: pd.DataFrame, robot: str) -> Figure1:
    """The reward draw shown in Figure 1, watched by ``robot``: a typical one at the smallest
    feature level whose humans differ.

    Among the subjects at the smallest feature level whose two regrets differ by more than
    :data:`FIGURE1_DIFFERENCE` (5%) of the larger, ``|regret(expert) - regret(best_response)|
    > 0.05 * max(|regret(expert)|, |regret(best_response)|)``, the one whose regret improvement
    ``regret(expert) - regret(best_response)`` is the median (the lower median for an even
    count; ties broken by subject id). Where no subject's regrets differ so, the median of all
    the level's subjects, and the ``rule`` says so.
    """
    level = int(paper_main["num_features"].min())
    paired = statistics.paired_by_subject(paper_main, "regret", level)
    expert, best = paired[EXPERT], paired[BEST_RESPONSE]
    improvement = (expert - best).rename("improvement")
    larger = pd.concat([expert.abs(), best.abs()], axis=1).max(axis=1)
    differ = improvement.abs() > FIGURE1_DIFFERENCE * larger
    percent = f"{FIGURE1_DIFFERENCE:.0%}"
    rule = (
        f"the subject at num_features={level} whose regret improvement (expert minus best "
        f"response) is the median of those whose two regrets differ by more than {percent} of "
        "the larger"
    )
    candidates = improvement[differ]
    if candidates.empty:
        candidates = improvement
        rule = (
            f"the subject at num_features={level} whose regret improvement (expert minus best "
            f"response) is the median of its feature level (no subject's two regrets differ by "
            f"more than {percent} of the larger)"
        )
    ordered = candidates.reset_index().sort_values(["improvement", "subject"], kind="mergesort")
    chosen = ordered.iloc[(len(ordered) - 1) // 2]
    subject = str(chosen["subject"])
    return Figure1(
        subject=subject,
        num_features=level,
        regret_expert=float(paired.at[subject, EXPERT]),
        regret_best_response=float(paired.at[subject, BEST_RESPONSE]),
        rule=rule,
        robot=robot,
    )


def _trial_counts(table: pd.DataFrame) -> dict[str, int]:
    """Trials in total and per block: the blocks of docs/design.md §5 first, then any other."""
    sizes = table.groupby("block").size()
    order = [b for b in BLOCKS if b in sizes.index]
    order += [b for b in sizes.index if b not in order]
    return {"total": len(table), **{str(block): int(sizes[block]) for block in order}}


def _design(main: pd.DataFrame, design: Design, pipeline: Pipeline) -> StudyDesign:
    subjects = main.groupby("num_features")["subject"].nunique()
    spec = pipeline.teaching
    return StudyDesign(
        humans=list(design.humans),
        baseline=design.baseline,
        robots=list(design.robots),
        reference_robot=reference_robot(design.robots),
        feature_levels=list(design.feature_levels),
        subjects_per_level={str(level): int(n) for level, n in subjects.items()},
        main_rationality=sorted({float(value) for value in main["rationality"]}),
        main_eta={
            str(level): sorted({float(value) for value in etas.dropna()})
            for level, etas in main.groupby("num_features")["eta"]
        },
        sweep_rationalities=list(design.sweep_rationalities),
        teaching=None if spec is None else _teaching(spec, pipeline),
    )


def _teaching(spec: TeachingSpec, pipeline: Pipeline) -> Teaching:
    """The ``[teaching]`` of the results: its settings, with the number of hypotheses."""
    return Teaching(
        hypotheses=pipeline.hypothesis_count,
        includes_truth=spec.includes_truth,
        alpha=spec.alpha,
        demonstration=spec.demonstration,
        learning_paths=spec.learning_paths,
        of_tasks=spec.hypotheses == "tasks",
    )


def eta_cv(
    trials: Sequence[TrialRow], table: pd.DataFrame, pipeline: Pipeline
) -> EtaCrossValidation:
    """The cross-validation of the best response's eta, and whether the main block used it.

    ``means``: mean best-response regret with its CI per feature level and eta
    (:func:`~cirl_study.analysis.statistics.procedures.eta_means`). ``uncertainty``: how clear-cut
    each cross-validated choice is
    (:func:`~cirl_study.analysis.statistics.procedures.eta_choice_uncertainty`).
    ``chosen``: per feature level, the eta the study of ``pipeline`` plays
    (:func:`~cirl_study.study.eta_cv.etas_of_study`: picked from the ``eta_cv`` rows of
    ``trials``, the choice the run made, with its mean on the measure chosen on; or fixed by
    the universe, without a mean).
    ``main_block``: per feature level of the ``main`` block, the etas its best-response trials were
    played with (``main_etas``, one in a sound run), the chosen eta (``chosen_eta``,
    ``None`` without one at that level) and whether they agree (``None`` when there is
    nothing to compare with).

    Raises:
        UserError: the ``eta_cv`` trials admit no choice (see ``choose_etas``).
    """
    cv = table[table["block"] == ETA_CV]
    try:
        choices = etas_of_study(pipeline, trials)
    except ValueError as error:
        raise UserError(f"eta cross-validation: {error}") from None
    chosen = {k: choice for (human, k), choice in choices.items() if human == BEST_RESPONSE}
    played: dict[int, set[float]] = {}
    for row in trials:
        if row.block == MAIN and row.human == BEST_RESPONSE and row.eta is not None:
            played.setdefault(row.num_features, set()).add(row.eta)
    levels = sorted({row.num_features for row in trials if row.block == MAIN})
    main_block = Table(EtaMainBlock)
    for k in levels:
        main_etas = sorted(played.get(k, ()))
        chosen_eta = chosen[k].eta if k in chosen else None
        agree = None if chosen_eta is None else main_etas == [chosen_eta]
        main_block.append(
            EtaMainBlock(num_features=k, main_etas=main_etas, chosen_eta=chosen_eta, agree=agree)
        )
    chosen_etas = {k: choice.eta for k, choice in chosen.items() if not choice.fixed}
    return EtaCrossValidation(
        means=statistics.eta_means(cv) if not cv.empty else Table(EtaMean),
        uncertainty=statistics.eta_choice_uncertainty(cv, chosen_etas)
        if not cv.empty
        else Table(EtaUncertainty),
        chosen=Table(
            EtaChoice,
            (
                EtaChoice(num_features=k, eta=choice.eta, mean=choice.means.get(choice.eta))
                for k, choice in sorted(chosen.items())
            ),
        ),
        main_block=main_block,
    )


def _converged(table: pd.DataFrame) -> Table[Converged]:
    """Per robot, block and rationality: trials, and those whose estimate met the robot's
    stopping rule."""
    keys = ["robot", "block", "rationality"]
    counts = table.groupby(keys, sort=True)["converged"].agg(["size", "sum"])
    return Table(
        Converged,
        (
            Converged(
                robot=str(robot),
                block=str(block),
                rationality=float(rationality),
                trials=int(n),
                converged=int(k),
            )
            for (robot, block, rationality), (n, k) in counts.iterrows()
        ),
    )


def robot_comparison(table: pd.DataFrame, reference: str) -> RobotComparison:
    """Every other robot against the reference, on the same demonstrations.

    ``main``: per measure, the paired difference ``other - reference`` within each feature
    level and human, Holm over the measure's cells
    (:func:`~cirl_study.analysis.statistics.procedures.paired_differences`). ``lambda_sweep``: the
    same per rationality, feature level and human of the sweep, Holm over the measure's whole
    sweep. A negative difference means the other robot did better.
    """
    main = table[table["block"] == MAIN]
    sweep = table[table["block"] == LAMBDA_SWEEP]
    cells = ["num_features", "human"]
    return RobotComparison(
        reference=reference,
        others=sorted(set(main["robot"]) - {reference}),
        main=paired_rows(main, "robot", reference, cells),
        lambda_sweep=paired_rows(sweep, "robot", reference, ["rationality", *cells])
        if not sweep.empty
        else Table(PairedDifference),
    )


def analyse(trials: Sequence[TrialRow], pipeline: Pipeline) -> StudyResults:
    """Run every analysis of the study's design on checked trials: :func:`estimates` and
    :func:`tests`, in this process.

    Args:
        trials: the trials' rows (:class:`~cirl_study.record.TrialRow`), already accepted by
            :func:`~cirl_study.analysis.table.check_design`, in any order.
        pipeline: the run's pipeline (the order of its humans and robots, its name).

    Returns:
        The results (see the module docstring), with no claims judged yet, no run id and
        nothing partial (:func:`with_claims` adds them); a section whose cells the run lacks
        is ``None``.
    """
    everything = trial_table(trials)
    return tests(estimates(trials, everything, pipeline), everything, pipeline)


def models(everything: pd.DataFrame) -> pd.DataFrame:
    """The trials of the simulated humans: ``everything`` but the participants' (which
    :mod:`cirl_study.analysis.results.participants` analyses)."""
    if "participant" not in everything:
        return everything
    return everything[everything["participant"].isna()]


def paper_main_block(everything: pd.DataFrame, design: Design) -> pd.DataFrame:
    """The ``main`` block's trials of the paper's humans watched by the reference robot: the
    table the paper's tests read."""
    main = everything[everything["block"] == MAIN]
    reference = reference_robot(design.robots)
    return main[(main["robot"] == reference) & main["human"].isin(PAPER_HUMANS)]


def _cell_means(frame: pd.DataFrame, by: list[str]) -> Table[CellMean]:
    """Each measure's mean with its CI in each group of ``by`` (of ``frame``'s trials that
    have a value of it)."""
    return Table(
        CellMean,
        (
            row
            for m, kept in measured(frame)
            for row in statistics.group_mean_rows(kept, m, by, CellMean)
        ),
    )


@statistics.undefined_as_nan()
def estimates(
    trials: Sequence[TrialRow], everything: pd.DataFrame, pipeline: Pipeline
) -> Estimates:
    """What the trials measured, with confidence intervals: everything the figures draw.

    The sections ``pipeline, trials, design, undefined, cells, lambda_sweep, converged, eta_cv,
    robots`` of :func:`analyse` and, where the run has the paper's humans, the paper's
    ``figure1``, from the rows and their table ``everything``
    (:func:`~cirl_study.analysis.table.trial_table`).
    """
    design = design_of(everything, pipeline)
    people_table, everything = everything, models(everything)
    reference = reference_robot(design.robots)
    main = everything[everything["block"] == MAIN]
    sweep = everything[everything["block"] == LAMBDA_SWEEP]
    by_cell = ["num_features", "human", "robot"]
    return Estimates(
        pipeline=pipeline.name,
        trials=_trial_counts(everything),
        design=_design(main, design, pipeline),
        cells=_cell_means(main, by_cell),
        lambda_sweep=_cell_means(sweep, ["rationality", *by_cell])
        if not sweep.empty
        else Table(CellMean),
        converged=_converged(everything),
        eta_cv=eta_cv(trials, everything[everything["robot"] == reference], pipeline),
        figure1=None
        if PAPER.lacking(design)
        else figure1_subject(paper_main_block(everything, design), reference),
        robots=robot_comparison(everything, reference) if len(design.robots) > 1 else None,
        undefined=undefined(everything),
        participants=participants_section(trials, people_table, pipeline),
    )


@statistics.undefined_as_nan()
def tests(estimated: Estimates, everything: pd.DataFrame, pipeline: Pipeline) -> StudyResults:
    """The results of :func:`analyse`: the ``estimated`` sections of the trials' table
    ``everything`` with the tests of the study's design, those the results register
    (:func:`~cirl_study.analysis.results.per_measure.run_tests`), the paper's (``paper``,
    :func:`paper_tests`), the teaching sections (:mod:`cirl_study.analysis.results.teaching`)
    and the people's (:mod:`cirl_study.analysis.results.participants`)."""
    design = design_of(everything, pipeline)
    everything = models(everything)
    main = everything[everything["block"] == MAIN]
    return StudyResults(
        pipeline=estimated.pipeline,
        trials=estimated.trials,
        design=estimated.design,
        cells=estimated.cells,
        **run_tests(StudyResults, main, design),
        lambda_sweep=estimated.lambda_sweep,
        converged=estimated.converged,
        eta_cv=estimated.eta_cv,
        paper=None  # the paper's figure 1 is drawn exactly where the run has its humans
        if estimated.figure1 is None
        else paper_tests(paper_main_block(everything, design), design, estimated.figure1),
        robots=estimated.robots,
        milli_dragan=None if MILLI_DRAGAN.lacking(design) else teaching.milli_dragan(main),
        best_response_vs_pedagogic=None
        if VERSUS_PEDAGOGIC.lacking(design)
        else teaching.versus_pedagogic(main),
        regret_optimal=None
        if REGRET_OPTIMAL_GAP.lacking(design)
        else teaching.regret_optimal(main),
        run_id=None,
        partial=None,
        claims=Table(ClaimRow),
        undefined=estimated.undefined,
        participants=estimated.participants,
    )


def paper_tests(paper_main: pd.DataFrame, design: Design, figure1: Figure1) -> PaperSection:
    """The paper's tests on the ``main`` block of its humans and the reference robot
    (:func:`paper_main_block`): those :class:`~cirl_study.analysis.results.types.PaperSection`
    registers (each per measure), ``cronbach_alpha`` (of the paper's three measures), and the
    reward draw of Figure 1."""
    rows = (
        f"all {len(paper_main)} trials of the main block, one row per trial (both humans, "
        "every feature level), the three measures on their own scales"
    )
    alpha = statistics.cronbach_alpha(paper_main[list(PAPER_MEASURES)].reset_index(drop=True), rows)
    return PaperSection(
        **run_tests(PaperSection, paper_main, design), cronbach_alpha=alpha, figure1=figure1
    )


def with_claims(
    results: StudyResults,
    *,
    run_id: str | None,
    partial: Mapping[str, Any] | None,
    theory: Mapping[str, Any] | None,
) -> StudyResults:
    """``results`` with what the report adds to them: the run's id, what a partial run lacks
    (``None`` for a complete one: its ``planned``, ``logged``, ``missing``, ``damaged_files``
    and ``main_subjects_left_out``), ``theory`` itself (when given) and every claim judged on
    them (:func:`cirl_study.analysis.results.claims.evaluate_claims`, then those of ``theory``): the
    content of ``results.json``."""
    from cirl_study.analysis.results.claims import evaluate_claims

    return msgspec.structs.replace(
        results,
        run_id=run_id,
        partial=None if partial is None else Partial(**partial),
        claims=Table(ClaimRow, evaluate_claims(results, theory)),
        theory=None if theory is None else plain(theory),
    )
