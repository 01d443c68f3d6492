"""The trials of a run: who plays what, under which id, with which random numbers.

Identity. A *subject* is one reward draw; its id names the group it belongs to (``cv`` for
the cross-validation draws, ``main`` for the test draws shared by the main study and the
lambda sweep), the number of features and a 1-based index, e.g. ``main-k03-s0001``, so it
is unique across feature levels and the two groups never share a draw. A *trial* is a
subject played in one block with one human (and its ``eta``), rationality ``lambda`` and
robot; its id spells all of these out, e.g.
``lambda_sweep:main-k10-s0042:best_response:lambda=0.001:eta=0.316:robot=map`` (floats in
Python's shortest round-trip form; an expert trial has no ``eta`` part). Every robot of the
pipeline watches the same subjects under the same humans: the robot is a within-subjects
factor of the ``main`` and ``lambda_sweep`` blocks, and the eta cross-validation is played by
the reference robot alone (:attr:`cirl_study.study.spec.MainSpec.reference_robot`). In a
multiverse (:mod:`cirl_study.study.multiverse`) a trial's id ends with ``@`` and its universe's
id, e.g. ``main:main-k03-s0001:expert:lambda=1.0:robot=map@sigma=2.5,centers=per_draw,...``.
In a pipeline with ``[tasks]`` (a tile game's) each task is one test subject, its id the
task's name after the group and level, ``main-k04-oox``, so a task's trials and seeds do not
depend on the order or number of the tasks; the cross-validation draws stay prior draws.
A pipeline with ``[participants]`` adds the ``recorded`` human's trials: each participant is a
subject, ``participant-<id>``, and each of her demonstrations is watched by every robot, its
trial id naming its task (and its condition, where each participant is in every condition),
``main:participant-P01:recorded:task=oox:lambda=1.0:robot=map``; they are planned after the
simulated humans' trials, participant by participant.

Randomness. Every stream is a :class:`numpy.random.SeedSequence` with the pipeline's root
seed as entropy and, as spawn key, the BLAKE2b hash of the identity string
(``subject:<subject id>`` or ``trial:<trial id>``). Nothing depends on the order in which
trials are planned, batched or played. A subject's stream draws, in this order, ``K`` RBF
centers uniformly over the continuous extent ``[0, width-1] x [0, height-1]`` and then
``theta ~ Uniform[-1, 1]^K``; every trial of the subject (both humans, every lambda) sees
the same centers and ``theta``; in a tile game the layout's features are every subject's
and the stream draws ``theta`` alone, and a task's subject takes its task's weights. The
centers drawn are the subject's own when
``game.centers = "per_draw"``; with ``"shared"`` every subject at ``K`` features uses the
centers of the stream ``centres:k<K>`` (drawn the same way; the stream keeps its first name
so that no draw moves), with ``"lattice"`` those of :func:`lattice_centers`, and ``theta``
is the same draw under every placement. A trial's
``seed`` is the first 53 bits of the stream of its *demonstration's* id: the trial id without
the robot and the universe (:func:`demonstration_id`; an integer that every JSON reader holds
exactly). So every robot watches the same demonstration, drawn once from that seed, also from
a human who draws (``literal``, ``pedagogic``); and the trials of a subject are planned next to
each other (feature level, subject, human, robot), so a batch plays a demonstration once for
all its robots. A subject's reward hypotheses (a pipeline with
``[teaching]``) are drawn from the stream ``hypotheses:<subject id>`` (its first 53 bits are
the trials' ``teaching.hypothesis_seed``), so every trial of the subject shares them.
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple, TypeVar

import numpy as np

from cirl_study.features import Features, RBFFeatures
from cirl_study.record import (
    ETA_CV,
    GRADIENT_ASCENT,
    LAMBDA_SWEEP,
    MAIN,
    GradientAscent,
    Grid,
    Teaching,
    TrialSpec,
)
from cirl_study.study.multiverse import (
    cv_universe,
    played_universes,
    universe_pipeline,
    universes,
)
from cirl_study.study.spec import GameSpec, Pipeline, Shown, Task, Universe

CV_GROUP = "cv"
"""Subject-id prefix of the cross-validation draws."""

TEST_GROUP = "main"
"""Subject-id prefix of the test draws (blocks ``main`` and ``lambda_sweep``)."""


def random_stream(root_seed: int, identity: str) -> np.random.SeedSequence:
    """The seed sequence of ``identity``: entropy ``root_seed``, spawn key BLAKE2b(identity)."""
    digest = hashlib.blake2b(identity.encode(), digest_size=16).digest()
    spawn_key = tuple(int(word) for word in np.frombuffer(digest, dtype="<u4"))
    return np.random.SeedSequence(entropy=root_seed, spawn_key=spawn_key)


def subject_id(group: str, num_features: int, index: int) -> str:
    """Id of reward draw ``index`` (1-based) of ``group`` at ``num_features`` features."""
    return f"{group}-k{num_features:02d}-s{index:04d}"


def task_subject_id(num_features: int, task: str) -> str:
    """Id of the test subject whose reward is the task named ``task`` (``main-k04-oox``)."""
    return f"{TEST_GROUP}-k{num_features:02d}-{task}"


def participant_subject_id(participant: str) -> str:
    """Id of the subject who is the participant ``participant`` (``participant-P01``)."""
    return f"participant-{participant}"


def demonstration_id(
    block: str, subject: str, human: str, rationality: float, eta: float | None, shown: str = ""
) -> str:
    """Stable id of a demonstration: who shows what to a robot of rationality ``lambda``;
    ``shown`` names which of a participant's demonstrations (``:task=oox``)."""
    eta_part = "" if eta is None else f":eta={float(eta)!r}"
    return f"{block}:{subject}:{human}{shown}:lambda={float(rationality)!r}{eta_part}"


