"""The office-supplies game with ``Theta`` discretised, as a generic :class:`CIRLGame`.

``Theta = {(2i + 1) / (2n) : i = 0..n-1}``, the midpoints of ``n`` equal cells of
``[0, 1]``, each with prior ``1/n`` (the midpoint rule for the uniform prior; its
mean is exactly ``1/2``, like the continuous prior's). The generic solver and
best-response operators run on this game; as ``n`` grows their results approach
the exact analysis of :mod:`cirl_study.theory.office_supplies`.
"""

from __future__ import annotations

from fractions import Fraction

from cirl_study.errors import UserError
from cirl_study.theory.apprenticeship import apprenticeship_game
from cirl_study.theory.game import CIRLGame
from cirl_study.theory.office_supplies import HUMAN_ACTIONS, ROBOT_ACTIONS, production_reward
from cirl_study.theory.policies import HumanPolicy


def theta_grid(n: int) -> tuple[Fraction, ...]:
    """The ``n`` cell midpoints ``(2i + 1) / (2n)``."""
    if n < 1:
        raise UserError(f"the theta grid needs at least one point, got {n}")
    return tuple(Fraction(2 * i + 1, 2 * n) for i in range(n))


def office_supplies_grid_game(n: int) -> CIRLGame:
    """The ACIRL game: one learning round (``H`` makes items), one deployment round (``R``)."""
    thetas = theta_grid(n)
    return apprenticeship_game(
        initial_state=(0, 0),
        human_actions=HUMAN_ACTIONS,
        robot_actions=ROBOT_ACTIONS,
        step=lambda owned, made: (owned[0] + made[0], owned[1] + made[1]),
        reward=lambda _owned, made, theta: production_reward(made)(theta),
        thetas=thetas,
        prior=[Fraction(1, n)] * n,
        learning_steps=1,
        deployment_steps=1,
    )


def one_of_each_interval(game: CIRLGame, human: HumanPolicy) -> tuple[Fraction, Fraction] | None:
    """The smallest and largest grid theta at which ``H`` makes ``(1, 1)`` at ``t = 0``
    (the discretised thresholds), or ``None`` if she never does."""
    root = (game.roots[0],)
    one_of_each = game.human_actions.index((1, 1))
    chosen = [
        game.thetas[theta]
        for theta in range(len(game.thetas))
        if human[(root, theta)] == one_of_each
    ]
    return (min(chosen), max(chosen)) if chosen else None
