"""Theorem 1: the coordination POMDP has |S| |Theta| hidden states and a policy pair and its
coordinator policy achieve the same value (checked by enumeration on random small games)."""

from __future__ import annotations

import random
from fractions import Fraction

from hypothesis import given, settings
from hypothesis import strategies as st

from cirl_study.theory import coordination_pomdp, coordinator_policy, evaluate, policy_pair
from cirl_study.theory.coordination_pomdp import CoordinationPOMDP
from cirl_study.theory.game import CIRLGame
from cirl_study.theory.random_game import random_game

shapes = st.fixed_dictionaries(
    {
        "states": st.integers(1, 3),
        "human_actions": st.integers(1, 3),
        "robot_actions": st.integers(1, 2),
        "thetas": st.integers(1, 3),
        "horizon": st.integers(1, 3),
        "restrict_actions": st.booleans(),
    }
)


def _random_pair(game: CIRLGame, seed: int) -> tuple[dict, dict]:
    """A deterministic pair with a random action at every history (and theta)."""
    rng = random.Random(seed)
    human, robot = {}, {}
    for history in game.histories():
        s = history[-1]
        robot[history] = rng.choice(game.robot_available[s])
        for theta in range(len(game.thetas)):
            human[(history, theta)] = rng.choice(game.human_available[s])
    return human, robot


def _naive_pair_value(game: CIRLGame, human: dict, robot: dict) -> Fraction:
    """The value by enumerating every (theta, trajectory) with its probability."""
    total = Fraction(0)
    paths = [
        ((s0,), theta, p, Fraction(1))
        for s0 in range(len(game.states))
        for theta, p in enumerate(game.initial[s0])
        if p > 0
    ]
    while paths:
        following = []
        for history, theta, probability, discount in paths:
            if len(history) // 3 == game.horizon:
                continue
            s, a_r = history[-1], robot[history]
            a_h = human[(history, theta)]
            total += probability * discount * game.reward[(s, a_h, a_r)][theta]
            for s_next, q in game.transition[(s, a_h, a_r)]:
                following.append(
                    ((*history, a_h, a_r, s_next), theta, probability * q, discount * game.gamma)
                )
        paths = following
    return total


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10**6), shape=shapes)
def test_a_pair_and_its_coordinator_policy_have_the_same_value(seed: int, shape: dict) -> None:
    game = random_game(seed, **shape)
    pomdp = coordination_pomdp(game)
    assert len(pomdp.hidden_states) == len(game.states) * len(game.thetas)
    human, robot = _random_pair(game, seed)
    value = evaluate(game, human, robot)
    assert value == _naive_pair_value(game, human, robot)
    assert pomdp.evaluate(coordinator_policy(game, human, robot)) == value


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10**6), shape=shapes)
def test_a_coordinator_policy_and_its_pair_have_the_same_value(seed: int, shape: dict) -> None:
    game = random_game(seed, **shape)
    pomdp = coordination_pomdp(game)
    rng = random.Random(seed + 1)
    policy = {history: rng.choice(list(pomdp.actions(history[-1]))) for history in game.histories()}
    human, robot = policy_pair(game, policy)
    assert evaluate(game, human, robot) == pomdp.evaluate(policy)
    assert coordinator_policy(game, human, robot) == policy


def test_the_coordination_pomdp_follows_the_definition() -> None:
    game = random_game(
        11, states=2, human_actions=2, robot_actions=2, thetas=3, restrict_actions=False
    )
    pomdp = CoordinationPOMDP(game)
    assert pomdp.hidden_states == tuple((s, t) for s in range(2) for t in range(3))
    assert sum(pomdp.initial().values()) == 1
    actions = list(pomdp.actions(0))
    assert len(actions) == 2**3 * 2  # |A_H|^|Theta| decision rules times |A_R|
    rule, a_r = (1, 0, 1), 0
    for theta in range(3):
        hidden = (0, theta)
        assert pomdp.reward(hidden, (rule, a_r)) == game.reward[(0, rule[theta], a_r)][theta]
        for (s_next, kept), p in pomdp.transition(hidden, (rule, a_r)):
            assert kept == theta  # theta is static
            assert (s_next, p) in game.transition[(0, rule[theta], a_r)]
            assert pomdp.observation(hidden, (rule, a_r), (s_next, kept)) == (rule[theta], s_next)
