"""The trial record: the one contract between playing, logging and analysing (docs/design.md §7).

Every trial of a run is one :class:`TrialRecord`. The core plays a :class:`TrialSpec` (the
record's inputs: identity, game, reward draw) into a record; the log writer encodes it
(:func:`encode`), every reader decodes into it (:func:`decode`), and the analysis table is a
projection of it. Its JSON Schema, which every MCAP channel on ``/cirl/trial`` declares, is
generated from these types (:data:`TRIAL_SCHEMA`), so the schema, the writer and the readers
cannot drift apart.

The types are :class:`msgspec.Struct` s: frozen, typed, and validated while decoding (a
missing field, a wrong type or a value out of range fails with the JSON path of the first
fault). ``msgspec`` was chosen over the standard library and a hand-written validator
because it decodes and checks a record in one pass, an order of magnitude faster, and
generates the JSON Schema from the same declaration.

Notation as in the paper: ``theta`` the true reward weights :math:`\\theta \\in [-1, 1]^K`,
``theta_hat`` the robot's estimate :math:`\\hat\\theta`, ``rationality`` the robot's
:math:`\\lambda`, ``eta`` the best response's trade-off :math:`\\eta`.
"""

from __future__ import annotations

import hashlib
import sys
from typing import Annotated, Literal

import msgspec

from cirl_study.features import Features
from cirl_study.measure_registry import MEASURES

MAIN, ETA_CV, LAMBDA_SWEEP = "main", "eta_cv", "lambda_sweep"
"""The blocks of docs/design.md §5."""

BLOCKS: tuple[str, ...] = (MAIN, LAMBDA_SWEEP, ETA_CV)
"""Every block, in the order the report lists them."""

EXPERT, BEST_RESPONSE = "expert", "best_response"
"""The paper's humans: demonstration by expert, and the instructive best response."""

LITERAL = "literal"
"""The Boltzmann-rational demonstrator of Ho et al. (2016), who draws her path from the robot's
own model (:func:`cirl_study.core.humans.literal_paths`)."""

PEDAGOGIC, REGRET_OPTIMAL = "pedagogic", "regret_optimal"
"""The teaching humans: Ho et al.'s pedagogic shower, and the demonstration that minimises the
MAP robot's regret (:mod:`cirl_study.core.teaching`)."""

RECORDED = "recorded"
"""The human who is a person: each trial shows the demonstration a participant gave for its
task, read from a file of demonstrations (:mod:`cirl_study.study.participants`)."""

PAPER_HUMANS: tuple[str, ...] = (EXPERT, BEST_RESPONSE)
"""The levels of the paper's within-subjects factor ``human``, baseline first."""

MAP, POSTERIOR_MEAN = "map", "posterior_mean"
"""The robots: the paper's MAP estimate of MaxEnt IRL, and the Bayes-optimal posterior mean."""

GRADIENT_ASCENT = "gradient_ascent"
"""The robot of Ziebart et al.'s MaxEnt IRL as it is usually coded: a fixed number of gradient
steps from :math:`\\theta = 0`, without the box (:mod:`cirl_study.core.gradient_ascent`); the
one robot whose estimate may leave :math:`[-1, 1]^K`."""

LITERAL_OBSERVER, PRAGMATIC = "literal_observer", "pragmatic"
"""The robots of a hypothesis space: Bayes with the literal likelihood, and Bayes assuming the
pedagogic human (Fisac et al. 2017; :mod:`cirl_study.core.teaching`)."""

Block = Literal["main", "eta_cv", "lambda_sweep"]
DeploymentStart = Literal["uniform", "demonstration"]
PedagogicChoice = Literal["draw", "mode"]
Action = Literal["stay", "N", "S", "E", "W"]
NonEmptyText = Annotated[str, msgspec.Meta(min_length=1)]
PositiveInt = Annotated[int, msgspec.Meta(ge=1)]
Coordinate = Annotated[int, msgspec.Meta(ge=0)]
Positive = Annotated[float, msgspec.Meta(gt=0)]
Weight = Annotated[float, msgspec.Meta(ge=-1.0, le=1.0)]
Cell = tuple[Coordinate, Coordinate]
"""A grid cell ``[x, y]``."""
Path = Annotated[tuple[Cell, ...], msgspec.Meta(min_length=1)]
"""The cells ``(s_0, ..., s_T)`` of a path."""

_STRUCT = {"frozen": True, "kw_only": True, "gc": False}
"""Every record type is immutable, built by keyword, and untracked by the cyclic garbage
collector: a record is a tree of Structs, tuples and numbers, which cannot form a cycle, and
a run's rows would otherwise be traversed by every full collection."""


