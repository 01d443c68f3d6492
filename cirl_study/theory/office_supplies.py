"""The office-supplies ACIRL game of paper section 3.3 and its appendix, solved exactly.

``H`` makes one of ``A_H = {(0,2), (1,1), (2,0)}`` (paperclips, staples) at
``t = 0``; ``R`` watches, then makes one of ``A_R = {(0,90), (50,50), (90,0)}`` at
``t = 1``. ``theta ~ Uniform[0, 1]`` and an action ``(p, q)`` earns
``theta p + (1 - theta) q = q + (p - q) theta``; ``gamma = 1``.

``H`` acts once, so her policy is a decision rule ``delta: [0, 1] -> A_H``; ``R``
sees one action, so its policy is a map ``pi_R: A_H -> A_R``. The value of a pair is

    V(delta, pi_R) = int_0^1 [r(delta(theta); theta) + r(pi_R(delta(theta)); theta)] d theta.

* ``br(pi_R)`` maximises the integrand pointwise: the upper envelope of the three
  lines ``r(a; theta) + r(pi_R(a); theta)``, a threshold rule.
* ``br(delta)``: after seeing ``a``, ``R``'s posterior is the prior restricted to
  ``delta^{-1}(a)``; by Theorem 2 and linearity it takes the action best for the
  posterior mean. An action ``delta`` never takes (probability zero) leaves the
  belief at the prior, mean 1/2 (for ``delta^E``'s ``(1,1)`` at ``theta = 1/2`` the
  paper's point-mass posterior gives the same mean).
* The optimal pair: for any ``(delta, pi_R)``, ``V(delta, pi_R) <= V(br(pi_R), pi_R)``,
  so ``max V = max over the 27 maps pi_R of V(br(pi_R), pi_R)`` — an exact search
  over every threshold structure an optimal rule can have.

Ties on measure-zero sets: ``H`` prefers ``(1,1)``, then ``(0,2)``, then ``(2,0)``
(this reproduces the paper's ``delta^E(1/2) = (1,1)`` and the closed interval
``[41/92, 51/92]``); ``R`` prefers its actions in the order listed.
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction
from itertools import product
from typing import Any

from cirl_study.theory.threshold_rules import (
    Line,
    Piece,
    Rule,
    action_at,
    expected_payoff,
    posterior_mean,
    preimage,
    thresholds,
    upper_envelope,
)

HUMAN_ACTIONS: tuple[tuple[int, int], ...] = ((0, 2), (1, 1), (2, 0))
ROBOT_ACTIONS: tuple[tuple[int, int], ...] = ((0, 90), (50, 50), (90, 0))
HUMAN_TIE_PRIORITY: tuple[int, ...] = (1, 0, 2)
PRIOR_MEAN = Fraction(1, 2)

RobotMap = tuple[int, ...]
"""``pi_R`` as ``robot_map[a_H] = a_R`` (indices)."""


def production_reward(action: tuple[int, int]) -> Line:
    """``r((p, q); theta) = theta p + (1 - theta) q`` as a line in ``theta``."""
    paperclips, staples = action
    return Line(Fraction(staples), Fraction(paperclips - staples))


def expert_rule() -> Rule:
    """``delta^E``: ``H`` maximises her immediate reward ``r(a_H; theta)``."""
    return upper_envelope([production_reward(a) for a in HUMAN_ACTIONS], HUMAN_TIE_PRIORITY)


def robot_action_for_mean(theta_mean: Fraction) -> int:
    """``argmax_{a_R} r(a_R; theta_mean)``, the first action on ties (Theorem 2)."""
    return max(
        range(len(ROBOT_ACTIONS)),
        key=lambda a: (production_reward(ROBOT_ACTIONS[a])(theta_mean), -a),
    )


def acting_mean(rule: Rule, a_h: int) -> Fraction:
    """The mean of ``R``'s belief after seeing ``a_h`` under ``rule``."""
    theta_mean = posterior_mean(rule, a_h)
    return PRIOR_MEAN if theta_mean is None else theta_mean


