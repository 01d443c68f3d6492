"""Pipeline specifications: a whole study described in one TOML file.

A pipeline fixes everything the study needs and nothing about how it is executed
(engine, workers and output directory are options of ``cirl-study run``). Its
shape, with every key required::

    name = "paper"            # also the default output directory data/runs/<name>
    description = "..."
    seed = 2016               # the root seed of every random stream of the run

    [game]                    # the gridworld of docs/design.md §1
    width = 10
    height = 10
    start = [5, 5]            # s_0 of the learning phase, [x, y]
    learning_steps = 9        # T_learn
    deployment_steps = 9      # T_deploy
    sigma = 1.5               # RBF width, in cells
    feature_levels = [3, 10]  # K, the between-subjects factor
    centers = "per_draw"      # RBF centers: per_draw, shared or lattice (CENTER_PLACEMENTS)
    demonstrator_stays = true # may the human stay put during the demonstration?
    deployment_start = "uniform"  # the robot's start: uniform or demonstration

    [eta_cv]                  # cross-validation of the best response's eta
    subjects = 100            # reward draws per feature level, disjoint from the test draws
    etas = [0.01, ..., 100.0]
    rationality = 1.0         # lambda during cross-validation

    [main]                    # the human x num_features study
    subjects = 500
    rationality = 1.0
    humans = ["expert", "best_response"]   # humans, within subjects
    robots = ["map"]          # robots, within subjects (map, if listed, plays eta_cv)

    [lambda_sweep]            # both humans at every lambda, on the main block's draws
    subjects = 500            # the first `subjects` reward draws of the main block
    rationalities = [1e-4, ..., 1e3]

A game may instead have the features of a tile layout (``features = "tiles"``, when not
given ``"rbf"``): its grid, goals and features come from ``[game.tiles]``, and it has no
``width``, ``height``, ``sigma``, ``feature_levels`` nor ``centers``; ``[tasks]`` then names
rewards over those features, each the reward of one subject (docs/tiles.md)::

    [game.tiles]
    layout = [".oooo.", ".opccy"]   # rows, top first (or one string, a row a line)
    legend = { o = "orange", p = "purple", c = "cyan", "." = "", y = "" }
    goals = "y"               # characters whose cells end a path (optional)
    step = "step"             # the per-move feature (optional; with goals)

    [tasks]
    oox = { orange = 0, purple = 0, cyan = -1, step = -0.1 }

A tile game's pipeline may bring people: the ``recorded`` human (in ``main.humans``) shows,
for each participant and task, the demonstration a file of demonstrations gives
(:mod:`cirl_study.study.participants`, docs/participants.md); each participant is a subject of
her own, and the pipeline then needs no ``[lambda_sweep]``::

    [participants]
    file = "participants.csv"    # relative to the pipeline file's directory
    conditions = ["do", "show"]  # the conditions the file names, baseline first
    design = "between"           # each participant in one condition, or "within": in each

Its demonstrations may instead be collected in participants' browsers by ``cirl-study serve``
(``collect = true`` in place of ``file``), whose web experiment ``[experiment]`` describes
(:class:`ExperimentSpec`, :mod:`cirl_study.serve`)::

    [experiment]
    consent = "..."              # the text a participant agrees to first
    instructions.do = "..."      # one text per condition
    instructions.show = "..."
    practice = "ooo"             # one of [tasks], or a table of weights of its own
    completion_code = "C0DE"     # or completion_url = "https://..."
    participant_parameter = "PROLIFIC_PID"  # optional

A pipeline with teaching players (the ``pedagogic`` or ``regret_optimal`` human, the
``literal_observer`` or ``pragmatic`` robot; :mod:`cirl_study.core.teaching`) declares their
hypothesis space in ``[teaching]``, and then has no ``[lambda_sweep]``::

    [teaching]
    hypotheses = 64           # reward hypotheses per reward draw (at least 2)
    includes_truth = true     # the true theta is one of them (else all are prior draws)
    alpha = 1.0               # the pedagogic exponent
    demonstration = "draw"    # the pedagogic human draws her path, or shows its mode

A pipeline whose robots (``main.robots``, or a multiverse's ``robot`` levels) include
``gradient_ascent`` (:mod:`cirl_study.core.gradient_ascent`) sets its step budget and step
size in ``[gradient_ascent]``, and only then has one::

    [gradient_ascent]
    steps = 30                # gradient steps N from theta = 0 (at most 100000)
    learning_rate = 0.1       # the step size alpha, in [1e-12, 100]

A pipeline may instead declare a ``[multiverse]`` (and then no ``[lambda_sweep]``): the study
played in many *universes*, each a choice of the open settings :data:`AXES`
(:mod:`cirl_study.study.multiverse`)::

    [multiverse.cross]        # the full factorial of these axes ...
    sigma = [1.0, 1.5, 2.5, 4.0]
    centers = ["per_draw", "shared", "lattice"]
    [multiverse.alone]        # ... plus each of these levels varied alone ...
    steps = [7, 11]
    [[multiverse.universes]]  # ... plus these universes; unnamed settings as in the file
    sigma = 2.5
    robot = "posterior_mean"

Each field of the frozen dataclasses below states its constraint beside it
(:func:`~cirl_study.study.settings.setting`); :func:`cirl_study.study.pipeline_file.load_pipeline`
reads a file into them, and every problem is one :class:`~cirl_study.errors.UserError` line
naming the file and the key, e.g. ``pipelines/x.toml: game.learning_steps must be a positive
integer, got 0``.
"""

from __future__ import annotations

import hashlib
import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import msgspec

from cirl_study.features import TileFeatures
from cirl_study.record import GRADIENT_ASCENT, Recorded
from cirl_study.study.settings import (
    NOTHING_KNOWN,
    POSITIVE_INTEGER,
    Check,
    Invalid,
    Known,
    Limits,
    boolean,
    derived,
    integer_at_least,
    is_integer,
    is_positive_number,
    names,
    nested,
    number_in,
    numbers_in,
    one_of,
    positive_integers,
    setting,
    shown,
    string,
)

REGRET_READINGS: tuple[str, ...] = ("true", "estimate")
"""Which reading of the paper's regret a universe's claims judge (docs/design.md §4): ``true``,
both values under the true reward (the record's ``regret``), or ``estimate``, both under the
robot's estimate (``regret_under_estimate``)."""

CENTER_PLACEMENTS: tuple[str, ...] = ("per_draw", "shared", "lattice")
"""Where the ``K`` RBF centers lie (:func:`cirl_study.study.plan.draw_reward`): drawn uniformly
with each reward draw (the paper's reading), drawn once per feature level and shared by every
reward draw, or on a regular lattice."""

DEPLOYMENT_STARTS: tuple[str, ...] = ("uniform", "demonstration")
"""Where the robot's deployment starts: a cell drawn uniformly (the measures average over every
cell; the paper), or the demonstration's start cell."""

RATIONALITY = Limits(
    1e-4, 1e4, "the range in which the robots are checked against exact references"
)
"""lambda: docs/design.md §2 asks for the MAP to 1e-6 at every lambda in [1e-4, 1e4], and that
is where the MAP robot is checked against the mpmath reference (``tests/map_reference.py``)
and the posterior mean against quadrature; outside it no estimate the study prints is verified."""

ETA = Limits(1e-6, 1e6, "beyond, the best response equals its eta -> 0 or infinity limit")
"""eta: the best response seeks the path whose counts are nearest to ``phi_theta + theta /
(2 eta)`` with ``|theta_k| <= 1``. At ``eta > 1e6`` the pull ``theta / (2 eta)`` moves that
target by less than 5e-7 feature counts, and at ``eta < 1e-6`` it moves it by more than 5e5,
farther than any path's counts reach (at most ``T_learn + 1`` per feature for any horizon
this study can afford): either way the demonstration is that of the limit."""