def trial_id(
    block: str,
    subject: str,
    human: str,
    rationality: float,
    eta: float | None,
    robot: str,
    shown: str = "",
) -> str:
    """Stable id of a trial of a single study, spelling out its whole identity: its
    demonstration's id and the robot that watches it."""
    return f"{demonstration_id(block, subject, human, rationality, eta, shown)}:robot={robot}"


def in_universe(trial: str, universe: Universe | None) -> str:
    """The id of ``trial`` in ``universe``: ``<trial>@<universe id>`` (as is in a single study)."""
    return trial if universe is None else f"{trial}@{universe.id}"


def trial_seed(root_seed: int, demonstration: str) -> int:
    """The ``seed`` of the trials of demonstration ``demonstration``: 53 bits of its stream."""
    stream = random_stream(root_seed, f"trial:{demonstration}")
    return int(stream.generate_state(1, np.uint64)[0] >> 11)


Planned = TypeVar("Planned")


class Cell(NamedTuple):
    """Where one trial stands in the plan: its block, subject, human, the robot's lambda, the
    human's eta (``None`` without a trade-off) and the robot; with the pipeline, all that
    makes the trial (:func:`_trial`) or its id (:func:`_block_and_id`)."""

    block: str
    subject: Subject
    human: str
    rationality: float
    eta: float | None
    robot: str


"""What a plan gives of each trial: its :class:`TrialSpec`, or its block and id."""


@dataclass(frozen=True, eq=False)
class Subject:
    """Reward draw ``index`` (1-based) of ``group`` at ``num_features`` features of a pipeline,
    or, in a pipeline with tasks, the test subject of ``task``, or a participant's
    demonstration of ``task`` (``shown``; the subject is the participant).

    Its features and ``theta`` are drawn when first asked for (:func:`draw_reward`; a task's
    are its weights): a plan of trial ids needs only the subject's :attr:`id`.
    """

    pipeline: Pipeline
    group: str
    num_features: int
    index: int
    task: Task | None = None
    shown: Shown | None = None

    @property
    def id(self) -> str:
        if self.shown is not None:
            return participant_subject_id(self.shown.recorded.participant)
        if self.task is not None:
            return task_subject_id(self.num_features, self.task.name)
        return subject_id(self.group, self.num_features, self.index)

    @property
    def demonstration(self) -> str:
        """Which of the subject's demonstrations her trials watch: for a participant, its
        task (and condition, where she is in every condition), ``:task=oox``; else none."""
        if self.shown is None:
            return ""
        participants = self.pipeline.participants
        within = participants is not None and participants.within
        condition = f":condition={self.shown.recorded.condition}" if within else ""
        return f":task={self.shown.task}{condition}"

    @cached_property
    def reward(self) -> tuple[Features, tuple[float, ...]]:
        """The subject's features and ``theta`` (:func:`draw_reward`, or its task's)."""
        if self.task is not None:
            return self.pipeline.game.tile_features, self.task.weights  # type: ignore[return-value]
        return draw_reward(self.pipeline, self.id, self.num_features)

    @property
    def features(self) -> Features:
        return self.reward[0]

    @property
    def theta(self) -> tuple[float, ...]:
        return self.reward[1]


