"""CIRL games as data: pose a small game, reduce it, and solve it exactly.

* :mod:`~cirl_study.games.game` — the game ``M`` (paper Definition 1);
  :mod:`~cirl_study.games.apprenticeship` — its turn-based ACIRL form.
* :mod:`~cirl_study.games.coordination_pomdp` — the coordination POMDP (Theorem 1).
* :mod:`~cirl_study.games.solver` — exact optimal policy pairs;
  :mod:`~cirl_study.games.best_response` — the best-response operators;
  :mod:`~cirl_study.games.deployment` — Theorem 2 (act on the mean reward);
  :mod:`~cirl_study.games.brute_force` — the exhaustive reference.
* :mod:`~cirl_study.games.office_supplies` — the paper's example in exact arithmetic
  (Theorem 3); :mod:`~cirl_study.games.office_supplies_grid` — the same game on a grid of thetas.
"""

from cirl_study.games.apprenticeship import END, WAIT, apprenticeship_game
from cirl_study.games.beliefs import posterior
from cirl_study.games.best_response import human_best_response, robot_best_response
from cirl_study.games.brute_force import brute_force_optimum
from cirl_study.games.coordination_pomdp import (
    coordination_pomdp,
    coordinator_policy,
    policy_pair,
)
from cirl_study.games.deployment import mean_reward_plan
from cirl_study.games.game import CIRLGame, make_game
from cirl_study.games.office_supplies import office_supplies_results
from cirl_study.games.policies import demonstration_by_expert, describe_pair, evaluate
from cirl_study.games.solver import Solution, solve

__all__ = [
    "END",
    "WAIT",
    "CIRLGame",
    "Solution",
    "apprenticeship_game",
    "brute_force_optimum",
    "coordination_pomdp",
    "coordinator_policy",
    "demonstration_by_expert",
    "describe_pair",
    "evaluate",
    "human_best_response",
    "make_game",
    "mean_reward_plan",
    "office_supplies_results",
    "policy_pair",
    "posterior",
    "robot_best_response",
    "solve",
]
