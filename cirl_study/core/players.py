"""The players by name: every human and every robot a pipeline may name.

A human is a :class:`Human`; a robot is a :class:`Robot` (an
:data:`~cirl_study.core.estimate.Estimator`). Both read the batch's game
(:class:`~cirl_study.core.apprenticeship.Apprenticeship`). The built-in ones are registered
here; a package of your own adds players without editing this one, by declaring each as an
entry point of the group :data:`ENTRY_POINTS` whose object is a :class:`Human` or a
:class:`Robot` and whose name is the player's (``examples/cirl-study-example-players``)::

    [project.entry-points."cirl_study.players"]
    first_step = "my_players:FIRST_STEP"

Installed players are loaded the first time a name is looked up that is not built in, or the
registries are listed (:class:`Registry`); so a run of the built-in players never reads the
installed packages' metadata. In a script, :func:`register_human` and :func:`register_robot`
add a player for the process.

Each registered player imports its module when it first plays: reading, checking and
analysing logs need only the players' names and what they imply for a record
(:attr:`Human.takes_eta`, ``needs_hypotheses``), and so never load the numerical core (numba and
scipy) at their start.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Generic, TypeVar

from cirl_study.errors import UserError
from cirl_study.record import (
    BEST_RESPONSE,
    EXPERT,
    GRADIENT_ASCENT,
    LITERAL,
    LITERAL_OBSERVER,
    MAP,
    PEDAGOGIC,
    POSTERIOR_MEAN,
    PRAGMATIC,
    RECORDED,
    REGRET_OPTIMAL,
)

if TYPE_CHECKING:
    from cirl_study.core.apprenticeship import Apprenticeship
    from cirl_study.core.estimate import Estimate, Estimator
    from cirl_study.core.planning import FloatArray, IntArray


@dataclass(frozen=True)
class Human:
    """A human: how she demonstrates, and whether she trades reward against teaching.

    Attributes:
        demonstrate: ``demonstrate(game, theta, eta, seeds)`` returns the ``(B, T + 1)``
            paths; ``eta`` is ``(B,)`` when :attr:`takes_eta`, else ``None``; ``seeds`` are the
            trials' seeds.
        takes_eta: whether the human has the trade-off :math:`\\eta`, chosen by
            cross-validation before the test trials (docs/design.md §3).
        needs_hypotheses: whether she needs the trials' hypothesis space (a pipeline's
            ``[teaching]``).
        path_search: whether her demonstration runs the exact nearest-path search
            (:func:`cirl_study.core.path_search.nearest_paths`), whose time grows about
            fourfold a learning step: a pipeline where she plays is held to
            :data:`cirl_study.study.limits.MAX_SEARCH_STEPS` learning steps.
        recorded: whether she is a person: her trials' demonstrations are the participants'
            (``TrialSpec.recorded``), which the game carries
            (:attr:`~cirl_study.core.apprenticeship.Apprenticeship.recorded`), and she plays
            the participants of a pipeline's ``[participants]``, not its reward draws.
    """

    demonstrate: Callable[[Apprenticeship, FloatArray, FloatArray | None, IntArray], IntArray]
    takes_eta: bool
    needs_hypotheses: bool = False
    path_search: bool = False
    recorded: bool = False


@dataclass(frozen=True)
class Robot:
    """A robot: its estimator, whether it needs the trials' hypothesis space, and whether its
    estimate may leave the box :math:`[-1, 1]^K` of the prior (``leaves_box``: gradient
    ascent's does; every other robot's is checked to lie in it, as it plays and in its
    records)."""

    estimate: Estimator
    needs_hypotheses: bool = False
    leaves_box: bool = False


ENTRY_POINTS = "cirl_study.players"
"""The entry-point group of the players of installed packages."""

Player = TypeVar("Player", "Human", "Robot")


class Registry(dict[str, Player], Generic[Player]):
    """The players of one kind by name: the built-in ones, then those of the installed
    packages (:data:`ENTRY_POINTS`, in name order), loaded on the first lookup of a name not
    built in (``name in``, ``[name]``, :meth:`get`) or the first listing (iteration)."""

    def __contains__(self, name: object) -> bool:
        if dict.__contains__(self, name):
            return True
        _load_installed_players()
        return dict.__contains__(self, name)

    def __missing__(self, name: str) -> Player:
        _load_installed_players()
        if dict.__contains__(self, name):
            return dict.__getitem__(self, name)
        raise KeyError(name)

    def get(self, name: str, default: Player | None = None) -> Player | None:  # type: ignore[override]
        if name in self:  # loads the installed players on a miss (dict.get would not)
            return dict.__getitem__(self, name)
        return default

    def __iter__(self) -> Iterator[str]:
        _load_installed_players()
        return dict.__iter__(self)


HUMANS: Registry[Human] = Registry()
"""Every human, by the name a pipeline and a trial record use (``human``)."""

ROBOTS: Registry[Robot] = Registry()
"""Every robot, by the name a pipeline and a trial record use (``robot``)."""

_INSTALLED: list[str] = []
"""The names of the installed packages' players, once loaded (``[]`` before)."""