FixedEtas = tuple[tuple[int, float], ...]
"""A universe's fixed etas (:attr:`Universe.eta`): ``(K, eta)`` pairs, one per feature level it
fixes, by ``K``; a level it leaves out takes its eta by cross-validation."""

ETA_MEASURE = "regret"
"""The measure whose mean over the cross-validation draws chooses eta unless a universe names
another (``eta_measure``; docs/design.md §3)."""

SIGMA_LOW = 0.02
"""Least RBF width: a center lies within ``sqrt(2)/2`` of a cell, and ``exp(-d^2 / (2
sigma^2))`` underflows to 0 beyond ``d ~ 38.6 sigma``, so ``sigma >= 0.02`` keeps every
feature non-zero on at least one cell (a feature that is zero everywhere would leave its
weight unidentifiable by construction)."""

SIGMA_SPAN = 1e3
"""Largest RBF width, in units of the grid's diagonal: there the features vary across the
grid by less than ``1 / (2 * SIGMA_SPAN^2) = 5e-7`` of their value, below the 1e-6 to which
the robot certifies its estimate, so every reward would be flat."""

PEDAGOGIC_CHOICES = ("draw", "mode")
"""How the pedagogic human picks her path from her distribution."""

PEDAGOGIC_ALPHA = Limits(1e-3, 1e3, "from a choice all but uniform to all but the mode")
"""The pedagogic exponent alpha: at 1e-3 the pedagogic human's choice is all but uniform over
the paths, at 1e3 all but certain to be the most telling path (``demonstration = "mode"``)."""


MIN_SUBJECTS = 2
"""Fewest reward draws a block plays per feature level (``eta_cv.subjects``,
``main.subjects``, ``lambda_sweep.subjects``, the tasks of a tile study): the analysis
estimates every effect against the spread of its draws, and one draw has none. The human x
num_features ANOVA has ``L (n - 1)`` error degrees of freedom for ``n`` draws at each of ``L``
levels, and each mean's standard error and interval (the chosen eta's, the sweep's curves)
needs ``n >= 2``."""

SUBJECTS = integer_at_least(
    MIN_SUBJECTS,
    f"an integer of at least {MIN_SUBJECTS} (the analysis needs the spread of two reward "
    "draws per feature level)",
)
"""The check of a block's reward draws per feature level (:data:`MIN_SUBJECTS`)."""


def sigma_limits(width: int, height: int) -> Limits:
    """The RBF widths of a ``width x height`` grid: :data:`SIGMA_LOW` to :data:`SIGMA_SPAN`
    grid diagonals."""
    diagonal = math.hypot(width - 1, height - 1)
    return Limits(
        SIGMA_LOW,
        SIGMA_SPAN * diagonal,
        "0.02 to 1000 grid diagonals: each feature non-zero somewhere and varying",
    )


def _start_cell(value: Any, known: Known) -> tuple[int, int]:
    """A cell ``[x, y]`` of the grid read before it; in a tile game, not a goal's."""
    width, height = known["width"], known["height"]
    if not (
        isinstance(value, list)
        and len(value) == 2
        and all(is_integer(v) for v in value)
        and 0 <= value[0] < width
        and 0 <= value[1] < height
    ):
        raise Invalid(
            f"must be a cell [x, y] of the {width}x{height} grid "
            f"(0 <= x < {width}, 0 <= y < {height})"
        )
    tiles: TilesSpec | None = known.get("tiles")
    if tiles is not None and tuple(value) in tiles.goal_cells:
        raise Invalid("must not be a goal cell (a path ends on entering one)")
    return value[0], value[1]


def _learning_steps(value: Any, known: Known) -> int:
    """A positive number of moves; in a game with goals, enough to reach one from the start."""
    steps = POSITIVE_INTEGER(value, known)
    tiles: TilesSpec | None = known.get("tiles")
    if tiles is not None and tiles.goal_cells:
        distance = tiles.goal_distances()[known["start"]]
        if distance > steps:
            raise Invalid(
                f"must be at least the {distance} moves from game.start to the nearest goal "
                "(every path of the learning phase ends in a goal)"
            )
    return steps


def _feature_levels(value: Any, known: Known) -> tuple[int, ...]:
    """Distinct positive numbers of features, none above the grid's cells."""
    levels = positive_integers(value, known)
    cells = known["width"] * known["height"]
    if max(levels) > cells:
        raise Invalid(
            f"must be at most the {cells} cells of the grid (more features than cells leave "
            "theta unidentifiable)",
            got=str(max(levels)),
        )
    return levels


GAME_FEATURES: tuple[str, ...] = ("rbf", "tiles")
"""The feature kinds a pipeline's game may have (``game.features``): the paper's radial-basis
features, drawn with each reward (``rbf``), or a tile layout whose colours are the features
(``tiles``, :class:`TilesSpec`)."""

RBF, TILES = GAME_FEATURES

MAX_LAYOUT_CELLS = 4096
"""Most cells of a tile layout: a 64 x 64 grid, past the size whose dynamic programmes a
batch can hold (:func:`cirl_study.study.limits.batch_memory` bounds the rest)."""

_SYMBOL = re.compile(r"[!-~]")
_FEATURE_NAME = re.compile(r"[A-Za-z_][\w-]{0,63}", re.ASCII)


def _layout(value: Any, _known: Known) -> tuple[str, ...]:
    """The rows of a tile layout, top row first: a string of one row per line (surrounding
    spaces and blank first and last lines ignored) or a list of strings; a rectangle of at
    least two cells, each a printable ASCII character other than a space."""
    if isinstance(value, str):
        rows = [line.strip() for line in value.strip().splitlines()]
    elif isinstance(value, list) and value and all(isinstance(row, str) for row in value):
        rows = [row.strip() for row in value]
    else:
        raise Invalid("must be a string of rows, one per line, or a non-empty list of rows")
    widths = sorted({len(row) for row in rows})
    if len(widths) != 1 or widths[0] == 0:
        raise Invalid(
            "must be a rectangle: every row as long as the first (rows of "
            f"{', '.join(map(str, widths))} characters)"
        )
    if not 2 <= len(rows) * widths[0] <= MAX_LAYOUT_CELLS:
        raise Invalid(f"must have 2 to {MAX_LAYOUT_CELLS} cells")
    odd = sorted({char for row in rows for char in row if not _SYMBOL.fullmatch(char)})
    if odd:
        raise Invalid(f"must be printable ASCII characters other than a space, not {odd}")
    return tuple(rows)


def _legend(value: Any, known: Known) -> tuple[tuple[str, str | None], ...]:
    """Each character of the layout, once, with the name of its cells' feature or ``""`` for
    none; every character named is in the layout."""
    if not isinstance(value, dict) or not value:
        raise Invalid('must be a table of characters and feature names ("" for none)')
    for char, name in value.items():
        if not _SYMBOL.fullmatch(char):
            raise Invalid("must be one printable ASCII character other than a space", at=char)
        if not (name == "" or (isinstance(name, str) and _FEATURE_NAME.fullmatch(name))):
            raise Invalid(
                'must be "" (no feature) or a feature name (a letter or _, then letters, '
                "digits, _ or -; at most 64)",
                at=char,
            )
    layout = known["layout"]
    used = {char for row in layout for char in row}
    missing = sorted(used - set(value))
    if missing:
        raise Invalid(f"must name every character of the layout, not {missing}")
    unused = sorted(set(value) - used)
    if unused:
        raise Invalid(f"must name only characters of the layout, not {unused}")
    if not any(value.values()):
        raise Invalid("must name at least one feature")
    return tuple((char, name or None) for char, name in value.items())


