"""Random small CIRL games with exact rational tables, for checking solvers against each other."""

from __future__ import annotations

import random
from fractions import Fraction

from cirl_study.theory.game import CIRLGame, Number, Outcomes


def _distribution(rng: random.Random, size: int, support: int) -> list[Fraction]:
    """A random distribution over ``size`` outcomes with at most ``support`` of them possible."""
    chosen = rng.sample(range(size), k=rng.randint(1, min(support, size)))
    weights = {k: rng.randint(1, 4) for k in chosen}
    total = sum(weights.values())
    return [Fraction(weights.get(k, 0), total) for k in range(size)]


def random_game(
    seed: int,
    *,
    states: int = 2,
    human_actions: int = 2,
    robot_actions: int = 2,
    thetas: int = 2,
    horizon: int = 2,
    restrict_actions: bool = True,
) -> CIRLGame:
    """A random game: integer rewards in ``[-3, 3]``, sparse rational ``T`` and ``P0``,
    ``gamma`` in ``{1/2, 1}`` and, if ``restrict_actions``, random nonempty sets of
    available actions per state. The same ``seed`` gives the same game."""
    rng = random.Random(seed)

    def available(count: int) -> tuple[tuple[int, ...], ...]:
        if not restrict_actions:
            return tuple(tuple(range(count)) for _ in range(states))
        return tuple(
            tuple(sorted(rng.sample(range(count), k=rng.randint(1, count)))) for _ in range(states)
        )

    human_av, robot_av = available(human_actions), available(robot_actions)
    transition: dict[tuple[int, int, int], Outcomes] = {}
    reward: dict[tuple[int, int, int], tuple[Number, ...]] = {}
    for s in range(states):
        for a_h in human_av[s]:
            for a_r in robot_av[s]:
                probabilities = _distribution(rng, states, support=2)
                transition[(s, a_h, a_r)] = tuple(
                    (s_next, p) for s_next, p in enumerate(probabilities) if p > 0
                )
                reward[(s, a_h, a_r)] = tuple(Fraction(rng.randint(-3, 3)) for _ in range(thetas))
    joint = _distribution(rng, states * thetas, support=states * thetas)
    return CIRLGame(
        states=tuple(f"s{k}" for k in range(states)),
        human_actions=tuple(f"h{k}" for k in range(human_actions)),
        robot_actions=tuple(f"r{k}" for k in range(robot_actions)),
        thetas=tuple(f"theta{k}" for k in range(thetas)),
        human_available=human_av,
        robot_available=robot_av,
        transition=transition,
        reward=reward,
        initial=tuple(tuple(joint[s * thetas : (s + 1) * thetas]) for s in range(states)),
        gamma=rng.choice((Fraction(1, 2), Fraction(1))),
        horizon=horizon,
    )