PACKAGES: dict[str, str] = {}
"""The package each installed player came from, ``"name version"``, by the player's name
(a built-in player, or one registered by a script, has none). Provenance records these for
the players a pipeline names, so a log says where a player came from after its package is
gone."""


def origin(name: str) -> str:
    """Where the player ``name`` comes from, for a message: ``"package my-players 0.1"``,
    ``"built in"``, or ``"registered in this process"`` (:func:`register_human`).

    >>> origin("expert")
    'built in'
    """
    if name in PACKAGES:
        return f"package {PACKAGES[name]}"
    return "built in" if name in _BUILT_IN else "registered in this process"


def _load_installed_players() -> None:
    """Register the players of every installed package's :data:`ENTRY_POINTS`, once.

    Raises:
        UserError: an entry point cannot be loaded, is neither a :class:`Human` nor a
            :class:`Robot`, or takes a name already registered (one line naming it and its
            package).
    """
    if _INSTALLED:
        return
    from importlib.metadata import entry_points

    _INSTALLED.append("")  # loading: a lookup from a player's own import does not recurse
    for point in sorted(entry_points(group=ENTRY_POINTS), key=lambda point: point.name):
        package = point.dist.name if point.dist is not None else "an installed package"
        version = f" {point.dist.version}" if point.dist is not None else ""
        where = f"the player {point.name!r} of {package} ({point.value})"
        try:
            player = point.load()
        except Exception as error:  # the package's own code: any fault is its
            raise UserError(f"{where} cannot be loaded: {type(error).__name__}: {error}") from None
        try:
            if isinstance(player, Human):
                register_human(point.name, player)
            elif isinstance(player, Robot):
                register_robot(point.name, player)
            else:
                raise UserError(
                    f"{where} is a {type(player).__name__}, neither a "
                    "cirl_study.core.players.Human nor a Robot"
                )
        except ValueError as error:
            raise UserError(f"{where}: {error}") from None
        PACKAGES[point.name] = package + version
        _INSTALLED.append(point.name)


PLAYER_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_.-]{0,63}")
"""A player's name: a letter or ``_``, then at most 63 letters, digits, ``_``, ``.`` or
``-``. Names are parts of trial ids and universe ids, whose separators (``:``, ``=``, ``@``,
``,``) they must not hold, and of file and column names."""


def _check_name(kind: str, name: str) -> None:
    if not isinstance(name, str) or PLAYER_NAME.fullmatch(name) is None:
        raise ValueError(
            f"{name!r} is not a name for a {kind}: a letter or _, then at most 63 letters, "
            "digits, _, . or -"
        )


def register_human(name: str, human: Human) -> None:
    """Make ``human`` playable as the human ``name`` (:data:`PLAYER_NAME`)."""
    _check_name("human", name)
    if dict.__contains__(HUMANS, name):
        raise ValueError(f"a human named {name!r} is already registered")
    HUMANS[name] = human


def register_robot(name: str, robot: Robot) -> None:
    """Make ``robot`` playable as the robot ``name`` (:data:`PLAYER_NAME`)."""
    _check_name("robot", name)
    if dict.__contains__(ROBOTS, name):
        raise ValueError(f"a robot named {name!r} is already registered")
    ROBOTS[name] = robot


def player_faults(name: str, robot: str, eta: float | None, has_teaching: bool) -> list[str]:
    """What a trial's players make wrong in it, each named (empty when nothing): the human
    and the robot must be registered, ``eta`` given exactly for a human with a trade-off
    (:attr:`Human.takes_eta`), and a hypothesis space (``teaching``) for a player that
    needs one. The one statement of these rules, for a trial about to be played
    (:func:`cirl_study.core.trial.check_playable`) and a record read back
    (:mod:`cirl_study.logs.record_checks`).

    Examples:
        >>> player_faults("expert", "map", None, False)
        []
        >>> player_faults("expert", "map", 0.5, False)
        ['eta is 0.5 for human expert (null exactly for a human without a trade-off)']
    """
    faults = []
    human, machine = HUMANS.get(name), ROBOTS.get(robot)
    if human is None:
        faults.append(f"human {name!r} is not a known human ({', '.join(HUMANS)})")
    elif (eta is None) == human.takes_eta:
        faults.append(
            f"eta is {eta} for human {name} (null exactly for a human without a trade-off)"
        )
    if machine is None:
        faults.append(f"robot {robot!r} is not a known robot ({', '.join(ROBOTS)})")
    players = ((name, human), (robot, machine))
    needing = [who for who, player in players if player and player.needs_hypotheses]
    if needing and not has_teaching:
        faults.append(f"{' and '.join(needing)} need a hypothesis space, and teaching is null")
    return faults


