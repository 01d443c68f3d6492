"""Exact optimal policy pairs of small CIRL games, through the coordination POMDP.

By Theorem 1 an optimal pair is an optimal policy of the coordination POMDP
``M_C``, and by Corollary 1 it needs only the world state and the belief about
``theta``. With deterministic decision rules and ``T`` independent of ``theta``, the
belief after any history is the prior ``P0(. | s_0)`` restricted to the set ``W`` of
thetas consistent with ``H``'s actions so far. Backward induction over
``(t, s, s_0, W)`` gives the optimal conditional value

    V_t(s, W) = max_{a_R, delta: W -> A_H} sum_{theta in W} b(theta) R(s, delta(theta), a_R; theta)
                + gamma sum_{a_H} b(W_a) sum_{s'} T(s' | s, a_H, a_R) V_{t+1}(s', W_a),

with ``b = P0(. | s_0)`` restricted to ``W``, ``W_a = {theta in W : delta(theta) = a_H}``.
The maximum enumerates all ``|A_R| |A_H|^|W|`` coordinator actions, so the solver is
exact and meant for small games. In the last round there is no future, so each
``theta``'s action is chosen independently (the objective separates).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from fractions import Fraction
from itertools import product

from cirl_study.theory.coordination_pomdp import CoordinatorAction, policy_pair
from cirl_study.theory.game import CIRLGame, History, Number, round_of

_Key = tuple[int, int, int, tuple[int, ...]]
"""``(t, s, s_0, W)``: round, world state, initial state, thetas still possible."""


@dataclass(frozen=True)
class Solution:
    """An optimal policy pair and its value ``V*``."""

    value: Number
    coordinator: dict[History, CoordinatorAction]
    human: dict[tuple[History, int], int]
    robot: dict[History, int]


@dataclass
class _Solver:
    game: CIRLGame
    memo: dict[_Key, tuple[Number, dict[int, int], int]] = field(default_factory=dict)

    def best(self, key: _Key) -> tuple[Number, dict[int, int], int]:
        """``(V_t(s, W), delta on W, a_R)`` for ``key = (t, s, s_0, W)``."""
        if key not in self.memo:
            self.memo[key] = self._solve(key)
        return self.memo[key]

    def _solve(self, key: _Key) -> tuple[Number, dict[int, int], int]:
        t, s, s0, support = key
        game = self.game
        prior = game.initial[s0]
        total = sum(prior[theta] for theta in support)
        belief = {theta: prior[theta] / total for theta in support}
        best: tuple[Number, dict[int, int], int] | None = None
        for a_r in game.robot_available[s]:
            for rule in self._rules(s, a_r, support, last=t + 1 == game.horizon):
                value = self._q_value(key, belief, rule, a_r)
                if best is None or value > best[0]:
                    best = (value, rule, a_r)
        assert best is not None  # every state has available actions
        return best

    def _rules(
        self, s: int, a_r: int, support: Sequence[int], last: bool
    ) -> Iterator[dict[int, int]]:
        """Decision rules on ``support`` to consider: all of them, or in the last round the
        one maximising each theta's immediate reward (first action on ties)."""
        actions = self.game.human_available[s]
        if last:
            reward = self.game.reward
            yield {
                theta: max(actions, key=lambda a_h, theta=theta: reward[(s, a_h, a_r)][theta])
                for theta in support
            }
            return
        for acts in product(actions, repeat=len(support)):
            yield dict(zip(support, acts, strict=True))

    def _q_value(
        self, key: _Key, belief: dict[int, Number], rule: dict[int, int], a_r: int
    ) -> Number:
        t, s, s0, _ = key
        game = self.game
        value = sum(
            (b * game.reward[(s, rule[theta], a_r)][theta] for theta, b in belief.items()),
            start=Fraction(0),
        )
        if t + 1 == game.horizon:
            return value
        for a_h in sorted(set(rule.values())):
            cell = tuple(theta for theta in belief if rule[theta] == a_h)
            mass = sum(belief[theta] for theta in cell)
            for s_next, p in game.transition[(s, a_h, a_r)]:
                value += game.gamma * mass * p * self.best((t + 1, s_next, s0, cell))[0]
        return value


def solve(game: CIRLGame) -> Solution:
    """An optimal policy pair of ``game`` and its value, exact for exact games.

    The returned policies act at every history: off the optimal path (a human
    action the rule never gives) the set of possible thetas is kept unchanged, as
    in :mod:`cirl_study.theory.beliefs`; thetas already ruled out at a history take the
    first available action there (they never reach it). Ties go to the first
    robot action and the first decision rule in enumeration order.
    """
    solver = _Solver(game)
    coordinator: dict[History, CoordinatorAction] = {}
    value: Number = Fraction(0)
    layer: list[tuple[History, tuple[int, ...]]] = []
    for s0 in game.roots:
        support = tuple(theta for theta, p in enumerate(game.initial[s0]) if p > 0)
        layer.append(((s0,), support))
        value += sum(game.initial[s0]) * solver.best((0, s0, s0, support))[0]
    while layer:
        following = []
        for history, support in layer:
            s = history[-1]
            _, rule, a_r = solver.best((round_of(history), s, history[0], support))
            default = game.human_available[s][0]
            coordinator[history] = (
                tuple(rule.get(theta, default) for theta in range(len(game.thetas))),
                a_r,
            )
            if round_of(history) + 1 == game.horizon:
                continue
            for child in game.children(history):
                cell = tuple(theta for theta in support if rule[theta] == child[-3])
                following.append((child, cell or support))
        layer = following
    human, robot = policy_pair(game, coordinator)
    return Solution(value=value, coordinator=coordinator, human=human, robot=robot)