def _goal_symbols(value: Any, known: Known) -> str:
    """Distinct characters of the legend; no feature is carried by the goals alone, and by
    every one of them (every path would count it once: its weight is unidentifiable)."""
    legend = dict(known["legend"])
    if not isinstance(value, str) or len(set(value)) != len(value):
        raise Invalid("must be a string of distinct characters of the legend")
    strange = sorted(set(value) - set(legend))
    if strange:
        raise Invalid(f"must be characters of the legend, not {strange}")
    on_goals = {legend[char] for char in value}
    elsewhere = {name for char, name in legend.items() if char not in value}
    if len(on_goals) == 1 and None not in on_goals and not on_goals & elsewhere:
        (name,) = on_goals
        raise Invalid(
            f"must not all carry {name!r}, a feature of no other cell: every path enters one "
            "goal, so it counts that feature once and its weight is unidentifiable"
        )
    return value


def _step_feature(value: Any, known: Known) -> str | None:
    """The name of the per-move feature (1 in every cell): a name the legend does not use,
    in a game with goals (without, every path makes the same moves and counts it alike)."""
    if not (isinstance(value, str) and _FEATURE_NAME.fullmatch(value)):
        raise Invalid("must be a feature name (a letter or _, then letters, digits, _ or -)")
    if value in {name for _, name in known["legend"]}:
        raise Invalid("must not be a feature of the legend")
    if not known["goals"]:
        raise Invalid(
            "must not be given without goals: every path then makes the same number of "
            "moves, so the step feature's weight is unidentifiable"
        )
    return value


def _tile_features(known: Known) -> TileFeatures:
    """The layout's features: the legend's names in their order of first appearance, then
    the step feature last."""
    names = list(dict.fromkeys(name for _, name in known["legend"] if name is not None))
    if known["step"] is not None:
        names.append(known["step"])
    return TileFeatures(
        layout=known["layout"],
        names=tuple(names),
        legend=known["legend"],
        step=known["step"],
    )


@dataclass(frozen=True)
class TilesSpec:
    """A tile game's layout (``[game.tiles]``; :class:`cirl_study.features.TileFeatures`).

    ``layout`` holds the grid's rows, top (``y = height - 1``) first; ``legend`` each of its
    characters with the feature its cells carry (``None``: none); ``goals`` the characters
    whose cells absorb (a path ends on entering one; ``""``: none, every path makes exactly
    the phase's moves); ``step`` the per-move feature's name, if any. ``features`` are the
    game's features in the order of ``theta``: the legend's names as they first appear in it,
    then ``step``.
    """

    layout: tuple[str, ...] = setting(_layout)
    legend: tuple[tuple[str, str | None], ...] = setting(_legend)
    goals: str = setting(_goal_symbols, default="")
    step: str | None = setting(_step_feature, default=None)
    features: TileFeatures = derived(_tile_features)

    @property
    def width(self) -> int:
        return len(self.layout[0])

    @property
    def height(self) -> int:
        return len(self.layout)

    @property
    def goal_cells(self) -> tuple[tuple[int, int], ...]:
        """The goals' ``[x, y]`` cells, by flat index."""
        return self.features.cells_of(self.goals, self.width, self.height)

    def goal_distances(self) -> dict[tuple[int, int], int]:
        """Every cell's fewest moves to a goal (``0`` on one; unreachable cells left out)."""
        distance = {cell: 0 for cell in self.goal_cells}
        frontier = list(distance)
        while frontier:
            following = []
            for x, y in frontier:
                for cell in ((x + 1, y), (x - 1, y), (x, y + 1), (x, y - 1)):
                    inside = 0 <= cell[0] < self.width and 0 <= cell[1] < self.height
                    if inside and cell not in distance:
                        distance[cell] = distance[x, y] + 1
                        following.append(cell)
            frontier = following
        return distance


def _tile_game(known: Known) -> str | None:
    """Where ``[game.tiles]`` has a place: a game of tile features."""
    return None if known.get("features") == TILES else f'unless game.features = "{TILES}"'


def _rbf_game(known: Known) -> str | None:
    """Where the RBF settings and the grid's size have a place: a game of RBF features (a
    tile game's size is its layout's, its one feature level its features)."""
    return None if known.get("features", RBF) == RBF else f'with game.features = "{TILES}"'


def _goal_cells(known: Known) -> tuple[tuple[int, int], ...]:
    """The game's goal cells; with goals, every deployment start has one within reach."""
    tiles: TilesSpec | None = known["tiles"]
    if tiles is None or not tiles.goal_cells:
        return ()
    steps = known["deployment_steps"]
    distances = tiles.goal_distances()
    if known["deployment_start"] == "demonstration":
        starts = [known["start"]]
    else:
        starts = [cell for cell in distances if cell not in tiles.goal_cells]
    farthest = max(starts, key=lambda cell: (distances[cell], -cell[1], -cell[0]))
    if distances[farthest] > steps:
        where = (
            "game.start"
            if known["deployment_start"] == "demonstration"
            else f"cell {list(farthest)} (the deployment starts in every cell but a goal)"
        )
        raise Invalid(
            f"must be at least the {distances[farthest]} moves from {where} to the nearest "
            f"goal, got {steps}",
            at="deployment_steps",
        )
    return tiles.goal_cells


@dataclass(frozen=True)
class GameSpec:
    """The gridworld, horizons, features and the feature levels (docs/design.md §1).

    ``features`` is one of :data:`GAME_FEATURES`, ``rbf`` when not given. An ``rbf`` game
    gives its grid's size, its RBF width ``sigma``, its ``feature_levels`` and where the
    ``centers`` lie (one of :data:`CENTER_PLACEMENTS`); a ``tiles`` game gives its layout
    (``tiles``, :class:`TilesSpec`), which makes the grid's size, its one feature level
    (``K``, the layout's features) and its ``goals``, and has no ``sigma`` nor ``centers``
    (``None``). ``demonstrator_stays`` is whether the human may take the ``stay`` action
    during the demonstration (the robot always may), and ``deployment_start`` one of
    :data:`DEPLOYMENT_STARTS`.
    """

    features: str = setting(one_of(GAME_FEATURES), default=RBF)
    tiles: TilesSpec | None = nested(TilesSpec, only=_tile_game)
    width: int = setting(
        integer_at_least(2, "an integer of at least 2"),
        only=_rbf_game,
        otherwise=lambda known: known["tiles"].width,
    )
    height: int = setting(
        integer_at_least(2, "an integer of at least 2"),
        only=_rbf_game,
        otherwise=lambda known: known["tiles"].height,
    )
    start: tuple[int, int] = setting(_start_cell)
    learning_steps: int = setting(_learning_steps)
    deployment_steps: int = setting(POSITIVE_INTEGER)
    sigma: float | None = setting(
        number_in(lambda known: sigma_limits(known["width"], known["height"])), only=_rbf_game
    )
    feature_levels: tuple[int, ...] = setting(
        _feature_levels,
        only=_rbf_game,
        otherwise=lambda known: (known["tiles"].features.count,),
    )
    centers: str | None = setting(one_of(CENTER_PLACEMENTS), only=_rbf_game)
    demonstrator_stays: bool = setting(boolean)
    deployment_start: str = setting(one_of(DEPLOYMENT_STARTS))
    goals: tuple[tuple[int, int], ...] = derived(_goal_cells)
    """The goal cells of a tile game (``()`` without goals, and in an ``rbf`` game)."""

    @property
    def tile_features(self) -> TileFeatures | None:
        """A tile game's features (shared by every reward), ``None`` in an ``rbf`` game."""
        return None if self.tiles is None else self.tiles.features


