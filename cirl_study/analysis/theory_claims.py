"""The paper's theory claims (section 3, office-supplies example) as report rows.

Each row's verdict is computed from the exact results of
:func:`cirl_study.theory.office_supplies_results` (fractions compared exactly), never
written by hand. The rows have the shape :func:`cirl_study.analysis.claims.external_claims`
expects:

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

SOURCE_EXAMPLE = "paper, section 3.3 and appendix (office supplies)"


def _interval(rule: list[dict[str, str]], action: str) -> str | None:
    """The theta interval on which a threshold rule takes ``action``."""
    return next((piece["theta"] for piece in rule if piece["action"] == action), None)


def office_supplies_claims(results: dict[str, Any]) -> dict[str, list[dict[str, Any]]]:
    """Claim rows, with verdicts, from the exact office-supplies results."""
    optimal_interval = _interval(results["pairs"]["optimal"]["human_rule"], "(1, 1)")
    theorem = results["theorem_3"]
    example = results["section_3_3"]
    values = results["values"]
    expert_value, optimal_value = Fraction(values["expert"]), Fraction(values["optimal"])
    claims = [
        {
            "id": "office_supplies_thresholds",
            "source": SOURCE_EXAMPLE,
            "claim": "In the optimal equilibrium the human selects (1, 1) iff theta is in "
            "[41/92, 51/92].",
            "rule": "the optimal pair's human rule makes (1, 1) exactly on [41/92, 51/92], "
            "compared as exact fractions",
            "measurement": f"optimal pair makes (1, 1) on {optimal_interval}; thresholds "
            f"{', '.join(results['thresholds'])}",
            "reproduced": optimal_interval == "[41/92, 51/92]"
            and [Fraction(t) for t in results["thresholds"]]
            == [Fraction(41, 92), Fraction(51, 92)],
            "values": {"interval": optimal_interval, "thresholds": results["thresholds"]},
        },
        {
            "id": "theorem_3",
            "source": "paper, Theorem 3",
            "claim": "br(br(delta_E)) != delta_E: at theta = 0.49 the best response makes "
            "(1, 1) where the expert makes (0, 2).",
            "rule": "br(br(delta_E)) differs from delta_E, and at theta = 49/100 the expert "
            "and best-response actions are (0, 2) and (1, 1)",
            "measurement": f"at theta = {theorem['theta']}: expert {theorem['expert_action']}, "
            f"best response {theorem['best_response_action']}",
            "reproduced": not theorem["br_br_expert_equals_expert"]
            and Fraction(theorem["theta"]) == Fraction(49, 100)
            and theorem["expert_action"] == "(0, 2)"
            and theorem["best_response_action"] == "(1, 1)",
            "values": theorem,
        },
        {
            "id": "section_3_3_mean_theta",
            "source": "paper, section 3.3 (Theorem 2)",
            "claim": "With the 1/3, 2/3 rule and a uniform prior, after (0, 2) the robot "
            "behaves as though theta = 1/6.",
            "rule": "the posterior mean after (0, 2) is exactly 1/6 and the robot's expected "
            "rewards under its belief equal the rewards at that mean",
            "measurement": f"belief {example['belief']}, acts as if theta = "
            f"{example['theta_acting']}, makes {example['robot_action']}",
            "reproduced": Fraction(example["theta_acting"]) == Fraction(1, 6)
            and example["expected_rewards"] == example["rewards_at_mean"],
            "values": example,
        },
        {
            "id": "expert_not_optimal",
            "source": "paper, section 3.3",
            "claim": "Expert demonstrations are not part of an optimal policy pair: the "
            "instructive pair earns more.",
            "rule": "value(optimal pair) > value(delta_E, br(delta_E)), exact fractions",
            "measurement": f"expert pair {values['expert']}, best-response pair "
            f"{values['best_response']}, optimal {values['optimal']}",
            "reproduced": optimal_value > expert_value,
            "values": values,
        },
    ]
    for claim in claims:  # the exact results are stored under "theory" in results.json
        claim["evidence"] = ["results.json"]
    return {"claims": claims}


def theory_claims() -> dict[str, list[dict[str, Any]]]:
    """:func:`office_supplies_claims` of :func:`cirl_study.theory.office_supplies_results`:
    the theory claims every study's report lists beside the run's."""
    from cirl_study.theory import office_supplies_results

    return office_supplies_claims(office_supplies_results())
