"""The types of ``results.json``: a study's (:class:`StudyResults`), a multiverse's
(:class:`MultiverseResults`), which the claims are judged on and the reports read, and a
calibration's (:class:`CalibrationResults`).

The analysis makes plain data (:data:`Results`); :func:`checked` gives it its type, and
``results.json`` is the typed record's encoding (``msgspec.to_builtins``). Their JSON Schemas,
generated from the same declarations (:func:`json_schema`), are kept in ``docs/``
(``results-study.schema.json``, ``results-multiverse.schema.json``,
``results-calibration.schema.json``) for readers in other
languages; a test keeps them equal. A number that is undefined (a mean of nothing, a test on
a constant sample) is ``null``, never NaN; a field with a default is left out where it has
its default, so a missing optional field reads as ``null``. Every p-value is beside its
common logarithm ``log10_p``, which holds it where the double ``p`` underflows to 0. The
tests compute some of these records directly
(:func:`cirl_study.analysis.anova.repeated_measures_anova`,
:func:`cirl_study.analysis.statistics.pairwise_differences`), with NaN for an undefined
number until the results are made plain.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TypeVar

import msgspec
import pandas as pd

from cirl_study.errors import UserError

Results = dict[str, Any]
"""The results as plain JSON data (what ``results.json`` stores, and what the analysis makes
and the renderers read), before :func:`checked` gives them their type."""

Number = float | None
"""A number of the results; ``None`` (``null``) where it is undefined."""

_ROW = {"frozen": True, "kw_only": True, "forbid_unknown_fields": True, "omit_defaults": True}


class CellMean(msgspec.Struct, **_ROW):
    """A measure's mean with its t-based 95% CI in one cell (``sweep``: at one rationality)."""

    measure: str
    num_features: int
    human: str
    robot: str
    n: int
    mean: Number
    sd: Number
    ci95_low: Number
    ci95_high: Number
    rationality: float | None = None


class Probability(msgspec.Struct, **_ROW):
    """A p-value with its common logarithm: ``p`` may underflow to 0, ``log10_p`` does not."""

    p: Number
    log10_p: Number


class Sphericity(msgspec.Struct, **_ROW):
    """Mauchly's test of one within effect, and its Greenhouse-Geisser and Huynh-Feldt
    corrections (:mod:`cirl_study.analysis.anova`).

    ``reason`` says why some of them are ``null`` (left out where every one is reported): no
    error variance, or fewer error degrees of freedom than contrasts (all of them ``null``),
    or a singular error matrix (``mauchly_w`` 0, ``mauchly`` ``null``, the epsilons and
    corrected p-values reported).
    """

    mauchly_w: Number
    mauchly: Probability
    gg_epsilon: Number
    hf_epsilon: Number
    gg: Probability
    hf: Probability
    reason: str | None = None


class AnovaEffect(msgspec.Struct, **_ROW):
    """One effect of :func:`cirl_study.analysis.anova.repeated_measures_anova`.

    ``sphericity`` is ``None`` for a between-subjects effect and for a within effect on one
    degree of freedom (where sphericity holds trivially).
    """

    measure: str
    effect: str
    df1: int
    df2: int
    SS: Number
    MS: Number
    F: Number
    p: Number
    log10_p: Number
    np2: Number
    ges: Number
    sphericity: Sphericity | None


class PairedT(msgspec.Struct, **_ROW):
    """A paired t-test of ``d``: its mean with the t-based 95% CI, ``t`` on ``df`` degrees of
    freedom, the two-sided ``p`` with its log10, and ``d_z = mean(d) / sd(d)``."""

    mean_diff: Number
    ci95_low: Number
    ci95_high: Number
    t: Number
    df: int
    p: Number
    log10_p: Number
    d_z: Number


class PairedComparison(PairedT, **_ROW):
    """One paired comparison of two levels of a within factor in one cell of the others
    (:func:`cirl_study.analysis.statistics.pairwise_differences`).

    ``human`` and ``robot`` name the cell (``None`` for the factor compared); the
    difference is ``level_a - level_b``; ``p_holm`` is Holm's adjustment over the family,
    computed from ``log10_p`` (so it never underflows to 0 where ``p`` does not).
    """

    measure: str
    factor: str
    level_a: str
    level_b: str
    human: str | None
    robot: str | None
    num_features: int
    n: int
    mean_a: Number
    mean_b: Number
    p_holm: Number
    log10_p_holm: Number