@dataclass(frozen=True)
class EtaCVSpec:
    """Cross-validation of eta: each human with a trade-off on ``subjects`` draws per level."""

    subjects: int = setting(SUBJECTS)
    etas: tuple[float, ...] = setting(numbers_in(ETA))
    rationality: float = setting(number_in(RATIONALITY))


def _humans() -> Any:
    # The registries live with the numerical core, loaded only when a pipeline is read.
    from cirl_study.core.players import HUMANS

    return HUMANS


def _robots() -> Any:
    from cirl_study.core.players import ROBOTS

    return ROBOTS


TASK_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,31}")
"""A task's name: it ends its subject's id (``main-k04-oox``), so letters, digits, ``_`` and
``-``, at most 32."""


@dataclass(frozen=True)
class Task:
    """A named reward of a tile game: ``weights`` are ``theta``, one per feature, in the
    order of the game's features (:attr:`TilesSpec.features`)."""

    name: str
    weights: tuple[float, ...]


def _tasks(value: Any, known: Known) -> tuple[Task, ...]:
    """``[tasks]``: at least :data:`MIN_SUBJECTS` named rewards (each task is one subject),
    each a table giving every feature of the tile game its weight, a number in ``[-1, 1]``
    (the prior's box), and no other key."""
    features: TileFeatures = known["game"].tile_features
    wanted = ", ".join(features.names)
    if not isinstance(value, dict) or not value:
        raise Invalid(f"must be a table of named tasks, each a table of weights ({wanted})")
    if len(value) < MIN_SUBJECTS:
        raise Invalid(
            f"must name at least {MIN_SUBJECTS} tasks (each is one subject, and the analysis "
            "needs the spread of two)",
            got=f"{len(value)}",
        )
    tasks = []
    for name, weights in value.items():
        if not TASK_NAME.fullmatch(name):
            raise Invalid(
                "must be a task name: a letter or digit, then letters, digits, _ or -; at most "
                "32 (it ends the subject's id)",
                got=f'"{name}"',
            )
        tasks.append(_task(name, weights, features, at=name))
    return tuple(tasks)


def _task(name: str, weights: Any, features: TileFeatures, at: str | None) -> Task:
    """The task ``name`` of the table ``weights``: every feature of the tile game's
    ``features`` given a number in ``[-1, 1]`` (the prior's box), and no other key; a fault is
    :class:`~cirl_study.study.settings.Invalid` at the key ``at`` (``None``: the key checked)."""
    wanted = ", ".join(features.names)
    below = "" if at is None else f"{at}."
    if not isinstance(weights, dict):
        raise Invalid(f"must be a table of weights ({wanted})", got=shown(weights), at=at)
    unknown = sorted(set(weights) - set(features.names))
    if unknown:
        raise Invalid(f"is not a feature of the game ({wanted})", got="", at=f"{below}{unknown[0]}")
    missing = [feature for feature in features.names if feature not in weights]
    if missing:
        raise Invalid(
            f"must give every feature a weight ({wanted}); {missing[0]} is missing",
            got="",
            at=at,
        )
    for feature in features.names:
        weight = weights[feature]
        number = isinstance(weight, int | float) and not isinstance(weight, bool)
        if not (number and -1.0 <= weight <= 1.0):
            raise Invalid(
                "must be a number in [-1, 1] (the prior's box, where the robots estimate)",
                at=f"{below}{feature}",
                got=shown(weight),
            )
    return Task(name, tuple(float(weights[feature]) for feature in features.names))


def _without_tasks(known: Known) -> str | None:
    """Where ``main.subjects`` has a place: a study without tasks (each task is a subject)."""
    return None if not known.get("tasks") else "with [tasks] (each task is one subject)"


@dataclass(frozen=True)
class MainSpec:
    """The main study: every human of ``humans`` on ``subjects`` draws per feature level.

    ``humans`` are names of :data:`cirl_study.core.players.HUMANS` (within subjects, in the
    order the report compares them: baseline first); ``robots`` are names of
    :data:`cirl_study.core.players.ROBOTS`, also within subjects: every robot watches the same
    demonstrations of the ``main`` and ``lambda_sweep`` blocks. One of them is the
    *reference* (:func:`cirl_study.core.players.reference_robot`: ``map`` when present): it
    plays the eta cross-validation, so each human's eta, and with it her
    demonstration, is the same whichever robot watches.
    """

    subjects: int = setting(
        SUBJECTS, only=_without_tasks, otherwise=lambda known: len(known["tasks"])
    )
    rationality: float = setting(number_in(RATIONALITY))
    humans: tuple[str, ...] = setting(names(_humans, "humans"))
    robots: tuple[str, ...] = setting(names(_robots, "robots"))

    @property
    def reference_robot(self) -> str:
        """The robot of the eta cross-validation (see the class docstring)."""
        from cirl_study.core.players import reference_robot

        return reference_robot(self.robots)


class Shown(msgspec.Struct, frozen=True, kw_only=True):
    """One participant's demonstration of ``task``, from the file's ``line`` on (its first
    row)."""

    task: str
    recorded: Recorded
    line: int


@dataclass(frozen=True)
class Demonstrations:
    """A file of demonstrations (:mod:`cirl_study.study.participants`), checked against its
    pipeline: ``shown`` in the order
    participants first appear, then conditions and tasks in the pipeline's order. ``sha256``
    is the hash of the file's bytes, which a run's provenance records; ``text`` the file's
    text, which the run's logs carry, so a run is analysed, and resumed, from its logs."""

    shown: tuple[Shown, ...]
    sha256: str
    text: str = field(compare=False, repr=False)

    @property
    def participants(self) -> tuple[str, ...]:
        """Every participant, in order of first appearance."""
        return tuple(dict.fromkeys(shown.recorded.participant for shown in self.shown))


CONDITION_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,31}")
"""A condition's name: letters, digits, ``_`` and ``-``, at most 32 (a trial id may carry it)."""

PARTICIPANT_DESIGNS: tuple[str, ...] = ("between", "within")
"""How participants meet the conditions: each in one (between), or each in every one
(within)."""


def _data_file(value: Any, _known: Known) -> str:
    """A relative path of a file, ``/``-separated, that does not climb out of the pipeline's
    directory (a run is moved with its pipeline and data)."""
    parts = value.split("/") if isinstance(value, str) else []
    if not parts or value.startswith("/") or any(part in ("", ".", "..") for part in parts):
        raise Invalid(
            "must be a path relative to the pipeline file's directory, without . or .. "
            '(e.g. "participants.csv" or "data/participants.csv")'
        )
    return value


def _conditions(value: Any, _known: Known) -> tuple[str, ...]:
    """A non-empty list of distinct condition names, baseline first."""
    if (
        not isinstance(value, list)
        or not value
        or not all(isinstance(v, str) and CONDITION_NAME.fullmatch(v) for v in value)
        or len(set(value)) != len(value)
    ):
        raise Invalid(
            "must be a non-empty list of distinct condition names (a letter or digit, then "
            "letters, digits, _ or -; at most 32), the baseline first"
        )
    return tuple(value)


def _sums_of_squares(value: Any, _known: Known) -> int:
    """2 or 3."""
    if value not in (2, 3) or isinstance(value, bool):
        raise Invalid("must be 2 or 3 (the type of the ANOVA's sums of squares)")
    return int(value)


