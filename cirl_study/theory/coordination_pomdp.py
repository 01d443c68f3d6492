"""The coordination POMDP ``M_C`` of a CIRL game (paper section 3.2, Theorem 1).

A coordinator ``C`` sees only the common observations and, each round, picks a
decision rule for the human, ``delta_H: Theta -> A_H``, and an action ``a_R`` for
the robot. Hidden states are ``S_C = S x Theta``; the initial distribution is
``P0``; after action ``(delta_H, a_R)`` in ``(s, theta)`` the reward is
``R(s, delta_H(theta), a_R; theta)``, the next hidden state is ``(s', theta)`` with
probability ``T(s' | s, delta_H(theta), a_R)``, and ``C`` observes ``(delta_H(theta), s')``.

Theorem 1: ``|S_C| = |S| |Theta|`` and every policy pair of ``M`` has a coordinator
policy with the same value (and conversely): :func:`coordinator_policy` and
:func:`policy_pair` are the two directions of the proof.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from fractions import Fraction
from itertools import product
from typing import TypeAlias

from cirl_study.errors import UserError
from cirl_study.theory.game import CIRLGame, History, Number, round_of
from cirl_study.theory.policies import HumanPolicy, RobotPolicy, human_action, robot_action

HiddenState: TypeAlias = tuple[int, int]
"""``(s, theta)`` by index."""

CoordinatorAction: TypeAlias = tuple[tuple[int, ...], int]
"""``(delta_H, a_R)``: ``delta_H[theta]`` is the human's action for each theta."""

CoordinatorPolicy: TypeAlias = Mapping[History, CoordinatorAction]
"""The coordinator's action after each common history ``(s_0, a_H0, a_R0, ..., s_t)``
(its own past ``a_R`` and its observations ``(a_H, s')``)."""


@dataclass(frozen=True, eq=False)
class CoordinationPOMDP:
    """``M_C`` for a CIRL game: a single-actor POMDP over hidden states ``S x Theta``."""

    game: CIRLGame

    @property
    def hidden_states(self) -> tuple[HiddenState, ...]:
        """``S_C = S x Theta``."""
        return tuple(product(range(len(self.game.states)), range(len(self.game.thetas))))

    def initial(self) -> dict[HiddenState, Number]:
        """``P0`` as a distribution over hidden states (positive entries only)."""
        return {
            (s, theta): p
            for s, row in enumerate(self.game.initial)
            for theta, p in enumerate(row)
            if p > 0
        }

    def actions(self, s: int) -> Iterator[CoordinatorAction]:
        """Every ``(delta_H, a_R)`` available in world state ``s`` (``|A_H|^|Theta| |A_R|``)."""
        game = self.game
        for a_r in game.robot_available[s]:
            for rule in product(game.human_available[s], repeat=len(game.thetas)):
                yield rule, a_r

    def reward(self, hidden: HiddenState, action: CoordinatorAction) -> Number:
        """``R_C((s, theta), (delta_H, a_R)) = R(s, delta_H(theta), a_R; theta)``."""
        (s, theta), (rule, a_r) = hidden, action
        return self.game.reward[(s, rule[theta], a_r)][theta]

    def transition(
        self, hidden: HiddenState, action: CoordinatorAction
    ) -> tuple[tuple[HiddenState, Number], ...]:
        """``T_C((s', theta) | (s, theta), (delta_H, a_R)) = T(s' | s, delta_H(theta), a_R)``."""
        (s, theta), (rule, a_r) = hidden, action
        return tuple(
            ((s_next, theta), p) for s_next, p in self.game.transition[(s, rule[theta], a_r)]
        )

    def observation(
        self, hidden: HiddenState, action: CoordinatorAction, following: HiddenState
    ) -> tuple[int, int]:
        """``C`` observes the human's action ``delta_H(theta)`` and the next world state."""
        return action[0][hidden[1]], following[0]

    def evaluate(self, policy: CoordinatorPolicy) -> Number:
        """The coordinator policy's expected discounted reward, by exact forward recursion
        over (observation history, joint probability of hidden state and history)."""
        roots: dict[int, dict[HiddenState, Number]] = {}
        for hidden, p in self.initial().items():
            roots.setdefault(hidden[0], {})[hidden] = p
        return sum(
            (self._value((s0,), weights, policy) for s0, weights in roots.items()),
            start=Fraction(0),
        )

    def _value(
        self, history: History, weights: dict[HiddenState, Number], policy: CoordinatorPolicy
    ) -> Number:
        if round_of(history) == self.game.horizon:
            return Fraction(0)
        action = policy.get(history)
        if action is None:
            raise UserError(f"the coordinator policy has no action at history {history}")
        total = sum((p * self.reward(x, action) for x, p in weights.items()), start=Fraction(0))
        children: dict[tuple[int, int], dict[HiddenState, Number]] = {}
        for hidden, p in weights.items():
            for following, q in self.transition(hidden, action):
                seen = self.observation(hidden, action, following)
                child = children.setdefault(seen, {})
                child[following] = child.get(following, 0) + p * q
        for (a_h, s_next), child in children.items():
            total += self.game.gamma * self._value(
                (*history, a_h, action[1], s_next), child, policy
            )
        return total


def coordination_pomdp(game: CIRLGame) -> CoordinationPOMDP:
    """The coordination POMDP ``M_C`` of ``game``."""
    return CoordinationPOMDP(game)


def coordinator_policy(
    game: CIRLGame, human: HumanPolicy, robot: RobotPolicy
) -> dict[History, CoordinatorAction]:
    """Theorem 1, pair to coordinator: ``delta_H(theta) = pi_H(h, theta)`` and ``a_R = pi_R(h)``
    after each common history ``h``."""
    return {
        history: (
            tuple(human_action(game, human, history, theta) for theta in range(len(game.thetas))),
            robot_action(game, robot, history),
        )
        for history in game.histories()
    }


def policy_pair(
    game: CIRLGame, policy: CoordinatorPolicy
) -> tuple[dict[tuple[History, int], int], dict[History, int]]:
    """Theorem 1, coordinator to pair: both players simulate ``C`` on the common history;
    ``H`` applies the decision rule to her ``theta``, ``R`` takes ``a_R``."""
    human: dict[tuple[History, int], int] = {}
    robot: dict[History, int] = {}
    for history, (rule, a_r) in policy.items():
        robot[history] = a_r
        for theta, a_h in enumerate(rule):
            human[(history, theta)] = a_h
    return human, robot