class PairedDifference(PairedT, **_ROW):
    """One row of :func:`cirl_study.analysis.statistics.paired_differences`: ``level`` against
    the baseline in one group (its keys among ``human, robot, num_features, rationality,
    pooled, universe``); a multiverse's human effects have neither ``level`` nor Holm."""

    measure: str
    n: int
    mean_baseline: Number
    mean_level: Number
    level: str | None = None
    p_holm: Number = None
    log10_p_holm: Number = None
    human: str | None = None
    robot: str | None = None
    num_features: int | None = None
    rationality: float | None = None
    pooled: str | None = None
    universe: str | None = None


class SimpleEffect(PairedT, **_ROW):
    """The simple effect of human at one feature level, with its BCa bootstrap intervals
    (:func:`cirl_study.analysis.statistics.simple_effects`)."""

    measure: str
    num_features: int
    n: int
    mean_expert: Number
    mean_best_response: Number
    p_holm: Number
    log10_p_holm: Number
    boot_diff_low: Number
    boot_diff_high: Number
    boot_d_z_low: Number
    boot_d_z_high: Number


class TukeyRow(msgspec.Struct, **_ROW):
    measure: str
    a_num_features: int
    a_human: str
    b_num_features: int
    b_human: str
    mean_a: Number
    mean_b: Number
    diff: Number
    se: Number
    T: Number
    p_tukey: Number
    log10_p_tukey: Number
    hedges: Number


class WilcoxonRow(msgspec.Struct, **_ROW):
    measure: str
    num_features: int
    n: int
    W: Number
    p: Number
    log10_p: Number
    rbc: Number
    cles: Number


class CronbachAlpha(msgspec.Struct, **_ROW):
    raw: Number
    standardised: Number
    ci95: list[Number]
    ci95_standardised: list[Number]
    n_rows: int
    n_items: int
    items: list[str]
    rows: str


class Figure1(msgspec.Struct, **_ROW):
    subject: str
    num_features: int
    regret_expert: Number
    regret_best_response: Number
    rule: str
    robot: str


class PaperSection(msgspec.Struct, **_ROW):
    """The paper's analyses on the reference robot's trials of its two humans."""

    anova: list[AnovaEffect]
    simple_effects: list[SimpleEffect]
    tukey_hsd: list[TukeyRow]
    wilcoxon: list[WilcoxonRow]
    cronbach_alpha: CronbachAlpha
    figure1: Figure1


class RobotComparison(msgspec.Struct, **_ROW):
    reference: str
    others: list[str]
    main: list[PairedDifference]
    lambda_sweep: list[PairedDifference]


class EtaMean(msgspec.Struct, **_ROW):
    measure: str
    num_features: int
    eta: float
    n: int
    mean: Number
    sd: Number
    ci95_low: Number
    ci95_high: Number


class EtaUncertainty(msgspec.Struct, **_ROW):
    num_features: int
    n: int
    eta: float
    mean: Number
    se: Number
    within_one_se: list[float]
    runner_up: float | None = None
    runner_up_mean: Number = None
    mean_diff: Number = None
    ci95_low: Number = None
    ci95_high: Number = None
    t: Number = None
    df: int | None = None
    p: Number = None
    log10_p: Number = None
    d_z: Number = None


class EtaChoice(msgspec.Struct, **_ROW):
    num_features: int
    eta: float
    mean: Number


class EtaMainBlock(msgspec.Struct, **_ROW):
    num_features: int
    main_etas: list[float]
    chosen_eta: float | None
    agree: bool | None


class EtaCrossValidation(msgspec.Struct, **_ROW):
    means: list[EtaMean]
    uncertainty: list[EtaUncertainty]
    chosen: list[EtaChoice]
    main_block: list[EtaMainBlock]


class Converged(msgspec.Struct, **_ROW):
    robot: str
    block: str
    rationality: float
    trials: int
    converged: int