@dataclass(frozen=True)
class ParticipantsSpec:
    """``[participants]``: the people the ``recorded`` human stands for.

    Their demonstrations come from the file ``file`` (:mod:`cirl_study.study.participants`),
    relative to the pipeline file's directory, or, with ``collect = true``, from those the
    browser experiment collected in the run directory (``cirl-study serve``,
    :mod:`cirl_study.logs.collection`): exactly one of the two. ``conditions`` are the
    conditions they may name, in the order the report compares them (the first is the
    baseline); ``design`` says whether each participant is in one condition (``between``) or
    shows every task in each (``within``); ``sums_of_squares`` the type of the ANOVA's sums of
    squares, 2 (as R's ``car``, the project's default) or 3 (``afex``'s default), which differ
    where the conditions' groups differ in size. ``demonstrations`` are the file's, checked (set by
    :func:`cirl_study.study.pipeline_file.parse_pipeline`; of a collecting pipeline, once its
    run directory is known): two pipelines play the same trials only when they hold the same
    demonstrations.
    """

    file: str | None = setting(_data_file, default=None)
    collect: bool = setting(boolean, default=False)
    conditions: tuple[str, ...] = setting(_conditions)
    design: str = setting(one_of(PARTICIPANT_DESIGNS), default="between")
    sums_of_squares: int = setting(_sums_of_squares, default=2)
    demonstrations: Demonstrations | None = derived(lambda _known: None)

    @property
    def within(self) -> bool:
        """Whether each participant shows every task in every condition."""
        return self.design == "within"

    def shown(self) -> Demonstrations:
        """The demonstrations; an error before they are read."""
        if self.demonstrations is None:
            raise ValueError("the participants' demonstrations have not been read")
        return self.demonstrations


MAX_EXPERIMENT_TEXT = 20_000
"""Most characters of a text ``[experiment]`` shows a participant (the consent, one
condition's instructions): some eight pages."""

PRACTICE_TASK = "practice"
"""The name of ``experiment.practice`` when it is a task of its own, not one of ``[tasks]``."""

_CODE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,63}")
_PARAMETER = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,63}")
_URL_CHARACTERS = re.compile(r"[!#-;=?-~]+")


def _page_text(value: Any, _known: Known) -> str:
    """A non-empty text of at most :data:`MAX_EXPERIMENT_TEXT` characters, shown as plain text
    (paragraphs split at blank lines; nothing in it is markup)."""
    if not isinstance(value, str) or not value.strip():
        raise Invalid("must be a non-empty string (plain text; a blank line starts a paragraph)")
    if len(value) > MAX_EXPERIMENT_TEXT:
        raise Invalid(
            f"must be at most {MAX_EXPERIMENT_TEXT} characters", got=f"{len(value)} characters"
        )
    return value.strip()


def _instructions(value: Any, known: Known) -> tuple[tuple[str, str], ...]:
    """One text per condition of ``participants.conditions``, in their order, and no other."""
    participants: ParticipantsSpec = known["participants"]
    conditions = participants.conditions
    if not isinstance(value, dict):
        raise Invalid(f"must be a table of one text per condition ({', '.join(conditions)})")
    unknown = sorted(set(value) - set(conditions))
    if unknown:
        raise Invalid(
            f"is not one of participants.conditions ({', '.join(conditions)})",
            got="",
            at=unknown[0],
        )
    missing = [condition for condition in conditions if condition not in value]
    if missing:
        raise Invalid(f"must give every condition its text; {missing[0]} is missing", got="")
    return tuple((condition, _page_text(value[condition], known)) for condition in conditions)


def _practice(value: Any, known: Known) -> Task:
    """The practice task: the name of one of ``[tasks]``, or a table of weights (a task of its
    own, named :data:`PRACTICE_TASK`)."""
    tasks: tuple[Task, ...] = known["tasks"]
    if isinstance(value, str):
        named = [task for task in tasks if task.name == value]
        if not named:
            names = ", ".join(task.name for task in tasks)
            raise Invalid(f"must be one of [tasks] ({names}) or a table of weights")
        return named[0]
    return _task(PRACTICE_TASK, value, known["game"].tile_features, at=None)


def _completion_code(value: Any, _known: Known) -> str:
    """A code shown at the end: a letter or digit, then letters, digits, ``_`` or ``-``."""
    if not isinstance(value, str) or not _CODE.fullmatch(value):
        raise Invalid("must be a code: a letter or digit, then letters, digits, _ or -; at most 64")
    return value


def _completion_url(value: Any, _known: Known) -> str:
    """An ``https://`` (or ``http://``) address of at most 2,000 printable ASCII characters,
    without spaces, quotes or angle brackets."""
    ok = isinstance(value, str) and len(value) <= 2000 and _URL_CHARACTERS.fullmatch(value)
    if not ok or not re.match(r"https?://[^/?#]+", value):
        raise Invalid(
            "must be an https:// (or http://) address of at most 2000 characters, without "
            "spaces, quotes or angle brackets"
        )
    return value


def _parameter(value: Any, _known: Known) -> str:
    """The name of a URL parameter: a letter or ``_``, then letters, digits or ``_``."""
    if not isinstance(value, str) or not _PARAMETER.fullmatch(value):
        raise Invalid(
            "must be a URL parameter's name (a letter or _, then letters, digits or _; at "
            'most 64), e.g. "PROLIFIC_PID"'
        )
    return value


def _one_completion(known: Known) -> str:
    """How the experiment ends: ``code`` (``completion_code``) or ``url``
    (``completion_url``), exactly one of them given."""
    code, url = known["completion_code"], known["completion_url"]
    if (code is None) == (url is None):
        raise Invalid(
            "or completion_url: exactly one of them must be given (a code the participant "
            "copies, or the platform's completion address the page sends her to)",
            at="completion_code",
        )
    return "code" if code is not None else "url"


@dataclass(frozen=True)
class ExperimentSpec:
    """``[experiment]``: the web experiment ``cirl-study serve`` runs to collect the
    demonstrations of a pipeline with ``participants.collect = true``
    (:mod:`cirl_study.serve`, docs/participants.md).

    ``consent`` is the text a participant agrees to first; ``instructions`` each condition's
    text (by condition, in ``participants.conditions``' order), shown before its tasks;
    ``practice`` the task played once before them, never stored (one of ``[tasks]``, or a task
    of its own named :data:`PRACTICE_TASK`); the end shows ``completion_code`` or sends the
    participant to ``completion_url`` (exactly one is given: ``completion`` says which);
    ``participant_parameter`` names the URL parameter that carries the recruitment platform's
    id of the participant (without it, or without the parameter in the address, she is given
    a random id).
    """

    consent: str = setting(_page_text)
    instructions: tuple[tuple[str, str], ...] = setting(_instructions)
    practice: Task = setting(_practice)
    completion_code: str | None = setting(_completion_code, default=None)
    completion_url: str | None = setting(_completion_url, default=None)
    participant_parameter: str | None = setting(_parameter, default=None)
    completion: str = derived(_one_completion)

    def instructions_for(self, condition: str) -> str:
        """The instructions of ``condition``."""
        return dict(self.instructions)[condition]


def _hypotheses(value: Any, known: Known) -> int | Literal["tasks"]:
    """An integer of at least 2, or ``"tasks"`` in a study of two or more ``[tasks]`` (the
    hypotheses are then the tasks)."""
    if value != "tasks":
        return integer_at_least(2, 'an integer of at least 2, or "tasks"')(value, known)
    if len(known.get("tasks") or ()) < 2:
        raise Invalid('may be "tasks" only in a study of two or more [tasks]')
    return "tasks"


def _learning_paths(known: Known) -> int:
    """The paths of the learning phase of ``known["game"]``."""
    # The numerical core (numba) loads only for a pipeline with a hypothesis space.
    from cirl_study.core.gridworld import Gridworld
    from cirl_study.core.hypotheses import path_count
    from cirl_study.core.maxent import Phase

    game: GameSpec = known["game"]
    grid = Gridworld(game.width, game.height)
    moves = grid.demonstrator_moves(game.demonstrator_stays)
    goals = tuple(grid.index(*goal) for goal in game.goals)
    return path_count(Phase(moves, grid.index(*game.start), game.learning_steps, goals))