def draw_reward(
    pipeline: Pipeline, subject: str, num_features: int
) -> tuple[Features, tuple[float, ...]]:
    """Draw the reward of ``subject``: centers ``c_k`` then ``theta``, from its own stream; the
    centers are replaced by the shared or lattice ones when ``game.centers`` says so. In a
    tile game, ``theta`` alone (the layout's features are every subject's)."""
    game = pipeline.game
    rng = np.random.default_rng(random_stream(pipeline.seed, f"subject:{subject}"))
    tiles = game.tile_features
    if tiles is not None:
        theta = rng.uniform(-1.0, 1.0, size=num_features)
        return tiles, tuple(float(t) for t in theta)
    centers = _uniform_centers(rng, game, num_features)
    theta = rng.uniform(-1.0, 1.0, size=num_features)
    if game.centers == "shared":
        shared = np.random.default_rng(random_stream(pipeline.seed, f"centres:k{num_features:02d}"))
        centers = _uniform_centers(shared, game, num_features)
    elif game.centers == "lattice":
        centers = lattice_centers(game.width, game.height, num_features)
    features = RBFFeatures(
        centers=tuple((float(x), float(y)) for x, y in centers), sigma=game.sigma
    )
    return features, tuple(float(t) for t in theta)


def _uniform_centers(rng: np.random.Generator, game: GameSpec, count: int) -> np.ndarray:
    """``count`` centers uniform over ``[0, width-1] x [0, height-1]``, ``(count, 2)``."""
    return rng.uniform((0.0, 0.0), (game.width - 1, game.height - 1), size=(count, 2))


