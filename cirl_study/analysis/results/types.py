"""The types of ``results.json``: a study's (:class:`StudyResults`), a multiverse's
(:class:`MultiverseResults`), which the claims are judged on and the reports read, and a
calibration's (:class:`CalibrationResults`).

The analysis builds these records directly, statistic by statistic, each returning its typed
row or rows; ``results.json`` is the record's encoding (``msgspec.to_builtins``), and
:func:`checked` decodes one read back. Their JSON Schemas, generated from the same
declarations (:func:`json_schema`), are kept in ``docs/`` (``results-study.schema.json``,
``results-multiverse.schema.json``, ``results-calibration.schema.json``) for readers in other
languages; a test keeps them equal.

Every record is a :class:`Record`, which holds to these contracts however it is made (built by
the analysis or decoded): a number that is undefined (a mean of nothing, a test on a constant
sample) or infinite is ``None`` (``null``), never NaN; every number is a Python ``int`` or
``float`` of its field's type; a field with a default is left out of the encoding where it has
its default, so a missing optional field reads as ``null``; and every table (a field of
:data:`Rows`) is a :class:`Table`, whose :meth:`~Table.to_frame` gives it as a
:class:`pandas.DataFrame`. Every p-value is beside its common logarithm ``log10_p``, which holds
it where the double ``p`` underflows to 0.

The per-measure tests of a study are registered by the fields that hold their rows
(:mod:`cirl_study.analysis.results.registry`): those of :class:`StudyResults` and
:class:`PaperSection` annotated with a :class:`~cirl_study.analysis.results.registry.StudyTest`.
"""

from __future__ import annotations

import functools
import json
import math
import numbers
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal, TypeVar

import msgspec
from msgspec import inspect

from cirl_study.analysis.results.registry import Registered, StudyTest, registered
from cirl_study.errors import UserError

if TYPE_CHECKING:
    import pandas as pd

Number = float | None
"""A number of the results; ``None`` (``null``) where it is undefined."""

Row = TypeVar("Row", bound=msgspec.Struct)
"""The row type of a :class:`Table`."""


class Table(list[Row]):
    """A table of the results: its rows, in order, each of :attr:`row_type`.

    It is a list (``results.json`` stores it as an array of objects) that knows its row type,
    so that :meth:`to_frame` has a column per field even when it holds no row.
    """

    def __init__(self, row_type: type[Row], rows: Iterable[Row] = ()) -> None:
        super().__init__(rows)
        self.row_type = row_type

    def to_frame(self) -> pd.DataFrame:
        """The table as a :class:`pandas.DataFrame`: a row per row, a column per field, in
        the row type's order (as pingouin's tests return theirs).

        A field that is itself a record is flattened into a column per field of it, named by
        the path joined with ``_`` (an ANOVA row's ``sphericity.gg.p`` is the column
        ``sphericity_gg_p``; missing where the record is ``None``); a number field is a
        ``float64`` column, NaN where the number is undefined; a list or a mapping stays one
        column of objects.
        """
        import pandas as pd

        columns = _columns(self.row_type)
        frame = pd.DataFrame(
            {name: [_follow(row, path) for row in self] for name, path, _ in columns},
            columns=[name for name, _, _ in columns],
        )
        numbers = [name for name, _, number in columns if number]
        return frame.astype(dict.fromkeys(numbers, "float64"))

    def filter(self, keep: Callable[[Row], bool]) -> Table[Row]:
        """The rows for which ``keep`` is true, as a table of the same row type."""
        return Table(self.row_type, (row for row in self if keep(row)))


if TYPE_CHECKING:
    Rows = Table
else:
    Rows = list
"""``Rows[R]``, the type of a table field: to msgspec (the encoding, the JSON Schema,
decoding) a ``list[R]``; in Python a :class:`Table` of ``R``, which :class:`Record` makes
every such field hold."""