@dataclass(frozen=True)
class TeachingSpec:
    """The hypothesis space of a pipeline's teaching players (:mod:`cirl_study.core.teaching`).

    Every subject has ``hypotheses`` reward hypotheses, the true ``theta`` among them when
    ``includes_truth`` (as in Ho et al. 2016; it flatters every learner) or all drawn from
    the prior; or, with ``hypotheses = "tasks"`` in a study of ``[tasks]``, exactly the tasks
    (Ho et al.'s space: each subject's own task among them, so ``includes_truth`` must be
    true). ``alpha`` is the pedagogic exponent and ``demonstration``
    whether the pedagogic human draws her path (``draw``) or shows the most likely one
    (``mode``).
    """

    hypotheses: int | Literal["tasks"] = setting(_hypotheses)
    includes_truth: bool = setting(boolean)
    alpha: float = setting(number_in(PEDAGOGIC_ALPHA))
    demonstration: str = setting(one_of(PEDAGOGIC_CHOICES))
    learning_paths: int = derived(_learning_paths)
    """Paths of the learning phase, which a worker enumerates once (its memory estimate)."""


MAX_ASCENT_STEPS = 100_000
"""Most gradient steps of the ``gradient_ascent`` robot: each costs a soft value iteration of
the learning phase per trial, so a budget past this would make its trials the run's whole cost."""

LEARNING_RATE = Limits(
    1e-12, 1e2, "from steps that ascend at every lambda to one far past the prior's box"
)
"""alpha: a step moves each weight by at most ``alpha lambda T_learn`` (a feature lies in
``(0, 1]``), so at 100 one step at ``lambda = 1`` can move it a hundred times past the prior's
box; every step is an ascent below ``8 / (lambda^2 K T_learn^2)``
(:mod:`cirl_study.core.gradient_ascent`), which the lower end admits at ``lambda = 1e4`` up to
``K T_learn^2 = 80000`` (the paper's game has 810)."""


def _ascent_steps(value: Any, known: Known) -> int:
    """A step budget of 1 to :data:`MAX_ASCENT_STEPS`."""
    within = f"an integer in [1, {MAX_ASCENT_STEPS}]"
    steps = integer_at_least(1, within)(value, known)
    if steps > MAX_ASCENT_STEPS:
        raise Invalid(f"must be {within} (each step is a soft value iteration)")
    return steps


@dataclass(frozen=True)
class GradientAscentSpec:
    """The ``gradient_ascent`` robot's settings (:mod:`cirl_study.core.gradient_ascent`):
    ``steps`` gradient steps of size ``learning_rate`` from :math:`\\theta = 0`."""

    steps: int = setting(_ascent_steps)
    learning_rate: float = setting(number_in(LEARNING_RATE))


def _sweep_subjects(value: Any, known: Known) -> int:
    """At least :data:`MIN_SUBJECTS` of the main block's reward draws."""
    subjects = SUBJECTS(value, known)
    main: MainSpec = known["main"]
    if subjects > main.subjects:
        raise Invalid(
            f"must be at most main.subjects = {main.subjects} "
            "(the sweep reuses the main block's reward draws)"
        )
    return subjects


@dataclass(frozen=True)
class LambdaSweepSpec:
    """Every human at every rationality, on the first ``subjects`` draws of the main block."""

    subjects: int = setting(_sweep_subjects)
    rationalities: tuple[float, ...] = setting(numbers_in(RATIONALITY))


def shortest_number(value: float) -> str:
    """``value`` in Python's shortest round-trip form, less a trailing ``.0`` (``1.5``, ``4``,
    ``1e-05``): distinct numbers give distinct text (universe ids and level labels)."""
    return repr(float(value)).removesuffix(".0")


@dataclass(frozen=True)
class Universe:
    """One choice of every open setting of :data:`AXES` (see :mod:`cirl_study.study.multiverse`),
    a field per axis, in the order of :data:`AXES`."""

    sigma: float
    centers: str
    demonstrator_stays: bool
    steps: int
    rationality: float
    robot: str
    deployment_start: str
    ascent_steps: int | None = None
    learning_rate: float | None = None
    eta: FixedEtas | None = None
    eta_measure: str | None = None
    eta_grid: tuple[float, ...] | None = None
    regret: str | None = None

    @property
    def id(self) -> str:
        """A readable id spelling out every choice that applies, e.g. ``sigma=1.5,
        centers=per_draw,stays=yes,steps=9,lambda=1,robot=map,start=uniform`` (the
        gradient-ascent settings only for that robot, ``...,robot=gradient_ascent,
        start=uniform,ga_steps=30,ga_rate=0.1``, and the eta settings only where they depart
        from the default, ``...,start=uniform,eta=k3:1+k10:0.1``): a function of the choices
        alone, so adding a level to an axis never renames an existing universe."""
        return ",".join(
            f"{axis.label}={axis.show(getattr(self, name))}"
            for name, axis in AXES.items()
            if getattr(self, name) is not None
        )

    @property
    def played(self) -> Universe:
        """The universe whose trials this one analyses: itself with every axis that changes
        only the analysis (:attr:`Axis.analysis_only`) at its default, so universes that
        differ only there share their trials."""
        return replace(self, **{n: None for n, axis in AXES.items() if axis.analysis_only})

    def fitted(self, ascent: GradientAscentSpec | None, levels: tuple[int, ...]) -> Universe:
        """This universe with the settings that apply to it alone, so universes that differ
        only in a setting they lack are one universe: the gradient-ascent axes are ``None``
        for another robot, and for that robot default to ``ascent`` (the pipeline's
        ``[gradient_ascent]``); the cross-validation's measure and grid are ``None`` where
        ``eta`` fixes every feature level of ``levels``."""
        fitted = self
        if not self.cross_validates(levels):
            fitted = replace(fitted, eta_measure=None, eta_grid=None)
        if self.robot != GRADIENT_ASCENT:
            return replace(fitted, ascent_steps=None, learning_rate=None)
        if ascent is None:
            return fitted
        return replace(
            fitted,
            ascent_steps=ascent.steps if self.ascent_steps is None else self.ascent_steps,
            learning_rate=(
                ascent.learning_rate if self.learning_rate is None else self.learning_rate
            ),
        )

    def fixed_eta(self, num_features: int) -> float | None:
        """The eta this universe fixes at ``num_features`` features (``None``: cross-validated
        there)."""
        return dict(self.eta or ()).get(num_features)

    def cross_validates(self, levels: tuple[int, ...]) -> bool:
        """Whether some feature level of ``levels`` takes its eta by cross-validation."""
        return any(self.fixed_eta(k) is None for k in levels)


LevelCheck = tuple[Callable[[Any], bool], str]
"""Whether a value is a valid level of an axis, and the valid levels in words."""


