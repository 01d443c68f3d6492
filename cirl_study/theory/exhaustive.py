"""Exhaustive search over deterministic policy pairs: the reference the solver is checked against.

Every deterministic pair is enumerated by its choices at the histories it can reach
(what it would do elsewhere cannot change its value), each is evaluated by plain
forward recursion (:func:`cirl_study.theory.policies.root_value`), and the best is
kept. No beliefs, no dynamic programming: only the two facts that a pair's value
depends on its reachable choices alone, and that pairs from different initial
states use disjoint histories, so their best values add up. The number of pairs
grows like ``(|A_R| |A_H|^|Theta|)`` to the number of histories: tiny games only.
"""

from __future__ import annotations

from collections.abc import Iterator
from fractions import Fraction
from itertools import product

from cirl_study.theory.game import CIRLGame, History, Number, round_of
from cirl_study.theory.policies import root_value

_Pair = tuple[dict[tuple[History, int], int], dict[History, int]]


def exhaustive_optimum(game: CIRLGame) -> tuple[Number, _Pair]:
    """The best value over all deterministic policy pairs, and a pair attaining it."""
    value: Number = Fraction(0)
    human: dict[tuple[History, int], int] = {}
    robot: dict[History, int] = {}
    for s0 in game.roots:
        thetas = tuple(theta for theta, p in enumerate(game.initial[s0]) if p > 0)
        best: tuple[Number, _Pair] | None = None
        for pair in _pairs(game, (s0,), thetas):
            candidate = root_value(game, *pair, s0)
            if best is None or candidate > best[0]:
                best = (candidate, pair)
        assert best is not None  # at least one pair exists
        value += best[0]
        human.update(best[1][0])
        robot.update(best[1][1])
    return value, (human, robot)


def _pairs(game: CIRLGame, history: History, thetas: tuple[int, ...]) -> Iterator[_Pair]:
    """Every pair's choices at ``history`` and below, where ``thetas`` can reach ``history``."""
    if round_of(history) == game.horizon:
        yield {}, {}
        return
    s = history[-1]
    for a_r in game.robot_available[s]:
        for acts in product(game.human_available[s], repeat=len(thetas)):
            branches = [
                list(
                    _pairs(
                        game,
                        (*history, a_h, a_r, s_next),
                        tuple(th for th, act in zip(thetas, acts, strict=True) if act == a_h),
                    )
                )
                for a_h in sorted(set(acts))
                for s_next, _ in game.transition[(s, a_h, a_r)]
            ]
            for parts in product(*branches):
                human = {(history, theta): act for theta, act in zip(thetas, acts, strict=True)}
                robot = {history: a_r}
                for part_human, part_robot in parts:
                    human.update(part_human)
                    robot.update(part_robot)
                yield human, robot