class MilliDragan(msgspec.Struct, **_ROW):
    anova: list[AnovaEffect]
    robot_effect: list[PairedDifference]
    robot_effect_by_level: list[PairedDifference]


class RegretGap(msgspec.Struct, **_ROW):
    num_features: int
    human: str
    n: int
    mean_regret_optimal: Number
    mean_human: Number
    mean_gap: Number
    ci95_low: Number
    ci95_high: Number
    p: Number
    log10_p: Number
    smallest_gap: Number
    share_optimal: Number


class RegretOptimal(msgspec.Struct, **_ROW):
    gaps: list[RegretGap]


class ClaimRow(msgspec.Struct, **_ROW):
    """One claim as judged (:func:`cirl_study.analysis.claims.evaluate_claims`)."""

    id: str
    source: str
    claim: str
    rule: str
    measurement: str
    values: dict[str, Any]
    tested: bool
    reproduced: bool | None
    evidence: list[str]


class Teaching(msgspec.Struct, **_ROW):
    """The pipeline's ``[teaching]``: ``hypotheses`` per subject, drawn from the prior or, with
    ``of_tasks``, the pipeline's tasks."""

    hypotheses: int
    includes_truth: bool
    alpha: float
    demonstration: str
    learning_paths: int
    of_tasks: bool = False


class StudyDesign(msgspec.Struct, **_ROW):
    """The design section of a study's results: its factors
    (:class:`cirl_study.analysis.cells.Design`), subjects, lambdas and etas."""

    humans: list[str]
    baseline: str
    robots: list[str]
    reference_robot: str
    feature_levels: list[int]
    subjects_per_level: dict[str, int]
    main_rationality: list[float]
    main_eta: dict[str, list[float]]
    sweep_rationalities: list[float]
    teaching: Teaching | None


class Undefined(msgspec.Struct, **_ROW):
    """A measure ``trials`` of the analysed trials have no value of (``null`` in their records:
    undefined for them, or not logged by their log format), of ``subjects`` reward draws: each
    is left out of all the measure's statistics
    (:func:`cirl_study.analysis.measure_rows.measured`)."""

    measure: str
    trials: int
    subjects: int


class Partial(msgspec.Struct, **_ROW):
    planned: int
    logged: int
    missing: str | None
    damaged_files: int
    main_subjects_left_out: int


class Estimates(msgspec.Struct, **_ROW):
    """What a study's trials measured, with confidence intervals
    (:func:`cirl_study.analysis.results.estimates`): everything its figures draw, and the part
    of :class:`StudyResults` known before any test. ``figure1`` is the paper's Figure 1 reward
    draw, where the run has the paper's humans (``None`` otherwise); ``undefined`` is empty
    unless some trials have no value of a measure."""

    pipeline: str
    trials: dict[str, int]
    design: StudyDesign
    cells: list[CellMean]
    lambda_sweep: list[CellMean]
    converged: list[Converged]
    eta_cv: EtaCrossValidation
    figure1: Figure1 | None
    robots: RobotComparison | None
    undefined: list[Undefined] = []


class StudyResults(msgspec.Struct, **_ROW):
    """``results.json`` of a study (:func:`cirl_study.analysis.results.analyse`, with the
    report's ``run_id``, ``partial``, ``claims`` and ``theory``); ``undefined`` only where
    some trials have no value of a measure."""

    pipeline: str
    trials: dict[str, int]
    design: StudyDesign
    cells: list[CellMean]
    anova: list[AnovaEffect]
    pairwise: list[PairedComparison]
    against_baseline: list[PairedDifference]
    lambda_sweep: list[CellMean]
    converged: list[Converged]
    eta_cv: EtaCrossValidation
    paper: PaperSection | None
    robots: RobotComparison | None
    milli_dragan: MilliDragan | None
    best_response_vs_pedagogic: list[PairedDifference] | None
    regret_optimal: RegretOptimal | None
    run_id: str | None
    partial: Partial | None
    claims: list[ClaimRow]
    theory: dict[str, Any] | None = None
    undefined: list[Undefined] = []


class UniverseClaim(msgspec.Struct, **_ROW):
    tested: bool
    reproduced: bool | None
    values: dict[str, Any]


