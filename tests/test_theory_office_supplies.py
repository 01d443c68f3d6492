"""The office-supplies example (paper section 3.3 and appendix) in exact arithmetic, its
command, and its discretised version under the generic solver."""

from __future__ import annotations

import json
from fractions import Fraction
from itertools import product

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from cirl_study.cli import app
from cirl_study.theory import (
    demonstration_by_expert,
    evaluate,
    human_best_response,
    office_supplies_results,
    robot_best_response,
    solve,
)
from cirl_study.theory import office_supplies as office
from cirl_study.theory.office_supplies_grid import office_supplies_grid_game, one_of_each_interval
from cirl_study.theory.threshold_rules import Piece, action_at, thresholds

F = Fraction
LOW, HIGH = F(41, 92), F(51, 92)
OPTIMUM = office.analyse().optimal_value


def _riemann(robot_map: tuple[int, ...], rule, n: int = 500) -> float:
    """Midpoint-rule integral of the pair's total reward, independent of the exact code."""
    total = 0.0
    for i in range(n):
        theta = (i + 0.5) / n
        human = office.HUMAN_ACTIONS[action_at(rule, F(2 * i + 1, 2 * n))]
        robot = office.ROBOT_ACTIONS[robot_map[action_at(rule, F(2 * i + 1, 2 * n))]]
        for p, q in (human, robot):
            total += theta * p + (1 - theta) * q
    return total / n


def test_expert_rule_and_its_best_response_are_the_papers() -> None:
    expert = office.expert_rule()
    assert expert == (
        Piece(F(0), F(1, 2), True, False, 0),
        Piece(F(1, 2), F(1, 2), True, True, 1),
        Piece(F(1, 2), F(1), False, True, 2),
    )
    # br(delta_E): (0,2) -> (0,90), (1,1) -> (50,50), (2,0) -> (90,0).
    assert office.robot_best_response(expert) == (0, 1, 2)
    assert office.acting_mean(expert, 0) == F(1, 4)
    assert office.acting_mean(expert, 1) == F(1, 2)  # probability 0: the prior's mean


def test_human_best_response_to_the_expert_response_splits_at_41_92_and_51_92() -> None:
    rule = office.human_best_response((0, 1, 2))
    assert thresholds(rule) == (LOW, HIGH)
    assert rule == (
        Piece(F(0), LOW, True, False, 0),
        Piece(LOW, HIGH, True, True, 1),
        Piece(HIGH, F(1), False, True, 2),
    )
    # The paper's choice: 0 + 92 staples, 51 of each, or 92 paperclips.
    assert [line(LOW) for line in office.joint_payoffs((0, 1, 2))][:2] == [51, 51]
    assert [line(HIGH) for line in office.joint_payoffs((0, 1, 2))][1:] == [51, 51]


def test_pair_values_match_the_closed_forms() -> None:
    analysis = office.analyse()
    # Expert pair: 2 * int_0^{1/2} 92 (1 - theta) d theta.
    assert analysis.values["expert"] == 2 * 92 * (F(1, 2) - F(1, 8)) == 69
    # Best-response pair: 92 (1 - theta) below 41/92, 51 in between, 92 theta above.
    below = 92 * (LOW - LOW**2 / 2)
    assert analysis.values["best_response"] == 2 * below + 51 * (HIGH - LOW) == F(6373, 92)
    assert analysis.values["optimal"] == F(6373, 92)
    assert analysis.optimal == [(analysis.best_response, (0, 1, 2))]


def test_every_robot_policy_with_the_humans_best_response_integrates_exactly() -> None:
    for robot_map in product(range(3), repeat=3):
        rule = office.human_best_response(robot_map)
        exact = office.pair_value(rule, robot_map)
        assert abs(float(exact) - _riemann(robot_map, rule)) < 1e-3
        # The envelope is pointwise best: no action beats it at any sampled theta.
        lines = office.joint_payoffs(robot_map)
        for k in range(0, 101):
            theta = F(k, 100)
            assert lines[action_at(rule, theta)](theta) == max(line(theta) for line in lines)