@functools.cache
def _columns(row_type: type[msgspec.Struct]) -> tuple[tuple[str, tuple[str, ...], bool], ...]:
    """The columns of :meth:`Table.to_frame`: each name, its path of attributes, and whether
    it is a number (``float`` or ``float | None``)."""
    found: list[tuple[str, tuple[str, ...], bool]] = []

    def walk(info: inspect.StructType, path: tuple[str, ...]) -> None:
        for field in info.fields:
            nested = _record_of(field.type)
            if nested is None:
                number = isinstance(_only(field.type), inspect.FloatType)
                found.append(("_".join((*path, field.name)), (*path, field.name), number))
            else:
                walk(nested, (*path, field.name))

    walk(inspect.type_info(row_type), ())
    return tuple(found)


def _only(kind: inspect.Type) -> inspect.Type | None:
    """The one type of ``kind`` besides ``None`` (``None`` when it has several)."""
    types = kind.types if isinstance(kind, inspect.UnionType) else (kind,)
    others = [t for t in types if not isinstance(t, inspect.NoneType)]
    return others[0] if len(others) == 1 else None


def _record_of(kind: inspect.Type) -> inspect.StructType | None:
    """The record type of a field that holds one (or ``None``), else ``None``."""
    only = _only(kind)
    return only if isinstance(only, inspect.StructType) else None


def _follow(row: msgspec.Struct, path: tuple[str, ...]) -> Any:
    """The value at ``path`` of ``row``: ``None`` past a record that is ``None``."""
    value: Any = row
    for name in path:
        if value is None:
            return None
        value = getattr(value, name)
    return value


_NUMBER, _INTEGER, _BOOLEAN, _NUMBERS, _TABLE, _TABLES = range(6)
"""How :meth:`Record.__post_init__` holds a field to its type (:func:`_kinds`)."""


class Record(msgspec.Struct, frozen=True, forbid_unknown_fields=True, omit_defaults=True):
    """A record of the results (frozen; an unknown field is refused when one is decoded; a
    field at its default is left out of the encoding).

    However it is made, its fields hold to the module's contracts: a ``float`` field (or
    ``float | None``) holds a ``float``, or ``None`` for a number that is not finite; an
    ``int`` or ``bool`` field a Python ``int`` or ``bool`` (not a numpy scalar); a list of
    numbers the same; and a table field (:data:`Rows`, or a mapping of them) a :class:`Table`.
    """

    def __post_init__(self) -> None:
        for name, kind, row_type in _kinds(type(self)):
            value = getattr(self, name)
            held = _held(value, kind, row_type)
            if held is not value:
                msgspec.structs.force_setattr(self, name, held)


@functools.cache
def _kinds(record: type[Record]) -> tuple[tuple[str, int, type | None], ...]:
    """The fields of ``record`` that :meth:`Record.__post_init__` holds to their type, each
    with how (and a table's row type)."""
    kinds = []
    for field in inspect.type_info(record).fields:
        only = _only(field.type)
        if isinstance(only, inspect.FloatType):
            kinds.append((field.name, _NUMBER, None))
        elif isinstance(only, inspect.IntType):
            kinds.append((field.name, _INTEGER, None))
        elif isinstance(only, inspect.BoolType):
            kinds.append((field.name, _BOOLEAN, None))
        elif isinstance(only, inspect.ListType) and isinstance(only.item_type, inspect.StructType):
            kinds.append((field.name, _TABLE, only.item_type.cls))
        elif isinstance(only, inspect.ListType) and isinstance(
            _only(only.item_type), inspect.FloatType
        ):
            kinds.append((field.name, _NUMBERS, None))
        elif (
            isinstance(only, inspect.DictType)
            and isinstance(only.value_type, inspect.ListType)
            and isinstance(only.value_type.item_type, inspect.StructType)
        ):
            kinds.append((field.name, _TABLES, only.value_type.item_type.cls))
    return tuple(kinds)