def posterior_expectation(rule: Rule, a_h: int, payoff: Line) -> Fraction:
    """``E[payoff(theta) | delta(theta) = a_h]`` by integration over the posterior (the
    observed action must have positive probability)."""
    pieces = preimage(rule, a_h)
    mass = sum((piece.length for piece in pieces), start=Fraction(0))
    return sum((payoff.integral(p.lo, p.hi) for p in pieces), start=Fraction(0)) / mass


def robot_best_response(rule: Rule) -> RobotMap:
    """``br(delta)``: after each ``a_H``, the action best for the posterior mean."""
    return tuple(robot_action_for_mean(acting_mean(rule, a)) for a in range(len(HUMAN_ACTIONS)))


def joint_payoffs(robot_map: RobotMap) -> list[Line]:
    """``r(a_H; theta) + r(pi_R(a_H); theta)`` for each ``a_H``."""
    return [
        production_reward(a) + production_reward(ROBOT_ACTIONS[robot_map[k]])
        for k, a in enumerate(HUMAN_ACTIONS)
    ]


def human_best_response(robot_map: RobotMap) -> Rule:
    """``br(pi_R)``: the upper envelope of the joint payoff lines."""
    return upper_envelope(joint_payoffs(robot_map), HUMAN_TIE_PRIORITY)


def pair_value(rule: Rule, robot_map: RobotMap) -> Fraction:
    """``V(delta, pi_R)`` exactly."""
    return expected_payoff(rule, joint_payoffs(robot_map))


def optimal_pairs() -> tuple[Fraction, list[tuple[Rule, RobotMap]]]:
    """The optimal value and every ``(br(pi_R), pi_R)`` attaining it (see module docstring)."""
    scored = []
    for robot_map in product(range(len(ROBOT_ACTIONS)), repeat=len(HUMAN_ACTIONS)):
        rule = human_best_response(robot_map)
        scored.append((pair_value(rule, robot_map), rule, robot_map))
    best = max(value for value, _, _ in scored)
    return best, [(rule, robot_map) for value, rule, robot_map in scored if value == best]


def section_3_3_rule() -> Rule:
    """The paper's illustration: ``(0,2)`` on ``[0, 1/3)``, ``(1,1)`` on ``[1/3, 2/3]``,
    ``(2,0)`` on ``(2/3, 1]``."""
    third, two_thirds = Fraction(1, 3), Fraction(2, 3)
    return (
        Piece(Fraction(0), third, True, False, 0),
        Piece(third, two_thirds, True, True, 1),
        Piece(two_thirds, Fraction(1), False, True, 2),
    )


@dataclass(frozen=True)
class OfficeSuppliesAnalysis:
    """Every exact quantity of the example (see :func:`analyse`)."""

    expert: Rule
    expert_response: RobotMap
    best_response: Rule
    optimal_value: Fraction
    optimal: list[tuple[Rule, RobotMap]]
    values: dict[str, Fraction]


def analyse() -> OfficeSuppliesAnalysis:
    """``delta^E``, ``br(delta^E)``, ``br(br(delta^E))``, the optimal pairs and the values of
    the pairs "expert" ``(delta^E, br(delta^E))``, "best_response"
    ``(br(br(delta^E)), br(delta^E))`` and "optimal"."""
    expert = expert_rule()
    response = robot_best_response(expert)
    best_response = human_best_response(response)
    optimal_value, optimal = optimal_pairs()
    return OfficeSuppliesAnalysis(
        expert=expert,
        expert_response=response,
        best_response=best_response,
        optimal_value=optimal_value,
        optimal=optimal,
        values={
            "expert": pair_value(expert, response),
            "best_response": pair_value(best_response, response),
            "optimal": optimal_value,
        },
    )


def _action(action: tuple[int, int]) -> str:
    return f"({action[0]}, {action[1]})"


def _rule_dict(rule: Rule) -> list[dict[str, str]]:
    return [{"theta": str(piece), "action": _action(HUMAN_ACTIONS[piece.action])} for piece in rule]


