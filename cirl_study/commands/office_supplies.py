"""``cirl-study office-supplies``: the paper's office-supplies example, solved exactly."""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from cirl_study.theory.office_supplies import office_supplies_results

app = typer.Typer(rich_markup_mode=None)
"""The ``office-supplies`` command, merged into :data:`cirl_study.cli.app`."""

_PAIRS = {
    "expert": ("delta_E", "br(delta_E)"),
    "best_response": ("br(br(delta_E))", "br(delta_E)"),
    "optimal": ("optimal H", "optimal R"),
}


def _values_table(results: dict[str, Any]) -> Table:
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


def _rules_table(results: dict[str, Any]) -> Table:
    def thetas(key: str, action: str) -> str:
        pieces = results["pairs"][key]["human_rule"]
        return " U ".join(p["theta"] for p in pieces if p["action"] == action) or "-"

    return _per_action_table(
        results, "Human decision rules: the thetas where H makes each action", "rule", thetas
    )


def _robot_table(results: dict[str, Any]) -> Table:
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


def _example_table(example: dict[str, Any]) -> Table:
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


@app.command("office-supplies")
def office_supplies(
    as_json: Annotated[
        bool, typer.Option("--json", help="Print the results as JSON (exact fractions as strings).")
    ] = False,
) -> None:
    """Solve the office-supplies game of the paper (section 3.3 and appendix) exactly.

    Shows delta_E, br(delta_E) and br(br(delta_E)) (thresholds 41/92 and 51/92), the
    expected value of the expert, best-response and optimal pairs, and the section 3.3
    example where the robot acts as if theta = 1/6.
    """
    results = office_supplies_results()
    if as_json:
        typer.echo(json.dumps(results, indent=2))
        return
    game = results["game"]
    typer.echo("Office supplies (paper section 3.3 and appendix)")
    typer.echo(
        f"H makes (p, q) in {{{', '.join(game['human_actions'])}}}, "
        f"then R in {{{', '.join(game['robot_actions'])}}}"
    )
    typer.echo(f"reward {game['reward']}, theta ~ {game['prior']}, gamma = {game['gamma']}")
    console = Console(markup=False, highlight=False)
    console.print(_rules_table(results))
    console.print(_robot_table(results))
    console.print(_values_table(results))
    low, high = results["thresholds"]
    theorem = results["theorem_3"]
    typer.echo(
        f"br(br(delta_E)) makes (1, 1) for theta in [{low}, {high}], delta_E only at 1/2,\n"
        f"so br(br(delta_E)) != delta_E (Theorem 3): at theta = {theorem['theta']} "
        f"the expert makes {theorem['expert_action']},\n"
        f"the best response {theorem['best_response_action']}."
    )
    search = results["optimal_search"]
    optimal = "is" if search["best_response_pair_is_optimal"] else "is not"
    typer.echo(
        f"The best-response pair {optimal} the optimal pair (exhaustive search over\n"
        f"{search['robot_policies']} robot policies, each with the human's best response; "
        f"optimal pairs found: {search['optimal_pairs']})."
    )
    console.print(_example_table(results["section_3_3"]))