def reference_robot(robots: Iterable[str]) -> str:
    """The reference among ``robots``: the first in the order of :data:`ROBOTS`.

    ``map``, the paper's robot, whenever it is one of them. The reference robot plays the
    eta cross-validation, and the paper's claims are judged on its trials.
    """
    present = set(robots)
    for name in dict.__iter__(ROBOTS):  # the built-in ones first: no installed player loads
        if name in present:
            return name
    return next(name for name in ROBOTS if name in present)


def _expert(game: Apprenticeship, theta: FloatArray, _eta: object, _seeds: IntArray) -> IntArray:
    from cirl_study.core.humans import expert_paths

    return expert_paths(game.learning, theta)


def _best_response(
    game: Apprenticeship, theta: FloatArray, eta: FloatArray | None, _seeds: IntArray
) -> IntArray:
    from cirl_study.core.humans import best_response_paths

    return best_response_paths(game.learning, theta, eta)


def _literal(game: Apprenticeship, theta: FloatArray, _eta: object, seeds: IntArray) -> IntArray:
    from cirl_study.core.humans import literal_paths

    return literal_paths(game.learning, theta, seeds)


def _pedagogic(game: Apprenticeship, theta: FloatArray, _eta: object, seeds: IntArray) -> IntArray:
    from cirl_study.core.teaching import pedagogic_paths

    return pedagogic_paths(game, theta, seeds)


def _regret_optimal(
    game: Apprenticeship, theta: FloatArray, _eta: object, seeds: IntArray
) -> IntArray:
    from cirl_study.core.teaching import regret_optimal_paths

    return regret_optimal_paths(game, theta, seeds)


def _map(game: Apprenticeship, demos: IntArray, _seeds: IntArray) -> Estimate:
    from cirl_study.core.robot import map_estimate

    return map_estimate(game.learning, demos)


def _posterior_mean(game: Apprenticeship, demos: IntArray, seeds: IntArray) -> Estimate:
    from cirl_study.core.posterior import posterior_mean_estimate

    return posterior_mean_estimate(game.learning, demos, seeds)


def _gradient_ascent(game: Apprenticeship, demos: IntArray, seeds: IntArray) -> Estimate:
    from cirl_study.core.gradient_ascent import estimate

    return estimate(game, demos, seeds)


def _literal_observer(game: Apprenticeship, demos: IntArray, seeds: IntArray) -> Estimate:
    from cirl_study.core.teaching import literal_estimate

    return literal_estimate(game, demos, seeds)


def _pragmatic(game: Apprenticeship, demos: IntArray, seeds: IntArray) -> Estimate:
    from cirl_study.core.teaching import pragmatic_estimate

    return pragmatic_estimate(game, demos, seeds)


def _recorded(
    game: Apprenticeship, theta: FloatArray, eta: FloatArray | None, seeds: IntArray
) -> IntArray:
    return game.replayed()


register_human(EXPERT, Human(_expert, takes_eta=False))
register_human(BEST_RESPONSE, Human(_best_response, takes_eta=True, path_search=True))
register_human(LITERAL, Human(_literal, takes_eta=False))
register_human(PEDAGOGIC, Human(_pedagogic, takes_eta=False, needs_hypotheses=True))
register_human(
    REGRET_OPTIMAL,
    Human(_regret_optimal, takes_eta=False, needs_hypotheses=True, path_search=True),
)
register_human(RECORDED, Human(_recorded, takes_eta=False, recorded=True))

register_robot(MAP, Robot(_map))
register_robot(POSTERIOR_MEAN, Robot(_posterior_mean))
register_robot(GRADIENT_ASCENT, Robot(_gradient_ascent, leaves_box=True))
register_robot(LITERAL_OBSERVER, Robot(_literal_observer, needs_hypotheses=True))
register_robot(PRAGMATIC, Robot(_pragmatic, needs_hypotheses=True))

_BUILT_IN = frozenset((*dict.__iter__(HUMANS), *dict.__iter__(ROBOTS)))
"""The names of the players above."""
