"""The office-supplies results (:func:`~cirl_study.theory.office_supplies.office_supplies_results`)
as the tables ``cirl-study office-supplies`` prints (rich)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rich.table import Table

_PAIRS = {
    "expert": ("delta_E", "br(delta_E)"),
    "best_response": ("br(br(delta_E))", "br(delta_E)"),
    "optimal": ("optimal H", "optimal R"),
}


def values_table(results: dict[str, Any]) -> Table:
    """The expected total reward of the expert, best-response and optimal pairs, exact and
    in decimals."""
    table = Table(title="Expected total reward of each pair")
    for column in ("pair", "human", "robot"):
        table.add_column(column)
    table.add_column("exact", justify="right")
    table.add_column("decimal", justify="right")
    for key, (human, robot) in _PAIRS.items():
        value = results["values"][key]
        table.add_row(key, human, robot, value, f"{_decimal(value)}")
    return table


def _per_action_table(
    results: dict[str, Any], title: str, first: str, cell: Callable[[str, str], str]
) -> Table:
    """One row per pair of :data:`_PAIRS` (named by its human), one column per human action."""
    actions = results["game"]["human_actions"]
    table = Table(title=title)
    table.add_column(first)
    for action in actions:
        table.add_column(action)
    for key, (human, _) in _PAIRS.items():
        table.add_row(human, *(cell(key, action) for action in actions))
    return table


def rules_table(results: dict[str, Any]) -> Table:
    """Each pair's human decision rule: the thetas at which H makes each action."""

    def thetas(key: str, action: str) -> str:
        pieces = results["pairs"][key]["human_rule"]
        return " U ".join(p["theta"] for p in pieces if p["action"] == action) or "-"

    return _per_action_table(
        results, "Human decision rules: the thetas where H makes each action", "rule", thetas
    )


def robot_table(results: dict[str, Any]) -> Table:
    """Each pair's robot policy: after each human action, R's mean theta and what R makes."""

    def response(key: str, action: str) -> str:
        return _robot_cell(results["pairs"][key]["robot_policy"][action])

    table = _per_action_table(
        results,
        "Robot policies: after H's action, R's mean theta -> what R makes",
        "against",
        response,
    )
    table.caption = "* H never makes this action, so R's belief stays at the prior"
    return table


def _robot_cell(response: dict[str, str]) -> str:
    mark = "*" if response["belief"].startswith("prior") else ""
    return f"{response['mean_theta']}{mark} -> {response['robot_action']}"


def example_table(example: dict[str, Any]) -> Table:
    """Section 3.3's example: R's expected reward of each action after H's observed one."""
    table = Table(
        title=f"Section 3.3: after H makes {example['observed']}",
        caption=f"R's belief is {example['belief']}; it acts as if theta = "
        f"{example['theta_acting']}",
    )
    table.add_column("robot makes")
    table.add_column("E_belief[reward]", justify="right")
    table.add_column(f"reward at theta = {example['theta_acting']}", justify="right")
    for action, expected in example["expected_rewards"].items():
        chosen = " (chosen)" if action == example["robot_action"] else ""
        table.add_row(action + chosen, expected, example["rewards_at_mean"][action])
    return table


def _decimal(fraction: str) -> str:
    numerator, _, denominator = fraction.partition("/")
    return f"{int(numerator) / int(denominator or 1):.4f}"
