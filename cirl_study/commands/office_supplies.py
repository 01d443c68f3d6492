"""``cirl-study office-supplies``: the paper's office-supplies example, solved exactly."""

from __future__ import annotations

import json
from typing import Annotated

import typer

from cirl_study.commands.parameters import Command

app = typer.Typer(rich_markup_mode=None)
"""The ``office-supplies`` command, merged into :data:`cirl_study.cli.app`."""


@app.command("office-supplies", cls=Command)
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
    # The exact solver and the tables (rich) load only when the command runs.
    from rich.console import Console

    from cirl_study.commands.office_supplies_tables import (
        example_table,
        robot_table,
        rules_table,
        values_table,
    )
    from cirl_study.theory.office_supplies import office_supplies_results

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
    console.print(rules_table(results))
    console.print(robot_table(results))
    console.print(values_table(results))
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
    console.print(example_table(results["section_3_3"]))