@dataclass(frozen=True)
class Axis:
    """One open setting a multiverse varies, declared once: how a universe's id shows its
    level (``label=show(level)``), which levels are valid in a pipeline of ``game``
    (``levels``), how a parsed level is stored (``convert``), the file's own level (``read``,
    the base universe's) and how a level sets the pipeline of a universe (``apply``)."""

    label: str
    show: Callable[[Any], str]
    levels: Callable[[GameSpec], LevelCheck]
    read: Callable[[GameSpec, MainSpec], Any] = lambda game, main: None
    """The base universe's level (default: ``None``, an axis without a pipeline key)."""
    apply: Callable[[Pipeline, Any], Pipeline] = lambda pipeline, level: pipeline
    """How a level sets a universe's pipeline (default: it sets nothing; the universe
    carries the level, :attr:`Pipeline.universe`)."""
    convert: Callable[[Any], Any] = lambda value: value
    nested: bool = False
    """Whether the axis refines a level of another (the gradient-ascent settings, the
    ``gradient_ascent`` level of ``robot``): it is ``None`` in the other universes, and the
    multiverse's regression leaves it out, its levels being confounded with that axis's."""
    analysis_only: bool = False
    """Whether the axis changes how the trials are analysed and not the trials (``regret``):
    its default level is ``None``, not spelled in a universe's id, and universes that differ
    only in it share their trials (:attr:`Universe.played`)."""
    optional: bool = False
    """Whether the axis is a setting only of the universes that set it (the eta settings): at
    its default, ``None``, it is absent from a universe's settings as from its id, and from a
    multiverse's axes where no universe sets it."""
    written: Callable[[Any], Any] = lambda level: level
    """A stored level as a pipeline file writes it (a fixed eta: a table by feature level)."""
    unset: str = "–"
    """How a report writes a universe without the setting (``None``): an en dash where it
    does not apply, the default of an optional axis otherwise (an eta ``cv``)."""


def _set_game(*fields: str) -> Callable[[Pipeline, Any], Pipeline]:
    """``apply`` of an axis whose level is each of these fields of ``game``."""
    return lambda pipeline, level: replace(
        pipeline, game=replace(pipeline.game, **dict.fromkeys(fields, level))
    )


def _set_rationality(pipeline: Pipeline, level: float) -> Pipeline:
    """``main.rationality`` and ``eta_cv.rationality``: one lambda per universe."""
    return replace(
        pipeline,
        eta_cv=replace(pipeline.eta_cv, rationality=level),
        main=replace(pipeline.main, rationality=level),
    )


def _set_robot(pipeline: Pipeline, level: str) -> Pipeline:
    """``main.robots``: a universe's one robot."""
    return replace(pipeline, main=replace(pipeline.main, robots=(level,)))


def _set_ascent(field: str) -> Callable[[Pipeline, Any], Pipeline]:
    """``apply`` of a gradient-ascent axis: ``field`` of ``[gradient_ascent]``, for a universe
    of that robot (of another, the level is ``None`` and nothing is set)."""

    def apply(pipeline: Pipeline, level: Any) -> Pipeline:
        if level is None or pipeline.gradient_ascent is None:
            return pipeline
        return replace(
            pipeline, gradient_ascent=replace(pipeline.gradient_ascent, **{field: level})
        )

    return apply


def _set_eta_grid(pipeline: Pipeline, level: tuple[float, ...] | None) -> Pipeline:
    """``eta_cv.etas``: the grid a universe cross-validates eta over (``None``: the file's)."""
    if level is None:
        return pipeline
    return replace(pipeline, eta_cv=replace(pipeline.eta_cv, etas=level))


CROSS_VALIDATED = "cv"
"""The level of the ``eta`` axis that fixes no eta: every feature level cross-validates it
(the default, as a pipeline file may name it among fixed levels)."""


def _fixed_eta_levels(game: GameSpec) -> LevelCheck:
    """``levels`` of the fixed eta: :data:`CROSS_VALIDATED`, or a table of some of the game's
    feature levels, each with an eta of :data:`ETA`."""
    keys = {str(k) for k in game.feature_levels}

    def valid(value: Any) -> bool:
        return value == CROSS_VALIDATED or (
            isinstance(value, dict)
            and bool(value)
            and all(k in keys for k in value)
            and all(is_positive_number(v) and ETA.low <= v <= ETA.high for v in value.values())
        )

    levels = ", ".join(map(str, game.feature_levels))
    return valid, (
        f'"{CROSS_VALIDATED}" or tables of feature levels ({levels}) and their eta, numbers '
        f"in {ETA}"
    )


def _fixed_etas(value: str | dict[str, Any]) -> FixedEtas | None:
    """A fixed eta's level as stored: ``(K, eta)`` pairs by ``K`` (``None``: cross-validated
    at every level)."""
    if value == CROSS_VALIDATED:
        return None
    return tuple(sorted((int(k), float(eta)) for k, eta in value.items()))


def _show_fixed_etas(level: FixedEtas) -> str:
    """``k3:1+k10:0.1``: each level fixed, with its eta."""
    return "+".join(f"k{k}:{shortest_number(eta)}" for k, eta in level)


def _eta_measures(_game: GameSpec) -> LevelCheck:
    """``levels`` of the cross-validation's measure: a registered measure's name."""
    from cirl_study.measure_registry import MEASURES

    return (lambda v: isinstance(v, str) and v in MEASURES), ", ".join(MEASURES)


def _game_field(name: str) -> Callable[[GameSpec, MainSpec], Any]:
    """``read`` of an axis that is the field ``name`` of ``game``."""
    return lambda game, main: getattr(game, name)


def _one_of(choices: tuple[str, ...]) -> Callable[[GameSpec], LevelCheck]:
    """``levels`` of an axis whose levels are the names ``choices``."""
    return lambda game: (lambda v: v in choices, ", ".join(choices))


def _robot_levels(_game: GameSpec) -> LevelCheck:
    """The robots a universe may have: those without a hypothesis space (a multiverse has no
    ``[teaching]``)."""
    from cirl_study.core.players import ROBOTS

    playable = [name for name in ROBOTS if not ROBOTS[name].needs_hypotheses]
    return (lambda v: isinstance(v, str) and v in playable), (
        f"{', '.join(playable)} (a multiverse has no hypothesis space)"
    )


def _sigmas(game: GameSpec) -> LevelCheck:
    sigma = sigma_limits(game.width, game.height)
    return (lambda v: is_positive_number(v) and sigma.low <= v <= sigma.high), (
        f"numbers in {sigma}"
    )


def _passing(check: Check, what: str) -> Callable[[GameSpec], LevelCheck]:
    """``levels`` of an axis whose levels are the values ``check`` passes, the constraint of
    the setting it varies (``what``: those values in words)."""

    def passes(value: Any) -> bool:
        try:
            check(value, NOTHING_KNOWN)
        except Invalid:
            return False
        return True

    return lambda game: (passes, what)


def _game_axis(
    field: str,
    label: str,
    show: Callable[[Any], str],
    levels: Callable[[GameSpec], LevelCheck],
    convert: Callable[[Any], Any] = lambda value: value,
) -> Axis:
    """The axis of one field of ``game``: read from it, set in it."""
    return Axis(label, show, levels, _game_field(field), _set_game(field), convert)