def _robot_dict(rule: Rule, robot_map: RobotMap) -> dict[str, dict[str, str]]:
    """For each human action: the robot's belief, its mean, and the robot's action."""
    described = {}
    for a_h, a_r in enumerate(robot_map):
        pieces = preimage(rule, a_h)
        support = " U ".join(str(p) for p in pieces if p.length > 0)
        described[_action(HUMAN_ACTIONS[a_h])] = {
            "belief": f"Uniform{support}" if support else "prior (action has probability 0)",
            "mean_theta": str(acting_mean(rule, a_h)),
            "robot_action": _action(ROBOT_ACTIONS[a_r]),
        }
    return described


def _pair_dict(rule: Rule, robot_map: RobotMap, value: Fraction) -> dict[str, Any]:
    return {
        "human_rule": _rule_dict(rule),
        "robot_policy": _robot_dict(rule, robot_map),
        "value": str(value),
    }


def office_supplies_results() -> dict[str, Any]:
    """The whole example as plain data, every number an exact fraction string.

    Keys: ``thresholds`` (of ``br(br(delta^E))``), ``values`` (expert, best_response,
    optimal), ``pairs`` (each pair's human rule, robot policy with beliefs, value),
    ``optimal_is_best_response_pair``, ``theorem_3`` (``br(br(delta^E)) != delta^E``,
    witnessed at ``theta = 0.49``) and ``section_3_3`` (the 1/3, 2/3 rule: after
    ``(0, 2)`` the robot acts as if ``theta = 1/6``).
    """
    analysis = analyse()
    values = analysis.values
    optimal_rule, optimal_map = analysis.optimal[0]
    witness = Fraction(49, 100)
    example = section_3_3_rule()
    observed = 0
    theta_acting = acting_mean(example, observed)
    chosen = robot_action_for_mean(theta_acting)
    return {
        "game": {
            "human_actions": [_action(a) for a in HUMAN_ACTIONS],
            "robot_actions": [_action(a) for a in ROBOT_ACTIONS],
            "reward": "theta * paperclips + (1 - theta) * staples",
            "prior": "Uniform[0, 1]",
            "gamma": "1",
        },
        "thresholds": [str(t) for t in thresholds(analysis.best_response)],
        "values": {name: str(value) for name, value in values.items()},
        "pairs": {
            "expert": _pair_dict(analysis.expert, analysis.expert_response, values["expert"]),
            "best_response": _pair_dict(
                analysis.best_response, analysis.expert_response, values["best_response"]
            ),
            "optimal": _pair_dict(optimal_rule, optimal_map, values["optimal"]),
        },
        "optimal_search": {
            "robot_policies": len(ROBOT_ACTIONS) ** len(HUMAN_ACTIONS),
            "optimal_pairs": len(analysis.optimal),
            "best_response_pair_is_optimal": (analysis.best_response, analysis.expert_response)
            in analysis.optimal,
        },
        "theorem_3": {
            "br_br_expert_equals_expert": analysis.best_response == analysis.expert,
            "theta": str(witness),
            "expert_action": _action(HUMAN_ACTIONS[action_at(analysis.expert, witness)]),
            "best_response_action": _action(
                HUMAN_ACTIONS[action_at(analysis.best_response, witness)]
            ),
        },
        "section_3_3": {
            "human_rule": _rule_dict(example),
            "observed": _action(HUMAN_ACTIONS[observed]),
            "belief": f"Uniform{preimage(example, observed)[0]}",
            "theta_acting": str(theta_acting),
            "expected_rewards": {
                _action(a): str(posterior_expectation(example, observed, production_reward(a)))
                for a in ROBOT_ACTIONS
            },
            "rewards_at_mean": {
                _action(a): str(production_reward(a)(theta_acting)) for a in ROBOT_ACTIONS
            },
            "robot_action": _action(ROBOT_ACTIONS[chosen]),
        },
    }