def _number(value: Any) -> Any:
    """A number (a Python or numpy one) as a finite Python ``float``, or ``None``; anything
    else as it is."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return value
    number = float(value)
    return number if math.isfinite(number) else None


def _held(value: Any, kind: int, row_type: type | None) -> Any:
    """``value`` of a field of ``kind`` held to its type (itself when it already is)."""
    if value is None:
        return None
    if kind == _NUMBER:
        return value if type(value) is float and math.isfinite(value) else _number(value)
    if kind == _INTEGER:
        return value if type(value) is int else int(value)
    if kind == _BOOLEAN:
        return value if type(value) is bool else bool(value)
    if kind == _NUMBERS:
        held = [_number(item) for item in value]
        return value if all(a is b for a, b in zip(held, value, strict=True)) else held
    if kind == _TABLE:
        return value if isinstance(value, Table) else Table(row_type, value)
    if all(isinstance(rows, Table) for rows in value.values()):
        return value
    return {key: _held(rows, _TABLE, row_type) for key, rows in value.items()}


class CellMean(Record, kw_only=True):
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


class Probability(Record, kw_only=True):
    """A p-value with its common logarithm: ``p`` may underflow to 0, ``log10_p`` does not."""

    p: Number
    log10_p: Number


class Sphericity(Record, kw_only=True):
    """Mauchly's test of one within effect, and its Greenhouse-Geisser and Huynh-Feldt
    corrections (:mod:`cirl_study.analysis.statistics.anova`).

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


class AnovaEffect(Record, kw_only=True):
    """One effect of :func:`cirl_study.analysis.statistics.anova.repeated_measures_anova`.

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


class PairedT(Record, kw_only=True):
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


class PairedComparison(PairedT, kw_only=True):
    """One paired comparison of two levels of a within factor in one cell of the others
    (:func:`cirl_study.analysis.statistics.procedures.pairwise_differences`).

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


class PairedDifference(PairedT, kw_only=True):
    """One row of :func:`cirl_study.analysis.statistics.procedures.paired_differences`: ``level``
    against the baseline in one group (its keys among ``human, robot, num_features, rationality,
    pooled, universe, condition``); a multiverse's human effects have neither ``level`` nor Holm."""

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
    condition: str | None = None


class SimpleEffect(PairedT, kw_only=True):
    """The simple effect of human at one feature level, with its BCa bootstrap intervals
    (:func:`cirl_study.analysis.statistics.procedures.simple_effects`)."""

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


class TukeyRow(Record, kw_only=True):
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


class WilcoxonRow(Record, kw_only=True):
    measure: str
    num_features: int
    n: int
    W: Number
    p: Number
    log10_p: Number
    rbc: Number
    cles: Number


class CronbachAlpha(Record, kw_only=True):
    raw: Number
    standardised: Number
    ci95: list[Number]
    ci95_standardised: list[Number]
    n_rows: int
    n_items: int
    items: list[str]
    rows: str


class Figure1(Record, kw_only=True):
    subject: str
    num_features: int
    regret_expert: Number
    regret_best_response: Number
    rule: str
    robot: str


class PaperSection(Record, kw_only=True):
    """The paper's analyses on the reference robot's trials of its two humans: its registered
    tests (:mod:`cirl_study.analysis.results.registry`), Cronbach's alpha of its three measures and
    the reward draw of Figure 1."""

    anova: Annotated[
        Rows[AnovaEffect],
        StudyTest(
            "The paper's mixed ANOVA",
            "cirl_study.analysis.results.per_measure:paper_anova",
            "cirl_study.analysis.report.paper_sections:paper_anova",
        ),
    ]
    simple_effects: Annotated[
        Rows[SimpleEffect],
        StudyTest(
            "Simple effects of human",
            "cirl_study.analysis.results.per_measure:simple_effects",
            "cirl_study.analysis.report.paper_sections:simple_effects",
        ),
    ]
    tukey_hsd: Annotated[
        Rows[TukeyRow],
        StudyTest(
            "Tukey HSD",
            "cirl_study.analysis.results.per_measure:tukey_hsd",
            "cirl_study.analysis.report.paper_sections:tukey",
        ),
    ]
    wilcoxon: Annotated[
        Rows[WilcoxonRow],
        StudyTest(
            "Wilcoxon signed-rank tests",
            "cirl_study.analysis.results.per_measure:wilcoxon",
            "cirl_study.analysis.report.paper_sections:wilcoxon",
        ),
    ]
    cronbach_alpha: CronbachAlpha
    figure1: Figure1