@settings(max_examples=60, deadline=None)
@given(
    cuts=st.lists(st.fractions(0, 1), min_size=0, max_size=3).map(sorted),
    actions=st.lists(st.integers(0, 2), min_size=4, max_size=4),
)
def test_no_threshold_rule_with_its_robot_best_response_beats_the_optimum(cuts, actions) -> None:
    points = [F(0), *cuts, F(1)]
    rule = tuple(
        Piece(lo, hi, True, hi == 1, actions[k])
        for k, (lo, hi) in enumerate(zip(points, points[1:], strict=False))
        if hi > lo or k == 0
    )
    response = office.robot_best_response(rule)
    assert office.pair_value(rule, response) <= OPTIMUM


def test_theorem_3_and_the_section_3_3_example() -> None:
    results = office_supplies_results()
    assert results["theorem_3"] == {
        "br_br_expert_equals_expert": False,
        "theta": "49/100",
        "expert_action": "(0, 2)",
        "best_response_action": "(1, 1)",
    }
    example = results["section_3_3"]
    assert example["belief"] == "Uniform[0, 1/3)"
    assert example["theta_acting"] == "1/6"
    assert example["robot_action"] == "(0, 90)"
    # Theorem 2 on the example: posterior expectations equal rewards at the mean.
    assert example["expected_rewards"] == example["rewards_at_mean"]
    assert example["expected_rewards"] == {"(0, 90)": "75", "(50, 50)": "50", "(90, 0)": "15"}


def test_results_are_plain_data_with_exact_fraction_strings() -> None:
    results = office_supplies_results()
    assert results["thresholds"] == ["41/92", "51/92"]
    assert results["values"] == {"expert": "69", "best_response": "6373/92", "optimal": "6373/92"}
    assert results["optimal_search"] == {
        "robot_policies": 27,
        "optimal_pairs": 1,
        "best_response_pair_is_optimal": True,
    }
    assert results["pairs"]["expert"]["robot_policy"]["(1, 1)"]["belief"].startswith("prior")
    assert json.loads(json.dumps(results)) == results


def test_command_prints_json_and_a_readable_table() -> None:
    runner = CliRunner()
    as_json = runner.invoke(app, ["office-supplies", "--json"])
    assert as_json.exit_code == 0
    assert json.loads(as_json.stdout) == office_supplies_results()
    table = runner.invoke(app, ["office-supplies"])
    assert table.exit_code == 0
    for text in ("[41/92, 51/92]", "6373/92", "69.2717", "theta = 1/6", "Theorem 3"):
        assert text in table.stdout
    wrong = runner.invoke(app, ["office-supplies", "--grid"])
    assert wrong.exit_code != 0


@pytest.mark.parametrize("n", [10, 46, 150, 400])
def test_discretised_thresholds_converge_to_41_92_and_51_92(n: int) -> None:
    game = office_supplies_grid_game(n)
    expert = demonstration_by_expert(game)
    robot = robot_best_response(game, expert)
    # br(delta_E) on the grid is the paper's: (0,2) -> (0,90), (1,1) -> (50,50), (2,0) -> (90,0).
    after = {game.human_actions[h[1]]: game.robot_actions[robot[h]] for h in robot if len(h) == 4}
    assert after == dict(zip(office.HUMAN_ACTIONS, office.ROBOT_ACTIONS, strict=True))
    human = human_best_response(game, robot)
    interval = one_of_each_interval(game, human)
    assert interval is not None
    low, high = interval
    # The grid point nearest each threshold from inside (ties go to (0, 2) at 41/92).
    assert LOW < low <= LOW + F(1, n)
    assert HIGH - F(1, n) < high <= HIGH
    # The midpoint rule is exact where the integrand is linear; each kink (slope change
    # at most 92 here, 184 for the expert at 1/2) costs at most slope change * (1/n)^2 / 8.
    assert abs(evaluate(game, human, robot) - F(6373, 92)) <= F(2 * 92, 8 * n * n)
    assert abs(evaluate(game, expert, robot) - 69) <= F(184, 8 * n * n)


@pytest.mark.parametrize("n", [2, 3, 5, 6])
def test_grid_solver_equals_the_threshold_search_on_the_grid(n: int) -> None:
    """On the grid, too, the optimum is the best robot map with the human's best response."""
    game = office_supplies_grid_game(n)
    root = (game.roots[0],)
    wait = game.robot_actions.index("wait")
    best = None
    for robot_map in product(range(3), repeat=3):
        robot = {root: wait}
        for h in game.children(root):
            robot[h] = game.robot_actions.index(office.ROBOT_ACTIONS[robot_map[h[1]]])
        value = evaluate(game, human_best_response(game, robot), robot)
        best = value if best is None else max(best, value)
    assert solve(game).value == best
