"""The robot's belief about ``theta``: Bayes' rule on the human's observed actions.

``T`` does not depend on ``theta``, so only ``H``'s actions carry information. If
``H`` follows a deterministic policy ``pi_H``, the belief after the history
``h = (s_0, a_H0, a_R0, ..., s_t)`` is

    b_h(theta) ∝ P0(s_0, theta) * prod_k 1[pi_H(h_k, theta) = a_Hk],

the inverse-reinforcement-learning posterior of paper section 3.3. Convention for
an action that ``pi_H`` never takes under the current belief (a zero-probability
observation, where Bayes' rule is undefined): the belief stays as it was.
"""

from __future__ import annotations

from collections.abc import Sequence
from fractions import Fraction

from cirl_study.theory.game import CIRLGame, History, Number
from cirl_study.theory.policies import HumanPolicy, human_action

Belief = tuple[Number, ...]
"""A probability for each ``theta`` (by index)."""


def initial_belief(game: CIRLGame, s0: int) -> Belief:
    """``P0(theta | s_0)``; ``s_0`` must have positive probability."""
    row = game.initial[s0]
    total = sum(row)
    return tuple(p / total for p in row)


def condition(belief: Belief, keep: Sequence[bool]) -> Belief:
    """``belief`` restricted to the thetas where ``keep`` holds and renormalised; unchanged
    when that set has probability zero (the convention above)."""
    mass = sum((p for p, k in zip(belief, keep, strict=True) if k), start=Fraction(0))
    if mass == 0:
        return belief
    return tuple(p / mass if k else p * 0 for p, k in zip(belief, keep, strict=True))


def update(
    game: CIRLGame, human: HumanPolicy, belief: Belief, history: History, a_h: int
) -> Belief:
    """The belief after observing ``H`` take ``a_h`` at ``history``."""
    keep = [
        p > 0 and human_action(game, human, history, theta) == a_h for theta, p in enumerate(belief)
    ]
    return condition(belief, keep)


def posterior(game: CIRLGame, human: HumanPolicy, history: History) -> Belief:
    """The robot's belief ``b_h`` after ``history`` when ``H`` follows ``human``."""
    belief = initial_belief(game, history[0])
    for k in range(1, len(history), 3):
        belief = update(game, human, belief, history[:k], history[k])
    return belief


def mean(belief: Belief, values: Sequence[Number]) -> Number:
    """``E_b[f(theta)] = sum_theta b(theta) f(theta)``."""
    return sum((p * v for p, v in zip(belief, values, strict=True)), start=Fraction(0))