class RobotComparison(Record, kw_only=True):
    reference: str
    others: list[str]
    main: Rows[PairedDifference]
    lambda_sweep: Rows[PairedDifference]


class EtaMean(Record, kw_only=True):
    measure: str
    num_features: int
    eta: float
    n: int
    mean: Number
    sd: Number
    ci95_low: Number
    ci95_high: Number


class EtaUncertainty(Record, kw_only=True):
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


class EtaChoice(Record, kw_only=True):
    num_features: int
    eta: float
    mean: Number


class EtaMainBlock(Record, kw_only=True):
    num_features: int
    main_etas: list[float]
    chosen_eta: float | None
    agree: bool | None


class EtaCrossValidation(Record, kw_only=True):
    means: Rows[EtaMean]
    uncertainty: Rows[EtaUncertainty]
    chosen: Rows[EtaChoice]
    main_block: Rows[EtaMainBlock]


class Converged(Record, kw_only=True):
    robot: str
    block: str
    rationality: float
    trials: int
    converged: int


class MilliDragan(Record, kw_only=True):
    anova: Rows[AnovaEffect]
    robot_effect: Rows[PairedDifference]
    robot_effect_by_level: Rows[PairedDifference]


class RegretGap(Record, kw_only=True):
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


class RegretOptimal(Record, kw_only=True):
    gaps: Rows[RegretGap]


class ClaimRow(Record, kw_only=True):
    """One claim as judged (:func:`cirl_study.analysis.results.claims.evaluate_claims`).

    ``kind`` says what the claim is about: ``"data"``, the run's data, judged on its cells;
    ``"theory"``, a theorem checked exactly, which does not depend on the run. ``subjects`` is
    the fewest subjects (reward draws) in a cell a data claim was judged on; ``None`` for a
    theorem and for a claim not tested.
    """

    id: str
    kind: Literal["data", "theory"]
    source: str
    claim: str
    rule: str
    measurement: str
    values: dict[str, Any]
    tested: bool
    reproduced: bool | None
    subjects: int | None
    evidence: list[str]


class Teaching(Record, kw_only=True):
    """The pipeline's ``[teaching]``: ``hypotheses`` per subject, drawn from the prior or, with
    ``of_tasks``, the pipeline's tasks."""

    hypotheses: int
    includes_truth: bool
    alpha: float
    demonstration: str
    learning_paths: int
    of_tasks: bool = False


class StudyDesign(Record, kw_only=True):
    """The design section of a study's results: its factors
    (:class:`cirl_study.analysis.results.cells.Design`), subjects, lambdas and etas."""

    humans: list[str]
    baseline: str | None
    robots: list[str]
    reference_robot: str
    feature_levels: list[int]
    subjects_per_level: dict[str, int]
    main_rationality: list[float]
    main_eta: dict[str, list[float]]
    sweep_rationalities: list[float]
    teaching: Teaching | None


class Undefined(Record, kw_only=True):
    """A measure ``trials`` of the analysed trials have no value of (``null`` in their records:
    undefined for them, or not logged by their log format), of ``subjects`` reward draws: each
    is left out of all the measure's statistics
    (:func:`cirl_study.analysis.results.per_measure.measured`)."""

    measure: str
    trials: int
    subjects: int


class Partial(Record, kw_only=True):
    """What an incomplete run analysed anyway lacks: its trials ``planned`` and ``logged``, the
    blocks or files ``missing`` (in words), the damaged files salvaged and the ``main``-block
    subjects left out for lacking a cell."""

    planned: int
    logged: int
    missing: str | None
    damaged_files: int
    main_subjects_left_out: int


class Estimates(Record, kw_only=True):
    """What a study's trials measured, with confidence intervals
    (:func:`cirl_study.analysis.results.study.estimates`): everything its figures draw, and the part
    of :class:`StudyResults` known before any test. ``figure1`` is the paper's Figure 1 reward
    draw, where the run has the paper's humans (``None`` otherwise); ``undefined`` is ``None``
    unless some trials have no value of a measure."""

    pipeline: str
    trials: dict[str, int]
    design: StudyDesign
    cells: Rows[CellMean]
    lambda_sweep: Rows[CellMean]
    converged: Rows[Converged]
    eta_cv: EtaCrossValidation
    figure1: Figure1 | None
    robots: RobotComparison | None
    undefined: Rows[Undefined] | None = None
    participants: ParticipantsSection | None = None