class Grid(msgspec.Struct, **_STRUCT):
    """The ``width x height`` gridworld."""

    width: PositiveInt
    height: PositiveInt


class Demonstration(msgspec.Struct, **_STRUCT):
    """The human's learning-phase path: its cells ``s_0..s_T`` and the ``T`` moves between."""

    states: Path
    actions: tuple[Action, ...]


Finite = Annotated[float, msgspec.Meta(ge=-sys.float_info.max, le=sys.float_info.max)]
"""A finite number (not an infinity, not NaN)."""

ParticipantId = Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")]
"""A participant's id: a letter or digit, then letters, digits, ``_``, ``.`` or ``-``, at most
64 (it is part of the trial ids; a recruitment platform's id, e.g. Prolific's 24 hex digits)."""

Seconds = Annotated[float, msgspec.Meta(ge=0.0, le=sys.float_info.max)]


class Recorded(msgspec.Struct, **_STRUCT):
    """A participant's demonstration of a trial's task, as a file of demonstrations gave it.

    ``path`` is the cells ``s_0..s_T`` the participant moved through, from the task's start
    (to a goal, in a game with goals); ``seconds``, where the file has times, the time of
    each cell's arrival since the task began (``seconds[0]`` the first view of the task), a
    non-decreasing sequence as long as ``path``; ``order`` the task's 1-based position
    in the participant's sequence, where the file gives it. ``condition`` is the participant's
    condition (between participants) or the demonstration's (within).
    """

    participant: ParticipantId
    condition: NonEmptyText
    path: Path
    seconds: tuple[Seconds, ...] | None = None
    order: PositiveInt | None = None


Measures = dict[str, Finite | None]
"""A trial's measures (docs/design.md §4), by the names of the measure registry
(:data:`~cirl_study.measure_registry.MEASURES`): each a finite number, or ``null`` where the
trial has none (its measure is undefined for it, or its log format did not log it).

A mapping, checked against the registry when a record is logged or read
(:func:`~cirl_study.measure_registry.measure_faults`: every registered name and no other,
finite values, ``null`` only where the measure allows it, values in range; a NaN, which JSON
would write as ``null``, is refused before it is logged, naming the trial), rather than a
Struct generated from the registry: a Struct is fixed once this module is imported, where a
measure may be registered later (by a script, or a test), and a record of an earlier format,
which lacks the measures added since, would need a type of its own. The JSON is the same
object of numbers either way.
"""


class Collected(msgspec.Struct, **_STRUCT):
    """A demonstration a participant submitted in the browser experiment (``cirl-study
    serve``): her demonstration of ``task``, with the time of every move."""

    task: NonEmptyText
    recorded: Recorded


class FitDiagnostics(msgspec.Struct, **_STRUCT):
    """How the robot's estimate was computed."""

    log_likelihood: float
    iterations: Annotated[int, msgspec.Meta(ge=0)]
    converged: bool


class Deployment(msgspec.Struct, **_STRUCT):
    """The robot's deployment rollouts under ``theta_hat`` from a few start cells (for replay)."""

    starts: tuple[Cell, ...]
    paths: tuple[Path, ...]


class Teaching(msgspec.Struct, **_STRUCT):
    """A trial's hypothesis space and teaching settings (:mod:`cirl_study.core.hypotheses`).

    ``hypotheses`` reward weights per subject, the true ``theta`` first when
    ``includes_truth``, the others drawn from the prior with ``hypothesis_seed`` (one per
    subject, so all its trials share the space); or, where the pipeline lists them
    (``listed``: its tasks), exactly those, the trial's own ``theta`` (one of them) first and
    the others in their listed order. ``alpha`` is the pedagogic exponent;
    ``demonstration`` whether the pedagogic human shows a path drawn from her distribution or
    its most likely path; ``search_etas`` are the trade-offs whose best responses seed the
    regret-optimal search.
    """

    hypotheses: Annotated[int, msgspec.Meta(ge=2)]
    includes_truth: bool
    hypothesis_seed: Coordinate
    alpha: Positive
    demonstration: PedagogicChoice
    search_etas: tuple[Positive, ...]
    listed: tuple[tuple[Weight, ...], ...] = ()


class GradientAscent(msgspec.Struct, **_STRUCT):
    """The settings of the ``gradient_ascent`` robot (:mod:`cirl_study.core.gradient_ascent`):
    ``steps`` gradient steps :math:`N` of size ``learning_rate`` :math:`\\alpha`."""

    steps: PositiveInt
    learning_rate: Positive


