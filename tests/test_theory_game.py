"""CIRL games as data: construction, validation, histories and the apprenticeship form."""

from __future__ import annotations

from fractions import Fraction

import pytest

from cirl_study.errors import UserError
from cirl_study.theory import END, WAIT, CIRLGame, apprenticeship_game, make_game
from cirl_study.theory.office_supplies_grid import office_supplies_grid_game, theta_grid
from cirl_study.theory.random_game import random_game


def _simple(**changes: object):
    arguments = dict(
        states=("a", "b"),
        human_actions=("x", "y"),
        robot_actions=("u",),
        thetas=(0, 1),
        transition=lambda s, a_h, a_r: {"b": 1} if a_h == "x" else {"a": 1},
        reward=lambda s, a_h, a_r, theta: theta,
        initial={("a", 0): Fraction(1, 4), ("a", 1): Fraction(3, 4)},
        horizon=2,
    )
    arguments.update(changes)
    return make_game(**arguments)


def test_make_game_stores_tables_by_index_and_integers_as_fractions() -> None:
    game = _simple()
    assert game.transition[(0, 0, 0)] == ((1, Fraction(1)),)
    assert game.reward[(1, 1, 0)] == (Fraction(0), Fraction(1))
    assert all(isinstance(r, Fraction) for r in game.reward[(0, 0, 0)])
    assert game.initial == ((Fraction(1, 4), Fraction(3, 4)), (Fraction(0), Fraction(0)))
    assert game.roots == (0,)
    assert game.gamma == 1 and isinstance(game.gamma, Fraction)


def test_histories_are_every_reachable_common_history_up_to_the_last_round() -> None:
    game = _simple(horizon=3)
    # Round 0: (a,). Round 1: both human actions, each with one successor. Round 2: 2 * 2.
    assert len(game.histories()) == 1 + 2 + 4
    assert (0, 0, 0, 1, 1, 0, 0) in game.histories()
    assert all(len(h) in (1, 4, 7) for h in game.histories())


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"transition": lambda s, a_h, a_r: {"a": Fraction(1, 2)}}, "probability distribution"),
        ({"transition": lambda s, a_h, a_r: {"nowhere": 1}}, "unknown state 'nowhere'"),
        ({"initial": {("a", 0): Fraction(1, 2)}}, "P0 must be a probability distribution"),
        ({"initial": {("a", 7): 1}}, "unknown theta 7"),
        ({"horizon": 0}, "horizon must be at least 1"),
        ({"gamma": Fraction(3, 2)}, "gamma must lie in [0, 1]"),
        ({"reward": lambda s, a_h, a_r, theta: "big"}, "must be a number"),
        ({"reward": lambda s, a_h, a_r, theta: float("nan")}, "must be finite"),
        ({"thetas": (0, 0)}, "repeated labels"),
        ({"human_available": lambda s: ()}, "without actions"),
        ({"robot_available": lambda s: ("z",)}, "unknown robot action 'z'"),
    ],
)
def test_malformed_games_are_user_errors(changes: dict, message: str) -> None:
    with pytest.raises(UserError, match=message.replace("[", r"\[").replace("]", r"\]")):
        _simple(**changes)


def test_float_probabilities_are_accepted_to_a_tolerance() -> None:
    game = _simple(
        transition=lambda s, a_h, a_r: {"a": 0.1 + 0.2, "b": 0.7},
        initial={("a", 0): 0.5, ("b", 1): 0.5},
    )
    assert game.roots == (0, 1)


def test_apprenticeship_game_alternates_turns_with_a_single_ignored_wait_action() -> None:
    game = apprenticeship_game(
        initial_state=0,
        human_actions=(1, 2),
        robot_actions=(10,),
        step=lambda world, action: world + action,
        reward=lambda world, action, theta: action * theta,
        thetas=(1, -1),
        prior=(Fraction(1, 2), Fraction(1, 2)),
        learning_steps=2,
        deployment_steps=1,
    )
    assert game.states == ((0, 0), (1, 1), (2, 1), (2, 2), (3, 2), (4, 2), END)
    assert game.human_actions == (1, 2, WAIT) and game.robot_actions == (10, WAIT)
    wait_h, wait_r = 2, 1
    for s, (_, t) in enumerate(game.states[:-1]):
        if t < 2:
            assert game.human_available[s] == (0, 1) and game.robot_available[s] == (wait_r,)
        else:
            assert game.human_available[s] == (wait_h,) and game.robot_available[s] == (0,)
    # Learning: the human's action moves the world and pays action * theta.
    assert game.transition[(1, 1, wait_r)] == ((4, 1),)
    assert game.reward[(1, 1, wait_r)] == (2, -2)
    # Deployment: the robot's action pays; the last round leads to the sink.
    assert game.reward[(5, wait_h, 0)] == (10, -10)
    assert game.transition[(5, wait_h, 0)] == ((6, 1),)
    assert game.horizon == 3 and game.initial[0] == (Fraction(1, 2), Fraction(1, 2))


def test_apprenticeship_game_rejects_reserved_labels_and_a_mismatched_prior() -> None:
    common = dict(
        initial_state=0,
        step=lambda world, action: world,
        reward=lambda world, action, theta: 0,
        thetas=(0, 1),
        learning_steps=1,
        deployment_steps=1,
    )
    with pytest.raises(UserError, match="reserved"):
        apprenticeship_game(human_actions=(WAIT,), robot_actions=(1,), prior=(1, 0), **common)
    with pytest.raises(UserError, match="one probability per theta"):
        apprenticeship_game(human_actions=(1,), robot_actions=(1,), prior=(1,), **common)


def test_office_supplies_grid_game_matches_the_paper() -> None:
    game = office_supplies_grid_game(4)
    assert theta_grid(4) == (Fraction(1, 8), Fraction(3, 8), Fraction(5, 8), Fraction(7, 8))
    assert game.thetas == theta_grid(4) and game.horizon == 2
    assert game.states[0] == ((0, 0), 0) and len(game.states) == 1 + 3 + 1
    root = game.states.index(((0, 0), 0))
    one_of_each = game.human_actions.index((1, 1))
    wait = game.robot_actions.index(WAIT)
    # theta * p + (1 - theta) * q for the human's (1, 1): 1 whatever theta.
    assert game.reward[(root, one_of_each, wait)] == (1, 1, 1, 1)
    after = game.states.index(((1, 1), 1))
    fifty = game.robot_actions.index((50, 50))
    assert game.reward[(after, game.human_actions.index(WAIT), fifty)] == (50,) * 4
    with pytest.raises(UserError, match="at least one point"):
        theta_grid(0)


def test_random_games_are_reproducible_and_valid() -> None:
    first, second = random_game(3, thetas=3), random_game(3, thetas=3)
    assert first.transition == second.transition and first.reward == second.reward
    assert first.initial == second.initial
    assert len(first.thetas) == 3


def test_a_game_built_from_raw_tables_checks_its_available_actions() -> None:
    game = _simple()
    with pytest.raises(UserError, match="one set per state"):
        CIRLGame(
            states=game.states,
            human_actions=game.human_actions,
            robot_actions=game.robot_actions,
            thetas=game.thetas,
            human_available=((0, 5), (0, 1)),
            robot_available=game.robot_available,
            transition=game.transition,
            reward=game.reward,
            initial=game.initial,
            gamma=game.gamma,
            horizon=game.horizon,
        )
