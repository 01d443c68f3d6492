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

    [main]                    # the policy x num_features study
    subjects = 500
    rationality = 1.0
    policies = ["expert", "best_response"]   # human policies, within subjects
    robots = ["map"]          # robots, within subjects (map, if listed, plays eta_cv)

    [lambda_sweep]            # both policies at every lambda, on the main block's draws
    subjects = 500            # the first `subjects` reward draws of the main block
    rationalities = [1e-4, ..., 1e3]

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

:func:`load_pipeline` parses and validates a file into the frozen dataclasses below;
every problem is one :class:`~cirl_study.errors.UserError` line naming the file and
the key, e.g. ``pipelines/x.toml: main.subjects must be a positive integer, got 0``.
"""

from __future__ import annotations

import codecs
import hashlib
import itertools
import json
import math
import re
import tomllib
from collections.abc import Callable, Collection
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, NoReturn

from cirl_study.errors import UserError

PIPELINES_DIRECTORY = "pipelines"
"""Name of the directory that holds the pipeline files, at the repository root."""

MAX_PIPELINE_BYTES = 1 << 20
"""Largest pipeline file read: every log file of a run carries the whole text."""

MAX_PIPELINE_NESTING = 8
"""Most levels of tables and arrays a pipeline nests, its top table counting one. A valid
pipeline nests at most four (a multiverse axis: the file, ``[multiverse]``, ``cross`` and the
axis's list of levels); the bound leaves room for new keys and keeps every check of a value
far from the interpreter's recursion limit (the parser itself recurses at about 500 levels)."""

_NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")


CENTER_PLACEMENTS: tuple[str, ...] = ("per_draw", "shared", "lattice")
"""Where the ``K`` RBF centers lie (:func:`cirl_study.study.plan.draw_reward`): drawn uniformly
with each reward draw (the paper's reading), drawn once per feature level and shared by every
reward draw, or on a regular lattice."""

DEPLOYMENT_STARTS: tuple[str, ...] = ("uniform", "demonstration")
"""Where the robot's deployment starts: a cell drawn uniformly (the measures average over every
cell; the paper), or the demonstration's start cell."""


@dataclass(frozen=True)
class GameSpec:
    """The gridworld, horizons, RBF features and the feature levels (docs/design.md §1).

    ``centers`` is one of :data:`CENTER_PLACEMENTS`; ``demonstrator_stays`` whether the human
    may take the ``stay`` action during the demonstration (the robot always may); and
    ``deployment_start`` one of :data:`DEPLOYMENT_STARTS`.
    """

    width: int
    height: int
    start: tuple[int, int]
    learning_steps: int
    deployment_steps: int
    sigma: float
    feature_levels: tuple[int, ...]
    centers: str
    demonstrator_stays: bool
    deployment_start: str


@dataclass(frozen=True)
class EtaCVSpec:
    """Cross-validation of eta: each policy with a trade-off on ``subjects`` draws per level."""

    subjects: int
    etas: tuple[float, ...]
    rationality: float


@dataclass(frozen=True)
class MainSpec:
    """The main study: every policy of ``policies`` on ``subjects`` draws per feature level.

    ``policies`` are names of :data:`cirl_study.core.players.HUMANS` (within subjects, in the
    order the report compares them: baseline first); ``robots`` are names of
    :data:`cirl_study.core.players.ROBOTS`, also within subjects: every robot watches the same
    demonstrations of the ``main`` and ``lambda_sweep`` blocks. One of them is the
    *reference* (:func:`cirl_study.core.players.reference_robot`: ``map`` when present): it
    plays the eta cross-validation, so each policy's eta, and with it the human's
    demonstration, is the same whichever robot watches.
    """

    subjects: int
    rationality: float
    policies: tuple[str, ...]
    robots: tuple[str, ...]

    @property
    def reference_robot(self) -> str:
        """The robot of the eta cross-validation (see the class docstring)."""
        from cirl_study.core.players import reference_robot

        return reference_robot(self.robots)


@dataclass(frozen=True)
class TeachingSpec:
    """The hypothesis space of a pipeline's teaching players (:mod:`cirl_study.core.teaching`).

    Every subject has ``hypotheses`` reward hypotheses, the true ``theta`` among them when
    ``includes_truth`` (as in Ho et al. 2016; it flatters every learner) or all drawn from
    the prior; ``alpha`` is the pedagogic exponent and ``demonstration`` whether the
    pedagogic human draws her path (``draw``) or shows the most likely one (``mode``).
    """

    hypotheses: int
    includes_truth: bool
    alpha: float
    demonstration: str
    learning_paths: int
    """Paths of the learning phase, which a worker enumerates once (its memory estimate)."""


@dataclass(frozen=True)
class GradientAscentSpec:
    """The ``gradient_ascent`` robot's settings (:mod:`cirl_study.core.gradient_ascent`):
    ``steps`` gradient steps of size ``learning_rate`` from :math:`\\theta = 0`."""

    steps: int
    learning_rate: float


@dataclass(frozen=True)
class LambdaSweepSpec:
    """Every policy at every rationality, on the first ``subjects`` draws of the main block."""

    subjects: int
    rationalities: tuple[float, ...]


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

    @property
    def id(self) -> str:
        """A readable id spelling out every choice, e.g. ``sigma=1.5,centers=per_draw,stays=yes,
        steps=9,lambda=1,robot=map,start=uniform``: a function of the choices alone, so adding
        a level to an axis never renames an existing universe."""
        return ",".join(
            f"{axis.label}={axis.show(getattr(self, name))}" for name, axis in AXES.items()
        )


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
    read: Callable[[GameSpec, MainSpec], Any]
    apply: Callable[[Pipeline, Any], Pipeline]
    convert: Callable[[Any], Any] = lambda value: value


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


def _game_field(name: str) -> Callable[[GameSpec, MainSpec], Any]:
    """``read`` of an axis that is the field ``name`` of ``game``."""
    return lambda game, main: getattr(game, name)


def _one_of(choices: tuple[str, ...]) -> Callable[[GameSpec], LevelCheck]:
    """``levels`` of an axis whose levels are the names ``choices``."""
    return lambda game: (lambda v: v in choices, ", ".join(choices))


def _robots(_game: GameSpec) -> LevelCheck:
    from cirl_study.core.players import ROBOTS

    return (lambda v: isinstance(v, str) and v in ROBOTS), ", ".join(ROBOTS)


def _sigmas(game: GameSpec) -> LevelCheck:
    sigma = _sigma_limits(game.width, game.height)
    return (lambda v: _is_positive_number(v) and sigma.low <= v <= sigma.high), (
        f"numbers in {sigma}"
    )


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
        levels=lambda game: (lambda v: _is_integer(v) and v >= 1, "positive integers"),
        read=_game_field("learning_steps"),
        apply=_set_game("learning_steps", "deployment_steps"),
    ),
    "rationality": Axis(
        label="lambda",
        show=shortest_number,
        levels=lambda game: (
            lambda v: _is_positive_number(v) and RATIONALITY.low <= v <= RATIONALITY.high,
            f"numbers in {RATIONALITY}",
        ),
        read=lambda game, main: main.rationality,
        apply=_set_rationality,
        convert=float,
    ),
    "robot": Axis(
        label="robot",
        show=str,
        levels=_robots,
        read=lambda game, main: main.robots[0],
        apply=_set_robot,
    ),
    "deployment_start": _game_axis("deployment_start", "start", str, _one_of(DEPLOYMENT_STARTS)),
}
"""The open settings a multiverse varies, each declared once (:class:`Axis`), by the key of
``[multiverse.*]`` tables and of :class:`Universe`: ``game.sigma``, ``game.centers``,
``game.demonstrator_stays``, ``steps`` (``game.learning_steps = game.deployment_steps``),
``rationality`` (``main.rationality = eta_cv.rationality``), ``robot`` (the one robot of
``main.robots``) and ``game.deployment_start``. A new axis is one entry here and one field
of :class:`Universe`."""