class TrialSpec(msgspec.Struct, **_STRUCT):
    """Identity and inputs of one trial: everything needed to play it.

    ``eta`` is ``None`` exactly for a human without a trade-off (the expert); ``robot``
    names the estimator (:mod:`cirl_study.core.robot`). The game is common knowledge:
    ``grid``, the learning phase's ``start`` and the two horizons, the ``features``, whether
    the human may ``stay`` while demonstrating (``demonstrator_stays``) and where the robot's
    deployment starts (``deployment_start``: every cell, uniformly, or the learning phase's
    ``start``); the subject's reward draw is ``theta``. ``seed`` seeds the trial's own
    generator. ``teaching`` is the hypothesis space of a pipeline with teaching players
    (``None`` otherwise); ``gradient_ascent`` the settings of the robot of that name, given
    exactly for its trials; ``recorded`` the participant's demonstration, given exactly for the
    ``recorded`` human's trials (whose ``task`` it shows). ``universe`` is the id of the
    multiverse universe the trial belongs to (:class:`cirl_study.study.spec.Universe`),
    ``None`` in a single study.
    :func:`cirl_study.core.gridworld.gridworld` and
    :func:`cirl_study.core.gridworld.feature_matrix` turn the game into arrays.
    """

    trial_id: NonEmptyText
    run_id: NonEmptyText
    block: Block
    subject: NonEmptyText
    human: NonEmptyText
    num_features: PositiveInt
    rationality: Positive
    eta: Positive | None
    seed: Coordinate
    grid: Grid
    start: Cell
    learning_steps: PositiveInt
    deployment_steps: PositiveInt
    features: Features
    theta: Annotated[tuple[Weight, ...], msgspec.Meta(min_length=1)]
    goals: tuple[Cell, ...] = ()
    task: NonEmptyText | None = None
    robot: NonEmptyText = MAP
    demonstrator_stays: bool = True
    deployment_start: DeploymentStart = "uniform"
    universe: NonEmptyText | None = None
    teaching: Teaching | None = None
    gradient_ascent: GradientAscent | None = None
    recorded: Recorded | None = None


class TrialRecord(TrialSpec, **_STRUCT):
    """One played trial: its :class:`TrialSpec` and what happened (docs/design.md §7).

    ``theta_hat`` is the estimate of the trial's ``robot``, in the box :math:`[-1, 1]^K` for
    every robot but ``gradient_ascent`` (a rule of the record checks,
    :mod:`cirl_study.logs.record_checks`); a robot whose estimate is a Monte-Carlo one also
    logs ``theta_hat_se`` (standard error per coordinate) and ``effective_sample_size``; they
    are ``null`` otherwise.
    """

    theta_hat: Annotated[tuple[float, ...], msgspec.Meta(min_length=1)]
    demonstration: Demonstration
    measures: Measures
    theta_hat_se: tuple[Annotated[float, msgspec.Meta(ge=0.0)], ...] | None = None
    effective_sample_size: Annotated[float, msgspec.Meta(ge=0.0)] | None = None
    irl: FitDiagnostics | None = None
    deployment: Deployment | None = None

    def spec(self) -> TrialSpec:
        """The inputs this record was played from."""
        return TrialSpec(**{name: getattr(self, name) for name in TrialSpec.__struct_fields__})


