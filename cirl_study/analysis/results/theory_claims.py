"""The paper's theory claims (section 3, office-supplies example) as report rows.

Each row's verdict is computed from the exact results of
:func:`cirl_study.theory.office_supplies_results` (fractions compared exactly), never
written by hand; those results are plain data (every number an exact fraction string), read
here as the typed :class:`OfficeSupplies` (the parts the claims read). The rows have the shape
:func:`cirl_study.analysis.results.claims.external_claims` expects, each of ``kind`` ``"theory"``
(exact, independent of any run):

1. ``office_supplies_thresholds``: in the optimal equilibrium the human makes (1, 1)
   exactly when theta is in [41/92, 51/92] (appendix; section 3.3).
2. ``theorem_3``: br(br(delta_E)) differs from delta_E; at theta = 0.49 the expert makes
   (0, 2) while the best response makes (1, 1).
3. ``section_3_3_mean_theta``: with the 1/3, 2/3 rule and a uniform prior, after (0, 2)
   the robot acts as if theta = 1/6 (Theorem 2).
4. ``expert_not_optimal``: the expert pair (delta_E, br(delta_E)) has a strictly lower
   value than the optimal pair.
"""

from __future__ import annotations

from fractions import Fraction
from typing import Any

import msgspec

SOURCE_EXAMPLE = "paper, section 3.3 and appendix (office supplies)"


class _Exact(msgspec.Struct, frozen=True, kw_only=True):
    """Part of the exact office-supplies results. One a claim stores whole as its values
    (:class:`Values`, :class:`Theorem3`, :class:`Section33`) declares every field the results
    give it, in their order; the others declare what the claims read."""


class RulePiece(_Exact):
    """One piece of a threshold rule: on the interval ``theta``, the human makes ``action``."""

    theta: str
    action: str


class Pair(_Exact):
    """A policy pair of the results (only its human rule is read)."""

    human_rule: list[RulePiece]


class Pairs(_Exact):
    """The policy pairs of the results (only the optimal one is read)."""

    optimal: Pair


class Values(_Exact):
    """The value of each policy pair, an exact fraction."""

    expert: str
    best_response: str
    optimal: str


class Theorem3(_Exact):
    """``br(br(delta^E)) != delta^E``, witnessed at ``theta``: each human's action there."""

    br_br_expert_equals_expert: bool
    theta: str
    expert_action: str
    best_response_action: str


class Section33(_Exact):
    """The 1/3, 2/3 rule of section 3.3: after ``observed`` the robot's belief, the theta it
    acts as if, its expected rewards under the belief and the rewards at that theta."""

    human_rule: list[RulePiece]
    observed: str
    belief: str
    theta_acting: str
    expected_rewards: dict[str, str]
    rewards_at_mean: dict[str, str]
    robot_action: str


class OfficeSupplies(_Exact):
    """The exact office-supplies results (:func:`cirl_study.theory.office_supplies_results`)
    the claims read."""

    thresholds: list[str]
    values: Values
    pairs: Pairs
    theorem_3: Theorem3
    section_3_3: Section33


def _interval(rule: list[RulePiece], action: str) -> str | None:
    """The theta interval on which a threshold rule takes ``action``."""
    return next((piece.theta for piece in rule if piece.action == action), None)


def office_supplies_claims(results: dict[str, Any]) -> dict[str, list[dict[str, Any]]]:
    """Claim rows, with verdicts, from the exact office-supplies results (as
    :func:`cirl_study.theory.office_supplies_results` returns them)."""
    exact = msgspec.convert(results, OfficeSupplies)
    optimal_interval = _interval(exact.pairs.optimal.human_rule, "(1, 1)")
    theorem, example, values = exact.theorem_3, exact.section_3_3, exact.values
    evidence = ["results.json"]  # the exact results are stored under "theory" in results.json
    claims = [
        {
            "id": "office_supplies_thresholds",
            "kind": "theory",
            "source": SOURCE_EXAMPLE,
            "claim": "In the optimal equilibrium the human selects (1, 1) iff theta is in "
            "[41/92, 51/92].",
            "rule": "the optimal pair's human rule makes (1, 1) exactly on [41/92, 51/92], "
            "compared as exact fractions",
            "measurement": f"optimal pair makes (1, 1) on {optimal_interval}; thresholds "
            f"{', '.join(exact.thresholds)}",
            "reproduced": optimal_interval == "[41/92, 51/92]"
            and [Fraction(t) for t in exact.thresholds] == [Fraction(41, 92), Fraction(51, 92)],
            "values": {"interval": optimal_interval, "thresholds": exact.thresholds},
            "evidence": evidence,
        },
        {
            "id": "theorem_3",
            "kind": "theory",
            "source": "paper, Theorem 3",
            "claim": "br(br(delta_E)) != delta_E: at theta = 0.49 the best response makes "
            "(1, 1) where the expert makes (0, 2).",
            "rule": "br(br(delta_E)) differs from delta_E, and at theta = 49/100 the expert "
            "and best-response actions are (0, 2) and (1, 1)",
            "measurement": f"at theta = {theorem.theta}: expert {theorem.expert_action}, "
            f"best response {theorem.best_response_action}",
            "reproduced": not theorem.br_br_expert_equals_expert
            and Fraction(theorem.theta) == Fraction(49, 100)
            and theorem.expert_action == "(0, 2)"
            and theorem.best_response_action == "(1, 1)",
            "values": msgspec.to_builtins(theorem),
            "evidence": evidence,
        },
        {
            "id": "section_3_3_mean_theta",
            "kind": "theory",
            "source": "paper, section 3.3 (Theorem 2)",
            "claim": "With the 1/3, 2/3 rule and a uniform prior, after (0, 2) the robot "
            "behaves as though theta = 1/6.",
            "rule": "the posterior mean after (0, 2) is exactly 1/6 and the robot's expected "
            "rewards under its belief equal the rewards at that mean",
            "measurement": f"belief {example.belief}, acts as if theta = "
            f"{example.theta_acting}, makes {example.robot_action}",
            "reproduced": Fraction(example.theta_acting) == Fraction(1, 6)
            and example.expected_rewards == example.rewards_at_mean,
            "values": msgspec.to_builtins(example),
            "evidence": evidence,
        },
        {
            "id": "expert_not_optimal",
            "kind": "theory",
            "source": "paper, section 3.3",
            "claim": "Expert demonstrations are not part of an optimal policy pair: the "
            "instructive pair earns more.",
            "rule": "value(optimal pair) > value(delta_E, br(delta_E)), exact fractions",
            "measurement": f"expert pair {values.expert}, best-response pair "
            f"{values.best_response}, optimal {values.optimal}",
            "reproduced": Fraction(values.optimal) > Fraction(values.expert),
            "values": msgspec.to_builtins(values),
            "evidence": evidence,
        },
    ]
    return {"claims": claims}


def theory_claims() -> dict[str, list[dict[str, Any]]]:
    """:func:`office_supplies_claims` of :func:`cirl_study.theory.office_supplies_results`:
    the theory claims every study's report lists beside the run's."""
    from cirl_study.theory import office_supplies_results

    return office_supplies_claims(office_supplies_results())