@dataclass(frozen=True)
class MultiverseSpec:
    """The universes of a multiverse pipeline, the file's own choices (``base``) first."""

    base: Universe
    universes: tuple[Universe, ...]


@dataclass(frozen=True)
class Pipeline:
    """A validated pipeline file.

    ``text`` is the file's whole text and ``sha256`` the hash of its UTF-8 bytes: two runs
    are the same run exactly when their pipeline files hash alike. ``multiverse`` is ``None``
    for a single study; ``universe`` is set on the pipeline of one universe of a multiverse
    (:func:`cirl_study.study.multiverse.universe_pipeline`), whose trials carry its id.
    """

    name: str
    description: str
    seed: int
    game: GameSpec
    eta_cv: EtaCVSpec
    main: MainSpec
    lambda_sweep: LambdaSweepSpec
    path: Path
    text: str
    sha256: str
    multiverse: MultiverseSpec | None = None
    universe: Universe | None = None
    teaching: TeachingSpec | None = None
    gradient_ascent: GradientAscentSpec | None = None

    @property
    def policies_with_eta(self) -> tuple[str, ...]:
        """The policies of the main study that have a trade-off eta to cross-validate."""
        from cirl_study.core.players import HUMANS

        return tuple(policy for policy in self.main.policies if HUMANS[policy].takes_eta)

    @property
    def run_id(self) -> str:
        """Id of the run this pipeline describes: its name and the start of its hash."""
        return f"{self.name}-{self.sha256[:12]}"


