"""The players by name: every human policy and every robot a pipeline may name.

A human policy is a :class:`Human`; a robot is an
:data:`~cirl_study.core.estimate.Estimator`. Both read the batch's game
(:class:`~cirl_study.core.apprenticeship.Apprenticeship`). Adding one is one function in its
own module and one :func:`register_human` or :func:`register_robot` line here.

Each registered player imports its module when it first plays: reading, checking and
analysing logs need only the players' names and what they imply for a record
(:attr:`Human.takes_eta`, ``teaches``), and so never load the numerical core (numba and
scipy, about 0.3 s of every such command's start).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from cirl_study.record import (
    BEST_RESPONSE,
    EXPERT,
    LITERAL,
    LITERAL_ROBOT,
    MAP,
    PEDAGOGIC,
    POSTERIOR_MEAN,
    PRAGMATIC,
    REGRET_OPTIMAL,
)

if TYPE_CHECKING:
    from cirl_study.core.apprenticeship import Apprenticeship
    from cirl_study.core.estimate import Estimate, Estimator
    from cirl_study.core.planning import FloatArray, IntArray


@dataclass(frozen=True)
class Human:
    """A human policy: how she demonstrates, and whether she trades reward against teaching.

    Attributes:
        demonstrate: ``demonstrate(game, theta, eta, seeds)`` returns the ``(B, T + 1)``
            paths; ``eta`` is ``(B,)`` when :attr:`takes_eta`, else ``None``; ``seeds`` are the
            trials' seeds.
        takes_eta: whether the policy has the trade-off :math:`\\eta`, chosen by
            cross-validation before the test trials (docs/design.md §3).
        teaches: whether she needs the trials' hypothesis space (a pipeline's ``[teaching]``).
    """

    demonstrate: Callable[[Apprenticeship, FloatArray, FloatArray | None, IntArray], IntArray]
    takes_eta: bool
    teaches: bool = False


@dataclass(frozen=True)
class Robot:
    """A robot: its estimator, and whether it needs the trials' hypothesis space."""

    estimate: Estimator
    teaches: bool = False


HUMANS: dict[str, Human] = {}
"""Every human policy, by the name a pipeline and a trial record use (``policy``)."""

ROBOTS: dict[str, Robot] = {}
"""Every robot, by the name a pipeline and a trial record use (``robot``)."""


def register_human(name: str, human: Human) -> None:
    """Make ``human`` playable as the policy ``name``."""
    if name in HUMANS:
        raise ValueError(f"a human policy named {name!r} is already registered")
    HUMANS[name] = human


def register_robot(name: str, robot: Robot) -> None:
    """Make ``robot`` playable as the robot ``name``."""
    if name in ROBOTS:
        raise ValueError(f"a robot named {name!r} is already registered")
    ROBOTS[name] = robot


def reference_robot(robots: Iterable[str]) -> str:
    """The reference among ``robots``: the first in the order of :data:`ROBOTS`.

    ``map``, the paper's robot, whenever it is one of them. The reference robot plays the
    eta cross-validation, and the paper's claims are judged on its trials.
    """
    present = set(robots)
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


def _literal_robot(game: Apprenticeship, demos: IntArray, seeds: IntArray) -> Estimate:
    from cirl_study.core.teaching import literal_estimate

    return literal_estimate(game, demos, seeds)


def _pragmatic(game: Apprenticeship, demos: IntArray, seeds: IntArray) -> Estimate:
    from cirl_study.core.teaching import pragmatic_estimate

    return pragmatic_estimate(game, demos, seeds)


register_human(EXPERT, Human(_expert, takes_eta=False))
register_human(BEST_RESPONSE, Human(_best_response, takes_eta=True))
register_human(LITERAL, Human(_literal, takes_eta=False))
register_human(PEDAGOGIC, Human(_pedagogic, takes_eta=False, teaches=True))
register_human(REGRET_OPTIMAL, Human(_regret_optimal, takes_eta=False, teaches=True))

register_robot(MAP, Robot(_map))
register_robot(POSTERIOR_MEAN, Robot(_posterior_mean))
register_robot(LITERAL_ROBOT, Robot(_literal_robot, teaches=True))
register_robot(PRAGMATIC, Robot(_pragmatic, teaches=True))