class TrialRow(msgspec.Struct, **_STRUCT):
    """What the analysis and the run's checks keep of a record: one row of the trial table.

    A record holds its paths, rollouts and reward draw, a row a dozen numbers and names, so a
    run of a million trials is read one file at a time into rows (:meth:`of`) and analysed in
    memory. ``measures``: the record's measures in the order of the registry
    (:data:`~cirl_study.measure_registry.MEASURES`, as it was when the row was made; by name
    with :meth:`measure`), a tuple rather than the record's mapping: about 100 bytes less
    a row. ``converged``: the robot's estimate met its stopping rule (``irl.converged``; a
    record without a fit report counts as converged). ``draw``: a
    digest of the subject's reward draw (``num_features``, ``theta``, the features, the grid
    and the start cell), equal for two records exactly when their draws are (up to a
    BLAKE2b collision), so one subject's trials can be checked to share one draw. ``task``: the
    trial's task (``None`` for a reward draw); ``participant`` and ``condition``: who showed a
    ``recorded`` human's trial, in which condition (``None`` for every other trial);
    ``path``: the demonstration's cells, kept for a trial of a task (a tile game's few dozen
    cells; ``None`` for a reward draw's), whose people are compared with the models path by
    path. ``file``:
    the name of the log file, in the run directory, the record was read from (empty for a
    row made of a record not read from a run's file).
    """

    trial_id: str
    run_id: str
    universe: str | None
    block: Block
    subject: str
    human: str
    robot: str
    num_features: int
    rationality: float
    eta: float | None
    seed: int
    measures: tuple[float | None, ...]
    converged: bool
    draw: str
    task: str | None = None
    participant: str | None = None
    condition: str | None = None
    path: tuple[Cell, ...] | None = None
    file: str = ""

    @classmethod
    def of(cls, record: TrialRecord, file: str = "") -> TrialRow:
        """The row of ``record``, read from the log file named ``file`` (repeated names are
        interned: one copy per run)."""
        recorded = record.recorded
        return cls(
            trial_id=record.trial_id,
            run_id=sys.intern(record.run_id),
            universe=None if record.universe is None else sys.intern(record.universe),
            block=sys.intern(record.block),
            subject=record.subject,
            human=sys.intern(record.human),
            robot=sys.intern(record.robot),
            num_features=record.num_features,
            rationality=record.rationality,
            eta=record.eta,
            seed=record.seed,
            measures=tuple(record.measures[name] for name in MEASURES),
            converged=record.irl is None or record.irl.converged,
            draw=draw_digest(record),
            task=record.task,
            participant=None if recorded is None else recorded.participant,
            condition=None if recorded is None else sys.intern(recorded.condition),
            path=None if record.task is None else record.demonstration.states,
            file=sys.intern(file),
        )

    def measure(self, name: str) -> float | None:
        """The value of the measure ``name``, ``None`` where the trial has none."""
        return self.measures[list(MEASURES).index(name)]


def setting_faults(spec: TrialSpec) -> list[str]:
    """Every way ``spec``'s settings break the rules their types cannot state: ``theta`` has
    ``num_features`` entries, as many as its features (of any kind, each with rules of its own,
    :mod:`cirl_study.features`); the start ``s_0`` and the goals lie on the grid, the goals are
    distinct and ``s_0`` is none of them; and ``gradient_ascent`` is given exactly for the robot
    of that name (empty for a sound spec). A record (a :class:`TrialSpec` too) is checked by
    the same rules before it is believed (:mod:`cirl_study.logs.record_checks`).

    Examples:
        >>> from cirl_study.features import RBFFeatures
        >>> spec = TrialSpec(trial_id="t", run_id="r", block="main", subject="s",
        ...     human="expert", robot="map", num_features=1, rationality=1.0, eta=None,
        ...     seed=0, grid=Grid(width=2, height=2), start=(2, 0), learning_steps=1,
        ...     deployment_steps=1, features=RBFFeatures(centers=((0.0, 0.0),), sigma=1.0),
        ...     theta=(0.5, 0.1), demonstrator_stays=True, deployment_start="uniform")
        >>> setting_faults(spec)
        ['theta has 2 entries, num_features is 1', 'start [2, 0] is outside the 2x2 grid']
    """
    k, grid = spec.num_features, spec.grid
    lengths = {"theta": len(spec.theta), "the features": spec.features.count}
    faults = [
        f"{name} has {n} entries, num_features is {k}" for name, n in lengths.items() if n != k
    ]
    faults += spec.features.faults(grid.width, grid.height)
    for name, cell in [("start", spec.start)] + [("goal", goal) for goal in spec.goals]:
        x, y = cell
        if not (0 <= x < grid.width and 0 <= y < grid.height):
            faults.append(f"{name} {list(cell)} is outside the {grid.width}x{grid.height} grid")
    if len(set(spec.goals)) != len(spec.goals):
        faults.append("a goal cell is listed twice")
    if spec.start in spec.goals:
        faults.append(f"start {list(spec.start)} is a goal")
    teaching = spec.teaching
    if teaching is not None and teaching.listed:
        if len(teaching.listed) != teaching.hypotheses:
            faults.append(
                f"teaching lists {len(teaching.listed)} hypotheses, hypotheses is "
                f"{teaching.hypotheses}"
            )
        if not teaching.includes_truth or spec.theta not in teaching.listed:
            faults.append("theta is not one of the listed hypotheses")
    faults += _recorded_faults(spec)
    if (spec.gradient_ascent is None) == (spec.robot == GRADIENT_ASCENT):
        faults.append(
            f"gradient_ascent is {'null' if spec.gradient_ascent is None else 'given'} for "
            f"robot {spec.robot} (given exactly for robot {GRADIENT_ASCENT})"
        )
    return faults