@dataclass(frozen=True)
class Limits:
    """A closed range ``[low, high]`` of a setting, and why the engine needs it."""

    low: float
    high: float
    reason: str

    def __str__(self) -> str:
        return f"[{self.low:g}, {self.high:g}] ({self.reason})"


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

SIGMA_LOW = 0.02
"""Least RBF width: a center lies within ``sqrt(2)/2`` of a cell, and ``exp(-d^2 / (2
sigma^2))`` underflows to 0 beyond ``d ~ 38.6 sigma``, so ``sigma >= 0.02`` keeps every
feature non-zero on at least one cell (a feature that is zero everywhere would leave its
weight unidentifiable by construction)."""

SIGMA_SPAN = 1e3
"""Largest RBF width, in units of the grid's diagonal: there the features vary across the
grid by less than ``1 / (2 * SIGMA_SPAN^2) = 5e-7`` of their value, below the 1e-6 to which
the robot certifies its estimate, so every reward would be flat."""


def _show(value: Any) -> str:
    """Render a TOML value the way it was probably written, shortened to one short line."""
    if isinstance(value, dict):
        return "a table"
    text = json.dumps(value, default=str)
    return text if len(text) <= 60 else text[:57] + "..."


class _Table:
    """One TOML table being validated; every failure names ``file: prefix.key``."""

    def __init__(self, label: str, prefix: str, data: dict[str, Any], keys: tuple[str, ...]):
        self.label = label
        self.prefix = prefix
        self.data = data
        unknown = sorted(set(data) - set(keys))
        if unknown:
            self.fail(unknown[0], f"is not a known key (expected one of: {', '.join(keys)})")

    def fail(self, key: str, message: str) -> NoReturn:
        raise UserError(f"{self.label}: {self.prefix}{key} {message}")

    def value(self, key: str) -> Any:
        if key not in self.data:
            self.fail(key, "is missing")
        return self.data[key]

    def table(self, key: str, keys: tuple[str, ...]) -> _Table:
        value = self.value(key)
        if not isinstance(value, dict):
            self.fail(key, f"must be a table ([{self.prefix}{key}]), got {_show(value)}")
        return _Table(self.label, f"{self.prefix}{key}.", value, keys)

    def string(self, key: str) -> str:
        value = self.value(key)
        if not isinstance(value, str):
            self.fail(key, f"must be a string, got {_show(value)}")
        return value

    def boolean(self, key: str) -> bool:
        value = self.value(key)
        if not isinstance(value, bool):
            self.fail(key, f"must be true or false, got {_show(value)}")
        return value

    def choice(self, key: str, known: tuple[str, ...]) -> str:
        value = self.value(key)
        if value not in known:
            self.fail(key, f"must be one of {', '.join(known)}, got {_show(value)}")
        return value

    def integer(self, key: str, minimum: int, what: str) -> int:
        value = self.value(key)
        if not _is_integer(value) or value < minimum:
            self.fail(key, f"must be {what}, got {_show(value)}")
        return value

    def number_in(self, key: str, limits: Limits) -> float:
        value = self.value(key)
        if not (_is_positive_number(value) and limits.low <= value <= limits.high):
            self.fail(key, f"must be a number in {limits}, got {_show(value)}")
        return float(value)

    def _list(self, key: str, item_ok: Callable[[Any], bool], what: str) -> list[Any]:
        value = self.value(key)
        if not isinstance(value, list) or not value or not all(item_ok(v) for v in value):
            self.fail(key, f"must be a non-empty list of {what}, got {_show(value)}")
        if len({float(v) for v in value}) != len(value):
            self.fail(key, f"must not repeat a value, got {_show(value)}")
        return value

    def positive_integers(self, key: str) -> tuple[int, ...]:
        return tuple(self._list(key, lambda v: _is_integer(v) and v > 0, "positive integers"))

    def names(self, key: str, known: Collection[str], what: str) -> tuple[str, ...]:
        value = self.value(key)
        if (
            not isinstance(value, list)
            or not value
            or not all(isinstance(v, str) and v in known for v in value)
            or len(set(value)) != len(value)
        ):
            self.fail(
                key,
                f"must be a non-empty list of distinct known {what} ({', '.join(known)}), "
                f"got {_show(value)}",
            )
        return tuple(value)

    def numbers_in(self, key: str, limits: Limits) -> tuple[float, ...]:
        values = self._list(
            key,
            lambda v: _is_positive_number(v) and limits.low <= v <= limits.high,
            f"numbers in {limits}",
        )
        return tuple(float(v) for v in values)