class UniverseSummary(msgspec.Struct, **_ROW):
    id: str
    base: bool
    settings: dict[str, Any]
    claims: dict[str, UniverseClaim]
    eta: list[EtaChoice]
    anova: list[AnovaEffect]
    cells: list[CellMean]
    cronbach_alpha: CronbachAlpha


class LevelShare(msgspec.Struct, **_ROW):
    level: Any
    universes: int
    reproduced: int


class ClaimShare(msgspec.Struct, **_ROW):
    id: str
    universes: int
    reproduced: int
    base_reproduced: bool | None
    holds_in: list[str]
    by_level: dict[str, list[LevelShare]]


class Coefficient(msgspec.Struct, **_ROW):
    """One coefficient of :class:`Regression`; the intercept has no ``axis`` or ``level``."""

    axis: str | None
    level: Any
    estimate: Number
    ci95_low: Number
    ci95_high: Number
    p: Number
    log10_p: Number


class Regression(msgspec.Struct, **_ROW):
    """The OLS regression of the universes' human effects on the axes (none without
    residual degrees of freedom)."""

    universes: int
    df_residual: Number
    coefficients: list[Coefficient] | None
    variance_shares: dict[str, Number] | None
    r_squared: Number = None


class SignFlipStatistic(msgspec.Struct, **_ROW):
    """One statistic of a joint test, its sign-flip ``p`` (at least ``1 / (1 + resamples)``)
    and its ``log10_p``."""

    observed: Number
    p: Number
    log10_p: Number


class JointTest(msgspec.Struct, **_ROW):
    universes: int
    subjects: int
    resamples: int
    seed: int
    median_effect: SignFlipStatistic
    share_significant: SignFlipStatistic
    stouffer_z: SignFlipStatistic


class MultiverseResults(msgspec.Struct, **_ROW):
    """``results.json`` of a multiverse (:func:`cirl_study.analysis.multiverse.analyse_multiverse`,
    with the report's ``run_id``)."""

    pipeline: str
    base_universe: str
    axes: dict[str, list[Any]]
    trials: dict[str, int]
    universes: list[UniverseSummary]
    effects: list[PairedDifference]
    claims: list[ClaimShare]
    regression: dict[str, Regression]
    joint_test: dict[str, JointTest]
    run_id: str | None


class TargetCell(msgspec.Struct, **_ROW):
    """One published cell of a calibration target (:func:`cirl_study.analysis.calibration.
    read_target`): a measure's mean in one ``num_features`` x ``human`` cell, of ``robot``
    (``None``: the reference robot of each universe), and its uncertainty on the log scale
    (``log_se``: the standard error of :math:`\\ln` of the value; ``None`` when the target
    gives none)."""

    measure: str
    num_features: int
    human: str
    robot: str | None
    value: float
    log_se: float | None


class CellComparison(msgspec.Struct, **_ROW):
    """A target cell beside a universe's measurement of it: the mean over ``n`` subjects,
    its standard error on the log scale (:math:`s / (\\bar y \\sqrt n)`) and
    ``log_ratio`` :math:`\\ln(\\bar y / t)`."""

    measure: str
    num_features: int
    human: str
    robot: str
    target: float
    target_log_se: float | None
    measured: float
    measured_log_se: Number
    n: int
    log_ratio: float


class UniverseDistance(msgspec.Struct, **_ROW):
    """One universe's distance to the target (``docs/multiverse.md``, *Calibration*):
    ``mean_squared_log_ratio`` over every target cell, and where the target gives
    uncertainties the chi-square on the log scale over those cells (``chi_square_df`` of
    them) with its upper-tail ``p``. A universe that lacks a target cell, or measures a mean
    of 0 where the log is undefined, is not ranked: ``missing`` says why."""

    id: str
    base: bool
    settings: dict[str, Any]
    cells: list[CellComparison]
    mean_squared_log_ratio: Number
    chi_square: Number
    chi_square_df: int
    p: Number
    log10_p: Number
    missing: list[str]