AXES: dict[str, Axis] = {
    "sigma": _game_axis("sigma", "sigma", shortest_number, _sigmas, convert=float),
    "centers": _game_axis("centers", "centers", str, _one_of(CENTER_PLACEMENTS)),
    "demonstrator_stays": _game_axis(
        "demonstrator_stays",
        "stays",
        lambda v: "yes" if v else "no",
        lambda game: (lambda v: isinstance(v, bool), "true or false"),
    ),
    "steps": Axis(
        label="steps",
        show=str,
        levels=lambda game: (lambda v: is_integer(v) and v >= 1, "positive integers"),
        read=_game_field("learning_steps"),
        apply=_set_game("learning_steps", "deployment_steps"),
    ),
    "rationality": Axis(
        label="lambda",
        show=shortest_number,
        levels=_passing(number_in(RATIONALITY), f"numbers in {RATIONALITY}"),
        read=lambda game, main: main.rationality,
        apply=_set_rationality,
        convert=float,
    ),
    "robot": Axis(
        label="robot",
        show=str,
        levels=_robot_levels,
        read=lambda game, main: main.robots[0],
        apply=_set_robot,
    ),
    "deployment_start": _game_axis("deployment_start", "start", str, _one_of(DEPLOYMENT_STARTS)),
    "ascent_steps": Axis(
        label="ga_steps",
        show=str,
        levels=_passing(_ascent_steps, f"integers in [1, {MAX_ASCENT_STEPS}]"),
        read=lambda game, main: None,
        apply=_set_ascent("steps"),
        nested=True,
    ),
    "learning_rate": Axis(
        label="ga_rate",
        show=shortest_number,
        levels=_passing(number_in(LEARNING_RATE), f"numbers in {LEARNING_RATE}"),
        read=lambda game, main: None,
        apply=_set_ascent("learning_rate"),
        convert=float,
        nested=True,
    ),
    "eta": Axis(
        label="eta",
        show=_show_fixed_etas,
        levels=_fixed_eta_levels,
        convert=_fixed_etas,
        optional=True,
        written=lambda level: {str(k): eta for k, eta in level},
        unset=CROSS_VALIDATED,
    ),
    "eta_measure": Axis(
        label="eta_cv",
        show=str,
        levels=_eta_measures,
        convert=lambda level: None if level == ETA_MEASURE else level,
        nested=True,
        optional=True,
        unset=ETA_MEASURE,
    ),
    "eta_grid": Axis(
        label="eta_grid",
        show=lambda level: "+".join(map(shortest_number, level)),
        levels=_passing(numbers_in(ETA), f"lists of distinct numbers in {ETA}"),
        apply=_set_eta_grid,
        convert=lambda level: tuple(sorted(float(v) for v in level)),
        nested=True,
        optional=True,
        written=list,
        unset="pipeline",
    ),
    "regret": Axis(
        label="regret",
        show=str,
        levels=_one_of(REGRET_READINGS),
        read=lambda game, main: None,
        apply=lambda pipeline, level: pipeline,
        convert=lambda level: None if level == REGRET_READINGS[0] else level,
        analysis_only=True,
    ),
}
"""The open settings a multiverse varies, each declared once (:class:`Axis`), by the key of
``[multiverse.*]`` tables and of :class:`Universe`: ``game.sigma``, ``game.centers``,
``game.demonstrator_stays``, ``steps`` (``game.learning_steps = game.deployment_steps``),
``rationality`` (``main.rationality = eta_cv.rationality``), ``robot`` (the one robot of
``main.robots``), ``game.deployment_start``, for the ``gradient_ascent`` robot
``ascent_steps`` and ``learning_rate`` (``[gradient_ascent]``), how the humans with a
trade-off get their eta per feature level: ``eta`` fixes it at some levels (a table of ``K``
and eta), the others cross-validate it, on the mean of ``eta_measure`` (a registered measure;
``regret`` by default) over ``eta_grid`` (``eta_cv.etas``; the file's by default), and
``regret``, the reading of regret the claims judge (:data:`REGRET_READINGS`; it changes no
trial). A new axis is one entry here and one field of :class:`Universe`."""


@dataclass(frozen=True)
class MultiverseSpec:
    """The universes of a multiverse pipeline, the file's own choices (``base``) first."""

    base: Universe
    universes: tuple[Universe, ...]


def _tile_game_known(known: Known) -> str | None:
    """Where ``[tasks]`` has a place: a pipeline whose game has tile features."""
    game: GameSpec = known["game"]
    if game.tiles is not None:
        return None
    return f'unless game.features = "{TILES}" (a task weighs a tile game\'s named features)'


_NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")

FILE_NAME_BYTES = 255
"""The longest file name of the common file systems (ext4, XFS, btrfs, APFS; NTFS counts 255
UTF-16 units)."""

MAX_NAME_LENGTH = FILE_NAME_BYTES - len(".") - len(".tmp-XXXXXXXX") - len("-old")
"""The longest pipeline name, 237 characters: a name is a file name (the default run directory
``data/runs/<name>`` and report directory ``reports/<name>``), and the longest the code makes
of it is a report's staging directory set aside, ``.<name>.tmp-XXXXXXXX-old``
(:mod:`cirl_study.analysis.report.replacement`), which must fit :data:`FILE_NAME_BYTES`."""

PROBE_SUFFIX = "-probe"
"""What a calibration probe's pipeline adds to its multiverse's name
(:mod:`cirl_study.study.probes`): a multiverse's name leaves room for it."""


def _pipeline_name(value: Any, known: Known) -> str:
    """A name that can name a directory: letters, digits, ``.``, ``_`` and ``-``, at most
    :data:`MAX_NAME_LENGTH` of them."""
    name = string(value, known)
    if not _NAME_PATTERN.fullmatch(name):
        raise Invalid("must be letters, digits, '.', '_' or '-' (it names a directory)")
    if len(name) > MAX_NAME_LENGTH:
        raise Invalid(
            f"must be at most {MAX_NAME_LENGTH} characters (it names a directory, and a file "
            f"name holds {FILE_NAME_BYTES} bytes with the suffixes added to it)",
            got=f"{len(name)} characters",
        )
    return name


@dataclass(frozen=True)
class Pipeline:
    """A validated pipeline file (:func:`cirl_study.study.pipeline_file.parse_pipeline`).

    Its tables are the specs above, ``[game]``, ``[eta_cv]`` and ``[main]`` always;
    ``lambda_sweep`` is ``None`` in a multiverse (lambda is one of its axes) and in a study
    with a hypothesis space (its players are compared at the main study's lambda), and
    required otherwise. ``multiverse`` is ``None`` for a single study; ``universe`` is set on
    the pipeline of one universe of a multiverse
    (:func:`cirl_study.study.multiverse.universe_pipeline`), whose trials carry its id;
    ``teaching`` is set exactly when a player needs a hypothesis space, ``gradient_ascent``
    exactly when that robot plays, ``participants`` exactly when the ``recorded`` human
    does, and ``experiment`` when the file has that table (only where the demonstrations are
    collected).
    ``text`` is the file's
    whole text and ``sha256`` the hash of its UTF-8 bytes: two runs are the same run exactly
    when their pipeline files hash alike.
    """

    name: str = setting(_pipeline_name)
    description: str = setting(string)
    seed: int = setting(integer_at_least(0, "a non-negative integer"))
    game: GameSpec
    tasks: tuple[Task, ...] | None = setting(_tasks, only=_tile_game_known)
    eta_cv: EtaCVSpec
    main: MainSpec
    lambda_sweep: LambdaSweepSpec | None
    path: Path
    text: str
    sha256: str
    multiverse: MultiverseSpec | None = None
    universe: Universe | None = None
    teaching: TeachingSpec | None = None
    gradient_ascent: GradientAscentSpec | None = None
    participants: ParticipantsSpec | None = None
    experiment: ExperimentSpec | None = None

    @property
    def hypothesis_count(self) -> int:
        """The number of hypotheses of each subject's space (``[teaching]``; 0 without)."""
        if self.teaching is None:
            return 0
        if self.teaching.hypotheses == "tasks":
            return len(self.tasks or ())
        return self.teaching.hypotheses

    @property
    def humans_with_eta(self) -> tuple[str, ...]:
        """The humans of the main study that have a trade-off eta to cross-validate."""
        from cirl_study.core.players import HUMANS

        return tuple(human for human in self.main.humans if HUMANS[human].takes_eta)

    @property
    def run_id(self) -> str:
        """Id of the run this pipeline describes: its name and the start of its hash; of a
        pipeline with a file of participants, the hash of its text and of that file (SHA-256
        of the two hashes, hex, joined by a newline), so another file is another run (a
        collecting pipeline's run grows with every demonstration collected: its text alone)."""
        if self.participants is None or self.participants.collect:
            return f"{self.name}-{self.sha256[:12]}"
        both = f"{self.sha256}\n{self.participants.shown().sha256}".encode()
        return f"{self.name}-{hashlib.sha256(both).hexdigest()[:12]}"