class ParticipantsDesign(Record, kw_only=True):
    """The people of a run with ``[participants]``: the conditions (``baseline`` first), how
    participants meet them (``between`` or ``within``), the tasks and robots, the participants
    per condition, and those of them whose demonstrations entered the ANOVA
    (``complete``: every task, in every condition of a within design); ``left_out`` the others'
    subject ids; ``sums_of_squares`` the type (2 or 3) of the ANOVA's."""

    conditions: list[str]
    baseline: str
    design: str
    sums_of_squares: int
    tasks: list[str]
    robots: list[str]
    participants: dict[str, int]
    complete: dict[str, int]
    left_out: list[str]


class ConditionCell(Record, kw_only=True):
    """A measure's mean with its t-based 95% CI over the participants of one condition and
    robot, on one ``task`` (``None``: each participant's mean over her tasks)."""

    measure: str
    condition: str
    robot: str
    n: int
    mean: Number
    sd: Number
    ci95_low: Number
    ci95_high: Number
    task: str | None = None


class ConditionDifference(Record, kw_only=True):
    """``level`` against the ``baseline`` condition for one measure and robot, on each
    participant's mean over her tasks: Welch's t-test between participants (``df`` Welch's,
    fractional) or the paired t-test within (``d = level - baseline`` per participant); the
    t-based CI of the difference of the means, ``d``, Cohen's d on the pooled SD (between) or
    ``d_z`` (within), Holm over the measure's rows."""

    measure: str
    robot: str
    level: str
    baseline: str
    paired: bool
    n_baseline: int
    n_level: int
    mean_baseline: Number
    mean_level: Number
    mean_diff: Number
    ci95_low: Number
    ci95_high: Number
    t: Number
    df: Number
    p: Number
    log10_p: Number
    d: Number
    p_holm: Number
    log10_p_holm: Number


class ParticipantMean(Record, kw_only=True):
    """One participant's mean of a measure over her tasks, in one condition, with one
    robot."""

    measure: str
    subject: str
    condition: str
    robot: str
    mean: Number


class ClosestModel(Record, kw_only=True):
    """Which simulated human a participant's demonstrations are closest to: per model human,
    the mean over the participant's tasks of the L1 distance between the feature counts of her
    path and the model's (``distance``) and of the Jaccard overlap of their cells
    (``overlap``); ``closest`` the model of the least distance (of the larger overlap on a
    tie)."""

    participant: str
    condition: str
    closest: str
    distance: dict[str, float]
    overlap: dict[str, float]


class ParticipantsSection(Record, kw_only=True):
    """The people of a run with ``[participants]``
    (:func:`cirl_study.analysis.results.participants.participants_section`)."""

    design: ParticipantsDesign
    cells: Rows[ConditionCell]
    means: Rows[ParticipantMean]
    anova: Rows[AnovaEffect]
    conditions: Rows[ConditionDifference]
    robots: Rows[PairedDifference]
    cronbach_alpha: CronbachAlpha | None
    closest: Rows[ClosestModel]


