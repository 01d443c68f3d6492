"""The exact solver and the best-response operators against exhaustive enumeration."""

from __future__ import annotations

import random
from itertools import product

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cirl_study.theory import (
    coordination_pomdp,
    evaluate,
    exhaustive_optimum,
    human_best_response,
    robot_best_response,
    solve,
)
from cirl_study.theory.game import CIRLGame
from cirl_study.theory.office_supplies_grid import office_supplies_grid_game
from cirl_study.theory.random_game import random_game

small_shapes = st.sampled_from(
    [
        {"states": 2, "thetas": 2, "horizon": 2},
        {"states": 3, "thetas": 2, "horizon": 2},
        {"states": 1, "thetas": 3, "horizon": 2, "restrict_actions": False},
        {"states": 1, "thetas": 2, "horizon": 3, "robot_actions": 1, "restrict_actions": False},
        {"states": 3, "thetas": 3, "human_actions": 3, "horizon": 1, "restrict_actions": False},
    ]
)


def _all_robot_policies(game: CIRLGame):
    histories = game.histories()
    for actions in product(*(game.robot_available[h[-1]] for h in histories)):
        yield dict(zip(histories, actions, strict=True))


def _all_human_policies(game: CIRLGame):
    keys = [(h, theta) for h in game.histories() for theta in range(len(game.thetas))]
    for actions in product(*(game.human_available[h[-1]] for h, _ in keys)):
        yield dict(zip(keys, actions, strict=True))


def _random_human(game: CIRLGame, seed: int) -> dict:
    rng = random.Random(seed)
    return {
        (h, theta): rng.choice(game.human_available[h[-1]])
        for h in game.histories()
        for theta in range(len(game.thetas))
    }


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10**6), shape=small_shapes)
def test_solver_agrees_with_exhaustive_search_on_random_games(seed: int, shape: dict) -> None:
    game = random_game(seed, **shape)
    solution = solve(game)
    best, (human, robot) = exhaustive_optimum(game)
    assert solution.value == best
    assert evaluate(game, human, robot) == best
    # The solver's policies are complete and achieve its value, also as a coordinator policy.
    assert evaluate(game, solution.human, solution.robot) == solution.value
    assert coordination_pomdp(game).evaluate(solution.coordinator) == solution.value


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_solver_agrees_with_exhaustive_search_on_discretised_office_supplies(n: int) -> None:
    game = office_supplies_grid_game(n)
    assert solve(game).value == exhaustive_optimum(game)[0]


tiny_shapes = st.sampled_from(
    [  # at most 2**10 human and 2**5 robot policies
        {"states": 1, "thetas": 2, "horizon": 2, "restrict_actions": False},
        {"states": 2, "thetas": 2, "horizon": 1, "restrict_actions": False},
        {"states": 1, "thetas": 3, "horizon": 2, "robot_actions": 1, "restrict_actions": False},
    ]
)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10**6), shape=tiny_shapes)
def test_robot_best_response_beats_every_robot_policy(seed: int, shape: dict) -> None:
    game = random_game(seed, **shape)
    human = _random_human(game, seed)
    response = robot_best_response(game, human)
    assert set(response) == set(game.histories())
    best = max(evaluate(game, human, robot) for robot in _all_robot_policies(game))
    assert evaluate(game, human, response) == best


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 10**6), shape=tiny_shapes)
def test_human_best_response_beats_every_human_policy(seed: int, shape: dict) -> None:
    game = random_game(seed, **shape)
    rng = random.Random(seed)
    robot = {h: rng.choice(game.robot_available[h[-1]]) for h in game.histories()}
    response = human_best_response(game, robot)
    assert set(response) == {(h, t) for h in game.histories() for t in range(len(game.thetas))}
    best = max(evaluate(game, human, robot) for human in _all_human_policies(game))
    assert evaluate(game, response, robot) == best


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10**6), shape=small_shapes)
def test_no_pair_beats_the_solver_and_best_responses_never_lose_value(
    seed: int, shape: dict
) -> None:
    game = random_game(seed, **shape)
    optimum = solve(game).value
    human = _random_human(game, seed)
    robot = robot_best_response(game, human)
    better_human = human_best_response(game, robot)
    assert evaluate(game, human, robot) <= evaluate(game, better_human, robot) <= optimum