def _recorded_faults(spec: TrialSpec) -> list[str]:
    """The rules of ``recorded``: given exactly for the ``recorded`` human, whose trial has a
    task; a ``seconds`` per cell of its path. Whether the path is one of the game's learning
    phase the game decides (:meth:`cirl_study.core.maxent.Phase.path_faults`)."""
    recorded = spec.recorded
    if (recorded is None) == (spec.human == RECORDED):
        state = "null" if recorded is None else "given"
        return [f"recorded is {state} for human {spec.human} (given exactly for {RECORDED})"]
    if recorded is None:
        return []
    faults = [] if spec.task is not None else ["a recorded demonstration has no task"]
    if recorded.seconds is not None and len(recorded.seconds) != len(recorded.path):
        faults.append(
            f"recorded has {len(recorded.seconds)} seconds for {len(recorded.path)} cells"
        )
    elif recorded.seconds is not None and any(
        b < a for a, b in zip(recorded.seconds, recorded.seconds[1:], strict=False)
    ):
        faults.append("recorded seconds decrease")
    return faults


def draw_digest(spec: TrialSpec) -> str:
    """BLAKE2b digest of a trial's reward draw: ``num_features``, ``theta``, the features, the
    grid, the start cell and the goals."""
    drawn = (spec.num_features, spec.theta, spec.features, spec.grid, spec.start)
    if spec.goals:
        drawn += (spec.goals,)
    return hashlib.blake2b(_ENCODER.encode(drawn), digest_size=12).hexdigest()


_ENCODER = msgspec.json.Encoder(order="sorted")
_DECODER = msgspec.json.Decoder(TrialRecord)

DecodeError = msgspec.DecodeError
"""Raised by :func:`decode` on bytes that are not a valid trial record (a ``ValueError``)."""


class NestedTooDeep(DecodeError):
    """Raised by :func:`decode` on JSON nested deeper than it follows (see there)."""


def encode(value: object) -> bytes:
    """Canonical JSON of a record (or of any message of the logs): keys sorted, no spaces.

    Equal values give equal bytes, whatever the order their keys were built in. Not-a-number
    and infinities have no JSON form (they would be written as ``null``, which no record
    decodes): a record holding one is refused by :func:`decode`.
    """
    return _ENCODER.encode(value)


def decode(data: bytes) -> TrialRecord:
    """The record in ``data``, validated against the types above.

    A record's own fields nest five deep; what lies deeper is a field the record does not
    have, which msgspec skips by recursion, up to the interpreter's recursion limit: a payload
    nested deeper than that is refused here, not left to end the reader in a traceback.

    Raises:
        DecodeError: malformed JSON, nested past the recursion limit (:class:`NestedTooDeep`),
            or a field missing, of the wrong type or out of range (``msgspec.ValidationError``
            is a subclass), with the JSON path of the fault.
    """
    try:
        return _DECODER.decode(data)
    except RecursionError:
        raise NestedTooDeep("JSON nested deeper than a trial record can be read") from None


def from_builtins(data: object) -> TrialRecord:
    """The record held in plain Python data (dicts, lists, numbers), validated."""
    return msgspec.convert(data, TrialRecord)


def to_builtins(record: TrialRecord) -> dict:
    """The record as the plain JSON object its log holds (lists, dicts, numbers, strings)."""
    return msgspec.json.decode(encode(record))


def validated(spec: TrialSpec) -> TrialSpec:
    """``spec`` itself, once its fields are checked against their declared types and ranges.

    A Struct is not validated when it is built in Python, only when it is decoded; this decodes
    ``spec``'s own JSON, so a spec that plays is one whose record can be logged and read back.

    Raises:
        DecodeError: a field has the wrong type or is out of range (e.g. ``theta`` outside
            the box, ``rationality <= 0``, a numpy scalar where a float belongs).
    """
    try:
        data = encode(spec)
    except TypeError as error:
        raise msgspec.ValidationError(f"{spec.trial_id}: {error}") from None
    msgspec.json.decode(data, type=TrialSpec)
    return spec


TRIAL_SCHEMA: dict = msgspec.json.decode(msgspec.json.encode(msgspec.json.schema(TrialRecord)))
"""JSON Schema (draft 2020-12) of a trial record, declared by the ``/cirl/trial`` channel, as
JSON holds it (a default ``()`` is the list ``[]``)."""