def _is_integer(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_positive_number(value: Any) -> bool:
    return (
        isinstance(value, int | float)
        and not isinstance(value, bool)
        and math.isfinite(value)
        and value > 0
    )


def _too_deep(data: dict[str, Any]) -> str | None:
    """The key of ``data`` (a parsed TOML document) whose value nests past
    :data:`MAX_PIPELINE_NESTING` levels, if any (found without recursion)."""
    pending: list[tuple[object, int, str]] = [(data, 1, "")]
    while pending:
        value, depth, key = pending.pop()
        if isinstance(value, dict):
            children = [(f"{key}.{k}" if key else k, v) for k, v in value.items()]
        elif isinstance(value, list):
            children = [(key, v) for v in value]
        else:
            continue
        if depth > MAX_PIPELINE_NESTING:
            return key
        pending += [(child, depth + 1, name) for name, child in children]
    return None


def _display_path(path: Path) -> str:
    """``path`` relative to the current directory when it lies below it, else as given."""
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def path_argument(path: Path) -> str:
    """``path`` as a command the user is told to run names it, and as a run records where it
    found its pipeline file: relative to the current directory when it lies below it, else
    absolute. It never reads as a pipeline's name, which ``cirl-study run`` would look up among
    the shipped pipelines (:func:`resolve_pipeline`), nor as an option: a file of the current
    directory itself is ``./name``, as is a relative path that starts with ``-``.
    """
    resolved = path.resolve()
    try:
        shown = str(resolved.relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(resolved)
    return shown if "/" in shown and not shown.startswith("-") else f"./{shown}"


def parse_pipeline(
    text: str,
    path: Path,
    *,
    label: str | None = None,
    rename: Callable[[dict[str, Any]], dict[str, Any]] | None = None,
) -> Pipeline:
    """Validate the TOML ``text`` of the pipeline file ``path``, and what it plans against the
    limits of one run (:func:`cirl_study.study.limits.check_resources`).

    Every error is one line beginning with ``label``, by default ``path`` as the user sees it.
    ``rename`` maps the parsed table to the current names before it is read: how the text a
    log of an earlier format carries is read (:func:`cirl_study.logs.versions.pipeline_table`).
    """
    label = _display_path(path) if label is None else label
    # A character is at least one byte: a text of too many is not encoded to be measured.
    _check_size(label, len(text) if len(text) > MAX_PIPELINE_BYTES else len(text.encode()))
    nested = f"nests deeper than {MAX_PIPELINE_NESTING} levels of tables and arrays"
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise UserError(f"{label}: not valid TOML: {error}") from None
    except RecursionError:
        raise UserError(f"{label}: {nested}") from None
    deep = _too_deep(data)
    if deep is not None:
        raise UserError(f"{label}: {deep} {nested}")
    if rename is not None:
        data = rename(data)
    top = _Table(
        label,
        "",
        data,
        (
            "name", "description", "seed", "game", "eta_cv", "main", "lambda_sweep",
            "multiverse", "teaching", "gradient_ascent",
        ),
    )  # fmt: skip
    name = top.string("name")
    if not _NAME_PATTERN.fullmatch(name):
        top.fail(
            "name",
            f"must be letters, digits, '.', '_' or '-' (it names a directory), got {_show(name)}",
        )
    # Keyword arguments are evaluated in order: the file is checked top to bottom.
    pipeline = Pipeline(
        name=name,
        description=top.string("description"),
        seed=top.integer("seed", 0, "a non-negative integer"),
        game=(game := _game(top)),
        eta_cv=(eta_cv := _eta_cv(top)),
        main=(main := _main(top)),
        lambda_sweep=_lambda_sweep(top, main) if _has_sweep(top) else NO_SWEEP,
        multiverse=(
            multiverse := _multiverse(top, game, eta_cv, main) if "multiverse" in top.data else None
        ),
        teaching=_teaching(top, game, main),
        gradient_ascent=_gradient_ascent(top, main, multiverse),
        path=path,
        text=text,
        sha256=hashlib.sha256(text.encode()).hexdigest(),
    )
    # The limits count the trials planned, which needs the plan (which reads this module).
    from cirl_study.study.limits import check_resources

    check_resources(pipeline, label)
    return pipeline


def _game(top: _Table) -> GameSpec:
    game = top.table(
        "game",
        (
            "width",
            "height",
            "start",
            "learning_steps",
            "deployment_steps",
            "sigma",
            "feature_levels",
            "centers",
            "demonstrator_stays",
            "deployment_start",
        ),
    )
    width = game.integer("width", 2, "an integer of at least 2")
    height = game.integer("height", 2, "an integer of at least 2")
    start = game.value("start")
    if not (
        isinstance(start, list)
        and len(start) == 2
        and all(_is_integer(v) for v in start)
        and 0 <= start[0] < width
        and 0 <= start[1] < height
    ):
        game.fail(
            "start",
            f"must be a cell [x, y] of the {width}x{height} grid "
            f"(0 <= x < {width}, 0 <= y < {height}), got {_show(start)}",
        )
    return GameSpec(
        width=width,
        height=height,
        start=(start[0], start[1]),
        learning_steps=game.integer("learning_steps", 1, "a positive integer"),
        deployment_steps=game.integer("deployment_steps", 1, "a positive integer"),
        sigma=game.number_in("sigma", _sigma_limits(width, height)),
        feature_levels=_feature_levels(game, width * height),
        centers=game.choice("centers", CENTER_PLACEMENTS),
        demonstrator_stays=game.boolean("demonstrator_stays"),
        deployment_start=game.choice("deployment_start", DEPLOYMENT_STARTS),
    )


def _sigma_limits(width: int, height: int) -> Limits:
    diagonal = math.hypot(width - 1, height - 1)
    return Limits(
        SIGMA_LOW,
        SIGMA_SPAN * diagonal,
        "0.02 to 1000 grid diagonals: each feature non-zero somewhere and varying",
    )


def _feature_levels(game: _Table, cells: int) -> tuple[int, ...]:
    levels = game.positive_integers("feature_levels")
    if max(levels) > cells:
        game.fail(
            "feature_levels",
            f"must be at most the {cells} cells of the grid (more features than cells leave "
            f"theta unidentifiable), got {max(levels)}",
        )
    return levels


def _eta_cv(top: _Table) -> EtaCVSpec:
    block = top.table("eta_cv", ("subjects", "etas", "rationality"))
    return EtaCVSpec(
        subjects=block.integer("subjects", 1, "a positive integer"),
        etas=block.numbers_in("etas", ETA),
        rationality=block.number_in("rationality", RATIONALITY),
    )


def _main(top: _Table) -> MainSpec:
    # The registries live with the numerical core, loaded only when a pipeline is read.
    from cirl_study.core.players import HUMANS, ROBOTS

    block = top.table("main", ("subjects", "rationality", "policies", "robots"))
    return MainSpec(
        subjects=block.integer("subjects", 1, "a positive integer"),
        rationality=block.number_in("rationality", RATIONALITY),
        policies=block.names("policies", HUMANS, "human policies"),
        robots=block.names("robots", ROBOTS, "robots"),
    )


NO_SWEEP = LambdaSweepSpec(subjects=0, rationalities=())
"""The lambda sweep of a multiverse (none: lambda is one of its axes) and of a teaching study
(none: its players are compared at the main study's lambda)."""


def _has_sweep(top: _Table) -> bool:
    return "multiverse" not in top.data and "teaching" not in top.data


PEDAGOGIC_CHOICES = ("draw", "mode")
"""How the pedagogic human picks her path from her distribution."""

PEDAGOGIC_ALPHA = Limits(1e-3, 1e3, "from a choice all but uniform to all but the mode")
"""The pedagogic exponent alpha: at 1e-3 the pedagogic human's choice is all but uniform over
the paths, at 1e3 all but certain to be the most telling path (``demonstration = "mode"``)."""


def _teaching(top: _Table, game: GameSpec, main: MainSpec) -> TeachingSpec | None:
    """The ``[teaching]`` table: required exactly when a human or robot of ``main`` needs one."""
    from cirl_study.core.players import HUMANS, ROBOTS

    teaching = [p for p in main.policies if HUMANS[p].needs_hypotheses]
    teaching += [r for r in main.robots if ROBOTS[r].needs_hypotheses]
    if "teaching" not in top.data:
        if teaching:
            top.fail("teaching", f"is missing ({', '.join(teaching)} need a hypothesis space)")
        return None
    # The numerical core (numba) loads only for a pipeline with a hypothesis space.
    from cirl_study.core.gridworld import Gridworld
    from cirl_study.core.hypotheses import MAX_PATHS, path_count
    from cirl_study.core.maxent import Phase

    if "multiverse" in top.data:
        top.fail("teaching", "must not be given with [multiverse]")
    if "lambda_sweep" in top.data:
        top.fail("lambda_sweep", "must not be given with [teaching] (its study has no sweep)")
    block = top.table("teaching", ("hypotheses", "includes_truth", "alpha", "demonstration"))
    grid = Gridworld(game.width, game.height)
    learning = Phase(
        grid.demonstrator_moves(game.demonstrator_stays), grid.index(*game.start),
        game.learning_steps,
    )  # fmt: skip
    paths = path_count(learning)
    if paths > MAX_PATHS:
        top.fail(
            "game.learning_steps",
            f"gives {paths:,} learning paths, more than the {MAX_PATHS:,} a hypothesis space "
            "enumerates",
        )
    return TeachingSpec(
        hypotheses=block.integer("hypotheses", 2, "an integer of at least 2"),
        includes_truth=block.boolean("includes_truth"),
        alpha=block.number_in("alpha", PEDAGOGIC_ALPHA),
        demonstration=block.choice("demonstration", PEDAGOGIC_CHOICES),
        learning_paths=paths,
    )


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


def _gradient_ascent(
    top: _Table, main: MainSpec, multiverse: MultiverseSpec | None
) -> GradientAscentSpec | None:
    """The ``[gradient_ascent]`` table: required exactly when the ``gradient_ascent`` robot
    plays, in ``main.robots`` or as a multiverse's ``robot`` level."""
    from cirl_study.record import GRADIENT_ASCENT

    universes = () if multiverse is None else multiverse.universes
    plays = GRADIENT_ASCENT in main.robots or any(u.robot == GRADIENT_ASCENT for u in universes)
    if "gradient_ascent" not in top.data:
        if plays:
            top.fail("gradient_ascent", f"is missing (robot {GRADIENT_ASCENT} needs its settings)")
        return None
    if not plays:
        top.fail("gradient_ascent", f"is given, but robot {GRADIENT_ASCENT} does not play")
    block = top.table("gradient_ascent", ("steps", "learning_rate"))
    within = f"an integer in [1, {MAX_ASCENT_STEPS}]"
    steps = block.integer("steps", 1, within)
    if steps > MAX_ASCENT_STEPS:
        block.fail("steps", f"must be {within} (each step is a soft value iteration), got {steps}")
    return GradientAscentSpec(
        steps=steps, learning_rate=block.number_in("learning_rate", LEARNING_RATE)
    )


def _lambda_sweep(top: _Table, main: MainSpec) -> LambdaSweepSpec:
    block = top.table("lambda_sweep", ("subjects", "rationalities"))
    subjects = block.integer("subjects", 1, "a positive integer")
    if subjects > main.subjects:
        block.fail(
            "subjects",
            f"must be at most main.subjects = {main.subjects} "
            f"(the sweep reuses the main block's reward draws), got {subjects}",
        )
    return LambdaSweepSpec(
        subjects=subjects, rationalities=block.numbers_in("rationalities", RATIONALITY)
    )


def _multiverse(top: _Table, game: GameSpec, eta_cv: EtaCVSpec, main: MainSpec) -> MultiverseSpec:
    """The universes of ``[multiverse]``: the file's own (the base) first, then those of
    ``cross`` (a full factorial), ``alone`` (one level varied at a time) and ``universes``
    (listed), each once, in that order."""
    if "lambda_sweep" in top.data:
        top.fail(
            "lambda_sweep",
            "must not be given with [multiverse] (lambda is one of its axes: rationality)",
        )
    if len(main.robots) != 1:
        top.fail("main.robots", "must name one robot in a multiverse (robot is one of its axes)")
    if game.learning_steps != game.deployment_steps:
        top.fail(
            "game.deployment_steps",
            "must equal game.learning_steps in a multiverse (one axis, steps, sets both)",
        )
    if eta_cv.rationality != main.rationality:
        top.fail(
            "eta_cv.rationality",
            "must equal main.rationality in a multiverse (one axis, rationality, sets both)",
        )
    base = Universe(**{name: axis.read(game, main) for name, axis in AXES.items()})
    block = top.table("multiverse", ("cross", "alone", "universes"))
    levels = _AxisLevels(game)
    universes = [base]
    if "cross" in block.data:
        cross = block.table("cross", tuple(AXES))
        axes = {axis: levels.of(cross, axis) for axis in AXES if axis in cross.data}
        universes += [
            replace(base, **dict(zip(axes, chosen, strict=True)))
            for chosen in itertools.product(*axes.values())
        ]
    if "alone" in block.data:
        alone = block.table("alone", tuple(AXES))
        universes += [
            replace(base, **{axis: level})
            for axis in AXES
            if axis in alone.data
            for level in levels.of(alone, axis)
        ]
    if "universes" in block.data:
        listed = block.value("universes")
        if not isinstance(listed, list) or not all(isinstance(u, dict) for u in listed):
            block.fail("universes", f"must be an array of tables, got {_show(listed)}")
        for position, entry in enumerate(listed):
            table = _Table(top.label, f"multiverse.universes[{position}].", entry, tuple(AXES))
            universes.append(
                replace(base, **{axis: levels.one(table, axis) for axis in AXES if axis in entry})
            )
    return MultiverseSpec(base, tuple(dict.fromkeys(universes)))


class _AxisLevels:
    """Validation of an axis's levels: the range the same setting has in ``[game]``/``[main]``
    (:attr:`Axis.levels`)."""

    def __init__(self, game: GameSpec):
        self.checks = {name: axis.levels(game) for name, axis in AXES.items()}

    def of(self, table: _Table, axis: str) -> list[Any]:
        """The distinct levels ``table[axis]`` lists."""
        ok, what = self.checks[axis]
        value = table.value(axis)
        if not isinstance(value, list) or not value or not all(ok(v) for v in value):
            table.fail(axis, f"must be a non-empty list of {what}, got {_show(value)}")
        if len(set(value)) != len(value):
            table.fail(axis, f"must not repeat a level, got {_show(value)}")
        return [AXES[axis].convert(v) for v in value]

    def one(self, table: _Table, axis: str) -> Any:
        """The one level ``table[axis]`` names."""
        ok, what = self.checks[axis]
        value = table.value(axis)
        if not ok(value):
            table.fail(axis, f"must be one of {what}, got {_show(value)}")
        return AXES[axis].convert(value)


def _check_size(label: str, size: int) -> None:
    """Refuse a pipeline of more than :data:`MAX_PIPELINE_BYTES` (its text, or as much of its
    file as was read)."""
    if size > MAX_PIPELINE_BYTES:
        raise UserError(
            f"{label}: more than {MAX_PIPELINE_BYTES} bytes, too large for a pipeline file"
        )


def load_pipeline(path: Path) -> Pipeline:
    """Read and validate the pipeline file at ``path``."""
    try:
        with path.open("rb") as stream:
            raw = stream.read(MAX_PIPELINE_BYTES + 1)
    except OSError as error:
        raise UserError(f"{_display_path(path)}: cannot read: {error.strerror}") from None
    _check_size(_display_path(path), len(raw))
    if raw.startswith(codecs.BOM_UTF8):
        raise UserError(
            f"{_display_path(path)}: starts with a UTF-8 byte-order mark; save it as plain "
            "UTF-8 without one (TOML)"
        )
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise UserError(f"{_display_path(path)}: not valid TOML: not UTF-8 text") from None
    return parse_pipeline(text, path)


def pipeline_search_path() -> tuple[Path, ...]:
    """Directories searched for a pipeline given by name, in order.

    ``./pipelines`` (the current directory's), then the ``pipelines`` directory at the
    root of the source tree this package is imported from (an editable install).
    """
    here = Path.cwd() / PIPELINES_DIRECTORY
    repository = Path(__file__).resolve().parents[2] / PIPELINES_DIRECTORY
    return (here,) if here.resolve() == repository else (here, repository)


def resolve_pipeline(name_or_path: str) -> Path:
    """The file a ``cirl-study run PIPELINE`` argument means.

    An existing file is taken as it is; otherwise a bare name ``x`` (or ``x.toml``)
    is looked up as ``x.toml`` in :func:`pipeline_search_path`.
    """
    given = Path(name_or_path)
    if given.is_file():
        return given
    if given.is_dir():
        raise UserError(f"{name_or_path}: is a directory, not a pipeline file")
    if given.name == name_or_path:
        file_name = name_or_path if name_or_path.endswith(".toml") else f"{name_or_path}.toml"
        for directory in pipeline_search_path():
            candidate = directory / file_name
            if candidate.is_file():
                return candidate
        available = sorted(
            {p.stem for d in pipeline_search_path() if d.is_dir() for p in d.glob("*.toml")}
        )
        known = f"known pipelines: {', '.join(available)}" if available else "none shipped"
        if name_or_path.endswith(".toml"):
            raise UserError(f"{name_or_path}: no such file, nor a shipped pipeline ({known})")
        raise UserError(f"no pipeline named {name_or_path!r} ({known})")
    raise UserError(f"{name_or_path}: no such pipeline file")
