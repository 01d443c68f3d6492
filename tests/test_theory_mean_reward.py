"""Theorem 2: in the deployment phase the robot's best response maximises the mean reward."""

from __future__ import annotations

import random
from fractions import Fraction

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cirl_study.errors import UserError
from cirl_study.theory import (
    apprenticeship_game,
    demonstration_by_expert,
    mean_reward_plan,
    posterior,
    robot_best_response,
)
from cirl_study.theory.game import CIRLGame, round_of
from cirl_study.theory.office_supplies import HUMAN_ACTIONS, section_3_3_rule
from cirl_study.theory.office_supplies_grid import office_supplies_grid_game
from cirl_study.theory.threshold_rules import action_at


def _random_apprenticeship_game(seed: int, deployment_steps: int) -> CIRLGame:
    """Worlds 0..3, random deterministic moves and integer rewards, 3 thetas."""
    rng = random.Random(seed)
    moves = {(w, a): rng.randrange(4) for w in range(4) for a in range(3)}
    payoff = {(w, a, t): rng.randint(-3, 3) for w in range(4) for a in range(3) for t in range(3)}
    weights = [rng.randint(1, 3) for _ in range(3)]
    return apprenticeship_game(
        initial_state=0,
        human_actions=(0, 1),
        robot_actions=(0, 1, 2),
        step=lambda w, a: moves[(w, a)],
        reward=lambda w, a, theta: payoff[(w, a, theta)],
        thetas=(0, 1, 2),
        prior=[Fraction(w, sum(weights)) for w in weights],
        learning_steps=rng.randint(1, 2),
        deployment_steps=deployment_steps,
        gamma=rng.choice((Fraction(1, 2), 1)),
    )


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10**6), deployment_steps=st.integers(1, 3))
def test_robot_best_response_in_deployment_is_the_mean_reward_plan(
    seed: int, deployment_steps: int
) -> None:
    game = _random_apprenticeship_game(seed, deployment_steps)
    rng = random.Random(seed)
    human = {
        (h, theta): rng.choice(game.human_available[h[-1]])
        for h in game.histories()
        for theta in range(len(game.thetas))
    }
    robot = robot_best_response(game, human)
    learning = game.horizon - deployment_steps
    for history in game.histories():
        if round_of(history) != learning:
            continue
        belief = posterior(game, human, history)
        plan = mean_reward_plan(game, belief, learning, history[-1])
        # Every deployment history below: the same action as the mean-reward MDP.
        for later in game.histories():
            if later[: len(history)] == history:
                assert robot[later] == plan.actions[(round_of(later), later[-1])]


def test_section_3_3_example_on_a_grid_the_robot_acts_as_if_theta_is_one_sixth() -> None:
    game = office_supplies_grid_game(6)  # thetas 1/12, 3/12, ..., 11/12
    root = (game.roots[0],)
    rule = section_3_3_rule()
    human = {
        (h, theta): (
            game.human_actions.index(HUMAN_ACTIONS[action_at(rule, value)])
            if h == root
            else game.human_available[h[-1]][0]
        )
        for h in game.histories()
        for theta, value in enumerate(game.thetas)
    }
    robot = robot_best_response(game, human)
    made = game.human_actions.index((0, 2))
    wait = game.robot_actions.index("wait")
    history = (*root, made, wait, game.states.index(((0, 2), 1)))
    belief = posterior(game, human, history)
    assert [game.thetas[t] for t, p in enumerate(belief) if p > 0] == [
        Fraction(1, 12),
        Fraction(3, 12),
    ]
    theta_mean = sum(p * theta for p, theta in zip(belief, game.thetas, strict=True))
    assert theta_mean == Fraction(1, 6)
    plan = mean_reward_plan(game, belief, 1, history[-1])
    assert robot[history] == plan.actions[(1, history[-1])] == game.robot_actions.index((0, 90))
    assert plan.values[(1, history[-1])] == 90 * (1 - theta_mean)  # R((0, 90); 1/6) = 75


def test_mean_reward_plan_refuses_a_phase_where_the_human_still_acts() -> None:
    game = office_supplies_grid_game(2)
    expert = demonstration_by_expert(game)
    root = game.roots[0]
    with pytest.raises(UserError, match="deployment phase only"):
        mean_reward_plan(game, posterior(game, expert, (root,)), 0, root)