def lattice_centers(width: int, height: int, count: int) -> np.ndarray:
    """``count`` centers on a regular ``rows x columns`` lattice, ``(count, 2)``, row by row.

    ``rows x columns = count``, with the factor pair whose aspect ``columns / rows`` is
    closest (in log ratio) to the grid's ``width / height``, the wider of a tie (a prime
    ``count`` is one row).
    Each lattice cell's center: ``x = (width - 1)(i + 1/2) / columns``, ``y = (height - 1)(j +
    1/2) / rows``, so e.g. 10 centers on the paper's 10 x 10 grid lie on a 2 x 5 lattice.
    """
    pairs = [(rows, count // rows) for rows in range(1, count + 1) if count % rows == 0]

    def misfit(pair: tuple[int, int]) -> tuple[float, int]:
        rows, columns = pair  # ties (a pair and its transpose on a square grid): more columns
        return round(abs(math.log(columns * height / (rows * width))), 12), -columns

    rows, columns = min(pairs, key=misfit)
    xs = (width - 1) * (np.arange(columns) + 0.5) / columns
    ys = (height - 1) * (np.arange(rows) + 0.5) / rows
    return np.array([(x, y) for y in ys for x in xs])


def _participants(pipeline: Pipeline, num_features: int) -> list[Subject]:
    """Every participant's demonstration of a pipeline with ``[participants]``, as a subject
    of the test group, in the file's order
    (:class:`~cirl_study.study.participants.Demonstrations`)."""
    participants = pipeline.participants
    if participants is None or participants.demonstrations is None:
        return []  # a collecting pipeline before its run directory is read: none yet
    tasks = {task.name: task for task in pipeline.tasks or ()}
    return [
        Subject(pipeline, TEST_GROUP, num_features, index, tasks[shown.task], shown)
        for index, shown in enumerate(participants.demonstrations.shown, start=1)
    ]


def _subjects(pipeline: Pipeline, group: str, num_features: int, count: int) -> list[Subject]:
    """The first ``count`` subjects of ``group``: reward draws, or in the test group of a
    pipeline with tasks, its first ``count`` tasks."""
    if group == TEST_GROUP and pipeline.tasks is not None:
        return [
            Subject(pipeline, group, num_features, i, task)
            for i, task in enumerate(pipeline.tasks[:count], start=1)
        ]
    return [Subject(pipeline, group, num_features, i) for i in range(1, count + 1)]


def _trial(pipeline: Pipeline, cell: Cell) -> TrialSpec:
    block, subject, human, rationality, eta, robot = cell
    shown = demonstration_id(block, subject.id, human, rationality, eta, subject.demonstration)
    game = pipeline.game
    return TrialSpec(
        trial_id=_block_and_id(pipeline, cell)[1],
        run_id=pipeline.run_id,
        block=block,
        subject=subject.id,
        human=human,
        num_features=subject.num_features,
        rationality=rationality,
        eta=eta,
        seed=trial_seed(pipeline.seed, shown),
        grid=Grid(width=game.width, height=game.height),
        start=game.start,
        learning_steps=game.learning_steps,
        deployment_steps=game.deployment_steps,
        features=subject.features,
        theta=subject.theta,
        goals=game.goals,
        task=None if subject.task is None else subject.task.name,
        robot=robot,
        demonstrator_stays=game.demonstrator_stays,
        deployment_start=game.deployment_start,
        universe=None if pipeline.universe is None else pipeline.universe.id,
        teaching=_teaching(pipeline, subject),
        gradient_ascent=gradient_ascent_settings(pipeline, robot),
        recorded=None if subject.shown is None else subject.shown.recorded,
    )


def _block_and_id(pipeline: Pipeline, cell: Cell) -> tuple[str, str]:
    """The block and id of the trial :func:`_trial` builds from the same cell."""
    block, subject, human, rationality, eta, robot = cell
    return block, in_universe(
        trial_id(block, subject.id, human, rationality, eta, robot, subject.demonstration),
        pipeline.universe,
    )


def _teaching(pipeline: Pipeline, subject: Subject) -> Teaching | None:
    """The subject's hypothesis space and the pipeline's teaching settings, if it has them:
    with ``hypotheses = "tasks"``, a task's subject lists the tasks; a reward drawn from the
    prior (the eta cross-validation's, which no teaching player watches) draws as many."""
    spec = pipeline.teaching
    if spec is None:
        return None
    stream = random_stream(pipeline.seed, f"hypotheses:{subject.id}")
    listed = (
        tuple(task.weights for task in pipeline.tasks or ())
        if spec.hypotheses == "tasks" and subject.task is not None
        else ()
    )
    return Teaching(
        hypotheses=pipeline.hypothesis_count,
        listed=listed,
        includes_truth=spec.includes_truth,
        hypothesis_seed=int(stream.generate_state(1, np.uint64)[0] >> 11),
        alpha=spec.alpha,
        demonstration=spec.demonstration,
        search_etas=pipeline.eta_cv.etas,
    )


def gradient_ascent_settings(pipeline: Pipeline, robot: str) -> GradientAscent | None:
    """The pipeline's ``gradient_ascent`` settings for a trial of ``robot``: ``None`` but for
    the robot of that name."""
    spec = pipeline.gradient_ascent
    if robot != GRADIENT_ASCENT or spec is None:
        return None
    return GradientAscent(steps=spec.steps, learning_rate=spec.learning_rate)


def eta_cv_trials(pipeline: Pipeline) -> list[TrialSpec]:
    """Block ``eta_cv``: each human with a trade-off at every eta of the grid, on ``cv`` draws,
    watched by the reference robot; in a multiverse, that of every cross-validation universe
    (:func:`~cirl_study.study.multiverse.cv_universe`)."""
    return _eta_cv_plan(pipeline, _trial)


def eta_cv_trial_ids(pipeline: Pipeline) -> list[str]:
    """The id of every trial of :func:`eta_cv_trials`, in its order, without building them."""
    return [trial_id for _, trial_id in _eta_cv_plan(pipeline, _block_and_id)]


def _eta_cv_plan(
    pipeline: Pipeline,
    planned: Callable[[Pipeline, Cell], Planned],
) -> list[Planned]:
    """:func:`eta_cv_trials`, each trial given by ``planned`` (see :func:`_study_plan`)."""
    if pipeline.multiverse is not None:
        return [
            trial
            for universe in _cv_universes(pipeline)
            for trial in _eta_cv_plan(universe_pipeline(pipeline, universe), planned)
        ]
    cv = pipeline.eta_cv
    robot = pipeline.main.reference_robot
    trials = []
    for k in pipeline.game.feature_levels:
        subjects = _subjects(pipeline, CV_GROUP, k, cv.subjects)
        trials += [
            planned(pipeline, Cell(ETA_CV, subject, human, cv.rationality, eta, robot))
            for human in pipeline.humans_with_eta
            for eta in cv.etas
            for subject in subjects
        ]
    return trials


def study_trials(
    pipeline: Pipeline, etas: Mapping[tuple[str | None, str, int], float]
) -> list[TrialSpec]:
    """Blocks ``main`` and ``lambda_sweep`` on the ``main`` draws, for every robot (and in a
    multiverse, block ``main`` of every universe).

    A human with a trade-off plays at feature level ``K`` with ``etas[universe, human, K]``
    (fixed by the universe or cross-validated, :func:`cirl_study.study.eta_cv.study_etas`;
    ``universe`` is the id of the universe that plays the trial, ``None`` in a single study);
    the sweep plays the first ``lambda_sweep.subjects`` draws of the main block.
    """
    return _study_plan(pipeline, etas, _trial)


def study_trial_ids(
    pipeline: Pipeline, etas: Mapping[tuple[str | None, str, int], float]
) -> list[tuple[str, str]]:
    """The block and id of every trial of :func:`study_trials`, in its order, without building
    the trials: a run's audit needs no more, and drawing every trial's seed is most of the
    cost of planning."""
    return _study_plan(pipeline, etas, _block_and_id)


def _study_plan(
    pipeline: Pipeline,
    etas: Mapping[tuple[str | None, str, int], float],
    planned: Callable[[Pipeline, Cell], Planned],
) -> list[Planned]:
    """:func:`study_trials`, each trial given by ``planned`` (:func:`_trial` or
    :func:`_block_and_id`) from its pipeline and :class:`Cell`."""
    if pipeline.multiverse is None:
        return _single_study_plan(pipeline, etas, planned)
    return [
        trial
        for universe in played_universes(pipeline)
        for trial in _single_study_plan(universe_pipeline(pipeline, universe), etas, planned)
    ]


def _single_study_plan(
    pipeline: Pipeline,
    etas: Mapping[tuple[str | None, str, int], float],
    planned: Callable[[Pipeline, Cell], Planned],
) -> list[Planned]:
    """:func:`_study_plan` of a single study (a universe's), with its etas."""
    main, sweep = pipeline.main, pipeline.lambda_sweep
    levels = pipeline.game.feature_levels
    subjects = {k: _subjects(pipeline, TEST_GROUP, k, main.subjects) for k in levels}

    with_eta = pipeline.humans_with_eta
    universe = None if pipeline.universe is None else pipeline.universe.id

    def eta_of(human: str, k: int) -> float | None:
        return etas[universe, human, k] if human in with_eta else None

    simulated = [human for human in main.humans if human not in recorded_humans(pipeline)]
    main_block = [
        planned(pipeline, Cell(MAIN, subject, human, main.rationality, eta_of(human, k), robot))
        for k in levels
        for subject in subjects[k]
        for human in simulated
        for robot in main.robots
    ]
    main_block += [
        planned(pipeline, Cell(MAIN, subject, human, main.rationality, None, robot))
        for k in levels
        for subject in _participants(pipeline, k)
        for human in recorded_humans(pipeline)
        for robot in main.robots
    ]
    if sweep is None:
        return main_block
    sweep_block = [
        planned(pipeline, Cell(LAMBDA_SWEEP, subject, human, rationality, eta_of(human, k), robot))
        for k in levels
        for rationality in sweep.rationalities
        for subject in subjects[k][: sweep.subjects]
        for human in main.humans
        for robot in main.robots
    ]
    return main_block + sweep_block


def trial_counts(pipeline: Pipeline) -> dict[str, int]:
    """Number of trials of each block (known before eta is chosen)."""
    if pipeline.multiverse is not None:
        # Every universe plays the same subjects, levels and humans, with one robot; a
        # cross-validation universe plays its own grid.
        base = trial_counts(universe_pipeline(pipeline, pipeline.multiverse.base))
        return {
            ETA_CV: sum(
                trial_counts(universe_pipeline(pipeline, cv))[ETA_CV]
                for cv in _cv_universes(pipeline)
            ),
            MAIN: base[MAIN] * len(played_universes(pipeline)),
            LAMBDA_SWEEP: 0,
        }
    levels = len(pipeline.game.feature_levels)
    recorded = len(recorded_humans(pipeline))
    robots = len(pipeline.main.robots)
    humans = (len(pipeline.main.humans) - recorded) * robots
    shown = len(_participants(pipeline, 0))
    sweep = pipeline.lambda_sweep
    cv = pipeline.eta_cv
    return {
        ETA_CV: levels * cv.subjects * len(cv.etas) * len(pipeline.humans_with_eta),
        MAIN: levels * (pipeline.main.subjects * humans + shown * recorded * robots),
        LAMBDA_SWEEP: 0
        if sweep is None
        else levels * sweep.subjects * len(sweep.rationalities) * humans,
    }


def recorded_humans(pipeline: Pipeline) -> tuple[str, ...]:
    """The humans of ``main.humans`` who are people
    (:attr:`~cirl_study.core.players.Human.recorded`): they play the participants, not the
    reward draws."""
    from cirl_study.core.players import HUMANS

    return tuple(human for human in pipeline.main.humans if HUMANS[human].recorded)


def _cv_universes(pipeline: Pipeline) -> list[Universe]:
    """The distinct cross-validation universes of a multiverse, in the order first needed."""
    needed = (cv_universe(pipeline, u) for u in universes(pipeline))
    return list(dict.fromkeys(cv for cv in needed if cv is not None))