class LevelDistance(msgspec.Struct, **_ROW):
    """One level of an axis: the ranked universes at it, the nearest of them and the median
    of their distances."""

    level: Any
    universes: int
    nearest: str
    nearest_distance: float
    median_distance: float


class AxisDistance(msgspec.Struct, **_ROW):
    """Per axis that varies among the ranked universes: each level's distances, the level of
    the nearest universe (``best``), and how far the nearest distance moves across levels
    (``spread``: the largest level's nearest distance minus the smallest's)."""

    axis: str
    best: Any
    spread: float
    levels: list[LevelDistance]


class RefinementProbe(msgspec.Struct, **_ROW):
    """A point the refinement measured, in the order measured (``docs/multiverse.md``,
    *Refinement*): its universe and that universe's values of the searched settings, the axis
    and step factor of the move that proposed it, where its distance comes from (``source``:
    ``run``, a universe of the run; ``played``, a probe played now; ``reused``, a probe whose
    run the probes directory held complete), the distance and chi-square as
    :class:`UniverseDistance` has them, and whether the search moved to it."""

    id: str
    settings: dict[str, Any]
    axis: str
    step: float
    source: str
    mean_squared_log_ratio: Number
    chi_square: Number
    chi_square_df: int
    p: Number
    log10_p: Number
    accepted: bool


class Refinement(msgspec.Struct, **_ROW):
    """The coordinate search from the nearest universe (``start``) over the numeric settings
    ``axes`` (:mod:`cirl_study.analysis.refine`): its step factors, from ``first_step`` down
    to ``min_step``, its budget, every point measured, the probes played now and reused, why
    it stopped (``exact``, ``converged`` or ``budget``) and the universe it ended at with its
    distance (``final``; ``start``'s own when no probe was nearer)."""

    start: str
    axes: list[str]
    first_step: float
    min_step: float
    max_probes: int
    probes: list[RefinementProbe]
    played: int
    reused: int
    stop: str
    final: UniverseDistance


class CalibrationResults(msgspec.Struct, **_ROW):
    """``results.json`` of a calibration (:func:`cirl_study.analysis.calibration.calibrate`):
    the target, every universe's distance to it (ranked universes first, nearest first), the
    axes, the claims judged in the nearest universe, and with ``--refine`` the refinement
    (left out without)."""

    pipeline: str
    target_file: str
    target_sha256: str
    target: list[TargetCell]
    universes: list[UniverseDistance]
    axes: list[AxisDistance]
    nearest_claims: list[ClaimRow]
    run_id: str | None
    refinement: Refinement | None = None


SCHEMAS: dict[str, type[msgspec.Struct]] = {
    "results-study.schema.json": StudyResults,
    "results-multiverse.schema.json": MultiverseResults,
    "results-calibration.schema.json": CalibrationResults,
}
"""The schema files of ``docs/``, by name, and the type each is generated from."""

Typed = TypeVar("Typed", StudyResults, MultiverseResults, CalibrationResults)


def frame(rows: Sequence[msgspec.Struct]) -> pd.DataFrame:
    """``rows`` of the typed results as a table: one row each, a column per field."""
    return pd.DataFrame([msgspec.structs.asdict(row) for row in rows])


def checked(results: Results, kind: type[Typed]) -> Typed:
    """``results`` as the typed record ``kind``: every field present, of its type.

    Raises:
        UserError: ``results`` does not have the shape of ``kind`` (an analysis fault: the
            message names the field).
    """
    try:
        return msgspec.convert(results, kind)
    except msgspec.ValidationError as error:
        raise UserError(f"the results do not match {kind.__name__}: {error}") from None


def json_schema(kind: type[msgspec.Struct]) -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of ``kind``, as kept in ``docs/``."""
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", **msgspec.json.schema(kind)}


def write_schemas(directory: Path | str) -> None:
    """Write the schema files of :data:`SCHEMAS` into ``directory`` (``docs/``): ``python -c
    "from cirl_study.analysis.result_types import write_schemas; write_schemas('docs')"``."""
    for name, kind in SCHEMAS.items():
        text = json.dumps(json_schema(kind), indent=2, sort_keys=True)
        (Path(directory) / name).write_text(text + "\n", encoding="utf-8", newline="\n")
