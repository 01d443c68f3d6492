"""Theorem 2: in the deployment phase the robot maximises the mean reward.

Once ``H`` has no choice left (each state has one available human action), ``R``
gets no further information about ``theta``, so its belief ``b`` stays fixed and its
problem is the MDP with the mean reward

    R_b(s, a_R) = sum_theta b(theta) R(s, a_H, a_R; theta).

When ``R`` is affine in ``theta`` (as in the office-supplies game) this is the
reward under the posterior mean, ``R(s, a_H, a_R; E_b[theta])``.
:func:`mean_reward_plan` solves that MDP; the robot's best response
(:func:`cirl_study.theory.operators.robot_best_response`) must act the same way.
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction

from cirl_study.errors import UserError
from cirl_study.theory.beliefs import Belief, mean
from cirl_study.theory.game import CIRLGame, Number


@dataclass(frozen=True)
class MeanRewardPlan:
    """Optimal values and actions of the mean-reward MDP, keyed by ``(t, s)``."""

    values: dict[tuple[int, int], Number]
    actions: dict[tuple[int, int], int]


def mean_reward_plan(game: CIRLGame, belief: Belief, t: int, s: int) -> MeanRewardPlan:
    """Finite-horizon value iteration for ``R_b`` from round ``t`` in state ``s`` to the
    horizon, over the states reachable from there. Ties go to the first action.

    Raises :class:`UserError` if ``H`` still has a choice in a reachable state
    (Theorem 2 is about the deployment phase only).
    """
    reachable = [{s}]
    for _ in range(t, game.horizon - 1):
        reachable.append(
            {
                s_next
                for state in reachable[-1]
                for a_r in game.robot_available[state]
                for s_next, _ in game.transition[(state, game.human_available[state][0], a_r)]
            }
        )
    for layer in reachable:
        for state in layer:
            if len(game.human_available[state]) > 1:
                raise UserError(
                    f"the human still acts in state {game.states[state]!r}: "
                    "Theorem 2 applies to the deployment phase only"
                )
    values: dict[tuple[int, int], Number] = {}
    actions: dict[tuple[int, int], int] = {}
    for offset in reversed(range(len(reachable))):
        round_ = t + offset
        for state in reachable[offset]:
            a_h = game.human_available[state][0]
            best: tuple[Number, int] | None = None
            for a_r in game.robot_available[state]:
                future = sum(
                    (
                        p * values.get((round_ + 1, s_next), Fraction(0))
                        for s_next, p in game.transition[(state, a_h, a_r)]
                    ),
                    start=Fraction(0),
                )
                value = mean(belief, game.reward[(state, a_h, a_r)]) + game.gamma * future
                if best is None or value > best[0]:
                    best = (value, a_r)
            assert best is not None  # every state has an available robot action
            values[(round_, state)], actions[(round_, state)] = best
    return MeanRewardPlan(values=values, actions=actions)