class StudyResults(Record, kw_only=True):
    """``results.json`` of a study (:func:`cirl_study.analysis.results.study.analyse`, with the
    report's ``run_id``, ``partial``, ``claims`` and ``theory``,
    :func:`cirl_study.analysis.results.study.with_claims`); ``undefined`` only where some trials
    have no value of a measure (``None`` otherwise). ``anova``, ``pairwise``, ``against_baseline``
    and the paper's ``anova``, ``simple_effects``, ``tukey_hsd`` and ``wilcoxon`` are
    registered tests (:mod:`cirl_study.analysis.results.registry`)."""

    pipeline: str
    trials: dict[str, int]
    design: StudyDesign
    cells: Rows[CellMean]
    anova: Annotated[
        Rows[AnovaEffect],
        StudyTest(
            "Repeated-measures ANOVA",
            "cirl_study.analysis.results.per_measure:anova",
            "cirl_study.analysis.report.study_sections:anova",
        ),
    ]
    pairwise: Annotated[
        Rows[PairedComparison],
        StudyTest(
            "Pairwise comparisons",
            "cirl_study.analysis.results.per_measure:pairwise",
            "cirl_study.analysis.report.study_sections:pairwise",
        ),
    ]
    against_baseline: Annotated[
        Rows[PairedDifference],
        StudyTest(
            "Every human against the baseline",
            "cirl_study.analysis.results.per_measure:against_baseline",
            "cirl_study.analysis.report.study_sections:against_baseline",
        ),
    ]
    lambda_sweep: Rows[CellMean]
    converged: Rows[Converged]
    eta_cv: EtaCrossValidation
    paper: PaperSection | None
    robots: RobotComparison | None
    milli_dragan: MilliDragan | None
    best_response_vs_pedagogic: Rows[PairedDifference] | None
    regret_optimal: RegretOptimal | None
    run_id: str | None
    partial: Partial | None
    claims: Rows[ClaimRow]
    theory: dict[str, Any] | None = None
    undefined: Rows[Undefined] | None = None
    participants: ParticipantsSection | None = None


class UniverseClaim(Record, kw_only=True):
    tested: bool
    reproduced: bool | None
    values: dict[str, Any]


class UniverseSummary(Record, kw_only=True):
    id: str
    base: bool
    settings: dict[str, Any]
    claims: dict[str, UniverseClaim]
    eta: Rows[EtaChoice]
    anova: Rows[AnovaEffect]
    cells: Rows[CellMean]
    cronbach_alpha: CronbachAlpha


class LevelShare(Record, kw_only=True):
    level: Any
    universes: int
    reproduced: int


class ClaimShare(Record, kw_only=True):
    id: str
    universes: int
    reproduced: int
    base_reproduced: bool | None
    holds_in: list[str]
    by_level: dict[str, Rows[LevelShare]]


class Coefficient(Record, kw_only=True):
    """One coefficient of :class:`Regression`; the intercept has no ``axis`` or ``level``."""

    axis: str | None
    level: Any
    estimate: Number
    ci95_low: Number
    ci95_high: Number
    p: Number
    log10_p: Number


class Regression(Record, kw_only=True):
    """The OLS regression of the universes' human effects on the axes (none without
    residual degrees of freedom)."""

    universes: int
    df_residual: Number
    coefficients: Rows[Coefficient] | None
    variance_shares: dict[str, Number] | None
    r_squared: Number = None


class SignFlipStatistic(Record, kw_only=True):
    """One statistic of a joint test, its sign-flip ``p`` (at least ``1 / (1 + resamples)``)
    and its ``log10_p``."""

    observed: Number
    p: Number
    log10_p: Number


class JointTest(Record, kw_only=True):
    universes: int
    subjects: int
    resamples: int
    seed: int
    median_effect: SignFlipStatistic
    share_significant: SignFlipStatistic
    stouffer_z: SignFlipStatistic


class MultiverseResults(Record, kw_only=True):
    """``results.json`` of a multiverse
    (:func:`cirl_study.analysis.multiverse.results.analyse_multiverse`, with the report's
    ``run_id``)."""

    pipeline: str
    base_universe: str
    axes: dict[str, list[Any]]
    trials: dict[str, int]
    universes: Rows[UniverseSummary]
    effects: Rows[PairedDifference]
    claims: Rows[ClaimShare]
    regression: dict[str, Regression]
    joint_test: dict[str, JointTest]
    run_id: str | None


