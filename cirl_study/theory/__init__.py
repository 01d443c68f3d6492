"""CIRL games as data: pose a small game, reduce it, and solve it exactly.

* :mod:`~cirl_study.theory.game` — the game ``M`` (paper Definition 1);
  :mod:`~cirl_study.theory.apprenticeship` — its turn-based ACIRL form.
* :mod:`~cirl_study.theory.coordination_pomdp` — the coordination POMDP (Theorem 1).
* :mod:`~cirl_study.theory.solver` — exact optimal policy pairs;
  :mod:`~cirl_study.theory.operators` — the best-response operators;
  :mod:`~cirl_study.theory.mean_reward` — Theorem 2 (act on the mean reward);
  :mod:`~cirl_study.theory.exhaustive` — the exhaustive reference.
* :mod:`~cirl_study.theory.office_supplies` — the paper's example in exact arithmetic
  (Theorem 3); :mod:`~cirl_study.theory.office_supplies_grid` — the same game on a grid of thetas.
"""

from cirl_study.theory.apprenticeship import END, WAIT, apprenticeship_game
from cirl_study.theory.beliefs import posterior
from cirl_study.theory.coordination_pomdp import (
    coordination_pomdp,
    coordinator_policy,
    policy_pair,
)
from cirl_study.theory.exhaustive import exhaustive_optimum
from cirl_study.theory.game import CIRLGame, make_game
from cirl_study.theory.mean_reward import mean_reward_plan
from cirl_study.theory.office_supplies import office_supplies_results
from cirl_study.theory.operators import human_best_response, robot_best_response
from cirl_study.theory.policies import demonstration_by_expert, describe_pair, evaluate
from cirl_study.theory.solver import Solution, solve

__all__ = [
    "END",
    "WAIT",
    "CIRLGame",
    "Solution",
    "apprenticeship_game",
    "coordination_pomdp",
    "coordinator_policy",
    "demonstration_by_expert",
    "describe_pair",
    "evaluate",
    "exhaustive_optimum",
    "human_best_response",
    "make_game",
    "mean_reward_plan",
    "office_supplies_results",
    "policy_pair",
    "posterior",
    "robot_best_response",
    "solve",
]