class TargetCell(Record, kw_only=True):
    """One published cell of a calibration target (:func:`cirl_study.analysis.calibration.results.
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


class CellComparison(Record, kw_only=True):
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


class UniverseDistance(Record, kw_only=True):
    """One universe's distance to the target (``docs/multiverse.md``, *Calibration*):
    ``mean_squared_log_ratio`` over every target cell, and where the target gives
    uncertainties the chi-square on the log scale over those cells (``chi_square_df`` of
    them) with its upper-tail ``p``. A universe that lacks a target cell, or measures a mean
    of 0 where the log is undefined, is not ranked: ``missing`` says why."""

    id: str
    base: bool
    settings: dict[str, Any]
    cells: Rows[CellComparison]
    mean_squared_log_ratio: Number
    chi_square: Number
    chi_square_df: int
    p: Number
    log10_p: Number
    missing: list[str]


class LevelDistance(Record, kw_only=True):
    """One level of an axis: the ranked universes at it, the nearest of them and the median
    of their distances."""

    level: Any
    universes: int
    nearest: str
    nearest_distance: float
    median_distance: float


class AxisDistance(Record, kw_only=True):
    """Per axis that varies among the ranked universes: each level's distances, the level of
    the nearest universe (``best``), and how far the nearest distance moves across levels
    (``spread``: the largest level's nearest distance minus the smallest's)."""

    axis: str
    best: Any
    spread: float
    levels: Rows[LevelDistance]


class RefinementProbe(Record, kw_only=True):
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


class CellMove(Record, kw_only=True):
    """How far one searched setting moved one target cell's mean: of the setting's points
    measured with that cell at both ends (``points``), the one that moved it most,
    ``log_ratio`` :math:`\\ln(\\bar y / \\bar y_o)` against the point it was proposed from,
    with the setting's value at both (``origin``, ``value``)."""

    setting: str
    measure: str
    num_features: int
    human: str
    robot: str
    points: int
    log_ratio: float
    origin: Any
    value: Any


class Refinement(Record, kw_only=True):
    """The coordinate search from the nearest universe (``start``) over the numeric settings
    ``axes`` (:mod:`cirl_study.analysis.calibration.refine`): its step factors, from ``first_step``
    down to ``min_step``, its budget, every point measured, the probes played now and reused, why
    it stopped (``exact``, ``converged`` or ``budget``), the searched settings' values where it
    started and where it ended (``start_settings``, ``final_settings``), the universe it ended
    at with its distance (``final``; ``start``'s own when no probe was nearer), and per searched
    setting and target cell how far the setting moved the cell (``moves``)."""

    start: str
    axes: list[str]
    first_step: float
    min_step: float
    max_probes: int
    probes: Rows[RefinementProbe]
    played: int
    reused: int
    stop: str
    start_settings: dict[str, Any]
    final_settings: dict[str, Any]
    final: UniverseDistance
    moves: Rows[CellMove]


class CalibrationResults(Record, kw_only=True):
    """``results.json`` of a calibration
    (:func:`cirl_study.analysis.calibration.results.calibrate`): the target, every universe's
    distance to it (ranked universes first, nearest first), the axes, the claims judged in the
    nearest universe, and with ``--refine`` the refinement (left out without)."""

    pipeline: str
    target_file: str
    target_sha256: str
    target: Rows[TargetCell]
    universes: Rows[UniverseDistance]
    axes: Rows[AxisDistance]
    nearest_claims: Rows[ClaimRow]
    run_id: str | None
    refinement: Refinement | None = None


SCHEMAS: dict[str, type[msgspec.Struct]] = {
    "results-study.schema.json": StudyResults,
    "results-multiverse.schema.json": MultiverseResults,
    "results-calibration.schema.json": CalibrationResults,
}
"""The schema files of ``docs/``, by name, and the type each is generated from."""

Typed = TypeVar("Typed", StudyResults, MultiverseResults, CalibrationResults)


def checked(results: Any, kind: type[Typed]) -> Typed:
    """``results`` read back as plain JSON data (``results.json``) as the typed record
    ``kind``: every field present, of its type.

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
    "from cirl_study.analysis.results.types import write_schemas; write_schemas('docs')"``."""
    for name, kind in SCHEMAS.items():
        text = json.dumps(json_schema(kind), indent=2, sort_keys=True)
        (Path(directory) / name).write_text(text + "\n", encoding="utf-8", newline="\n")


def study_tests() -> dict[str, Registered]:
    """Every registered test by its key in ``results.json``: the main block's (``anova``),
    then the paper's (``paper.anova``)."""
    return {
        **{test.name: test for test in registered(StudyResults)},
        **{f"paper.{test.name}": test for test in registered(PaperSection)},
    }
