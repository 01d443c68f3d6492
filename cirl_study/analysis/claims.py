"""The paper's claims beside what we measured, each with a verdict computed from the data.

Each claim of docs/design.md §5 becomes one row::

    {"id", "source", "claim", "rule", "measurement", "values", "tested", "reproduced",
     "evidence"}

``claim`` is the paper's statement, ``rule`` the documented test that decides
``reproduced`` from the numbers in ``values`` (never written by hand), ``tested`` is false
when the run has no data for the claim (then ``reproduced`` is false too), and
``evidence`` names the keys of ``results.json`` (and figures) that support the row.

The rules (constants below):

1. ``policy_effect``: for every measure the mixed ANOVA's policy effect has
   ``p < .0001`` and the best response's mean over the main block is below the expert's.
2. ``policy_f_above_962``: every measure's policy ``F`` exceeds 962.
3. ``interaction_kl_l2``: for KL and L2, the policy x num_features interaction has
   ``p < .05`` and the gap ``mean(expert) - mean(best_response)`` is larger at the
   smallest feature level than at the largest.
4. ``cronbach_alpha``: the paper's .47 lies inside the 95% (Feldt) interval of our raw alpha.
5. ``tukey_br_ahead``: for every measure and feature level, Tukey HSD (as the paper ran
   it, ignoring the pairing) compares best response and expert at that level with
   ``p < .05`` and the best response's mean is lower.
6. ``lambda_intermediate``: at every feature level of the lambda sweep (at least three
   lambdas) the lambda with the lowest mean best-response regret is neither the smallest
   nor the largest, and the upper end of its 95% CI lies below the mean at both ends.

Claims from other sources (e.g. the office-supplies theory results) are appended with
:func:`external_claims`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from cirl_study.analysis.markdown import p_value
from cirl_study.analysis.results import Results, plain
from cirl_study.errors import UserError
from cirl_study.record import BEST_RESPONSE, EXPERT, MEASURES

SIGNIFICANCE = 0.05
"""Significance level of the rules that the paper states without a level."""

PAPER_P = 1e-4
"""The paper's bound on the p-values of the policy effect."""

PAPER_F = 962.0
"""The paper's lower bound on the F statistics of the policy effect."""

PAPER_ALPHA = 0.47
"""The paper's Cronbach's alpha across the three measures."""

SECTION_POLICY = "paper, section 4.2"
SECTION_LAMBDA = "paper, section 4.3"

MEASURE_NAMES = {"regret": "regret", "kl": "KL", "reward_l2": "L2"}
"""Short names of the measures in measurement texts."""


def _num(value: float) -> str:
    return f"{value:.4g}"


def _p(value: float) -> str:
    """``p = 0.0123``, or ``p < 1e-300`` (see :func:`cirl_study.analysis.markdown.p_value`)."""
    shown = p_value(value)
    return f"p {shown}" if shown.startswith("<") else f"p = {shown}"


def _anova(results: Results, measure: str, effect: str) -> dict[str, Any]:
    return next(
        row for row in results["anova"] if row["measure"] == measure and row["effect"] == effect
    )


def _means(results: Results, measure: str) -> dict[tuple[int, str], dict[str, Any]]:
    return {
        (row["num_features"], row["policy"]): row
        for row in results["cells"]
        if row["measure"] == measure
    }


def _policy_mean(results: Results, measure: str, policy: str) -> float:
    cells = [row for row in results["cells"] if row["measure"] == measure]
    weighted = sum(row["n"] * row["mean"] for row in cells if row["policy"] == policy)
    return weighted / sum(row["n"] for row in cells if row["policy"] == policy)


def _row(
    identifier: str,
    source: str,
    claim: str,
    rule: str,
    measurement: str,
    values: dict[str, Any],
    reproduced: bool,
    evidence: list[str],
    tested: bool = True,
) -> dict[str, Any]:
    return {
        "id": identifier,
        "source": source,
        "claim": claim,
        "rule": rule,
        "measurement": measurement,
        "values": plain(values),
        "tested": tested,
        "reproduced": bool(tested and reproduced),
        "evidence": evidence,
    }


def _f_text(row: dict[str, Any]) -> str:
    return f"F({row['df1']}, {row['df2']}) = {_num(row['F'])}, {_p(row['p'])}"


def policy_effect(results: Results) -> dict[str, Any]:
    """Claim 1: the best response beats the expert on every measure, ``p < .0001``."""
    values, parts, holds = {}, [], True
    for measure in MEASURES:
        row = _anova(results, measure, "policy")
        expert = _policy_mean(results, measure, EXPERT)
        best = _policy_mean(results, measure, BEST_RESPONSE)
        values[measure] = {"F": row["F"], "p": row["p"], "mean_expert": expert, "mean_br": best}
        holds &= row["p"] < PAPER_P and best < expert
        parts.append(
            f"{MEASURE_NAMES[measure]}: best response {_num(best)} vs expert {_num(expert)}, "
            f"{_f_text(row)}"
        )
    return _row(
        "policy_effect",
        SECTION_POLICY,
        "Best response outperforms demonstration-by-expert on all three measures "
        "(significant effect of policy, p < .0001).",
        f"every measure: policy effect p < {PAPER_P:g} and the best response's mean below "
        "the expert's",
        "; ".join(parts),
        values,
        holds,
        ["anova", "cells", "figure2_measures"],
    )


def policy_f(results: Results) -> dict[str, Any]:
    """Claim 1 (size): every policy ``F`` exceeds 962."""
    values = {m: _anova(results, m, "policy")["F"] for m in MEASURES}
    return _row(
        "policy_f_above_962",
        SECTION_POLICY,
        "The effect of policy has F > 962 on every measure.",
        f"every measure: policy effect F > {PAPER_F:g}",
        "; ".join(f"{MEASURE_NAMES[m]}: F = {_num(f)}" for m, f in values.items()),
        values,
        min(values.values()) > PAPER_F,
        ["anova"],
    )


def _gap(results: Results, measure: str, level: int) -> float:
    means = _means(results, measure)
    return means[(level, EXPERT)]["mean"] - means[(level, BEST_RESPONSE)]["mean"]


def interaction(results: Results) -> dict[str, Any]:
    """Claim 2: policy x num_features interaction for KL and L2, gap larger with fewer features."""
    levels = results["design"]["feature_levels"]
    low, high = min(levels), max(levels)
    values, parts, holds = {}, [], True
    for measure in MEASURES:
        row = _anova(results, measure, "policy:num_features")
        gaps = {low: _gap(results, measure, low), high: _gap(results, measure, high)}
        values[measure] = {"F": row["F"], "p": row["p"], **{f"gap_{k}": g for k, g in gaps.items()}}
        if measure != "regret":
            holds &= row["p"] < SIGNIFICANCE and gaps[low] > gaps[high]
        parts.append(
            f"{MEASURE_NAMES[measure]}: interaction {_f_text(row)}; gap {_num(gaps[low])} at "
            f"{low} vs {_num(gaps[high])} at {high} features"
        )
    return _row(
        "interaction_kl_l2",
        SECTION_POLICY,
        "An interaction of policy with num_features for KL and L2: the gap between the "
        "policies is larger with fewer features.",
        f"KL and L2: interaction p < {SIGNIFICANCE:g} and the gap mean(expert) - "
        f"mean(best response) larger at {low} than at {high} features (regret shown for context)",
        "; ".join(parts),
        values,
        holds,
        ["anova", "simple_effects", "cells", "figure2_measures"],
    )


def cronbach(results: Results) -> dict[str, Any]:
    """Claim 3: Cronbach's alpha across the three measures is .47."""
    alpha = results["cronbach_alpha"]
    low, high = alpha["ci95"]
    return _row(
        "cronbach_alpha",
        SECTION_POLICY,
        "Relatively little correlation between the measures: Cronbach's alpha of .47.",
        f"{PAPER_ALPHA:g} inside the 95% Feldt interval of our raw alpha",
        f"raw alpha {_num(alpha['raw'])} [{_num(low)}, {_num(high)}], standardised "
        f"{_num(alpha['standardized'])}, over {alpha['n_rows']} main-block trials",
        {"raw": alpha["raw"], "ci95": [low, high], "standardized": alpha["standardized"]},
        low <= PAPER_ALPHA <= high,
        ["cronbach_alpha"],
    )


def tukey(results: Results) -> dict[str, Any]:
    """Claim 4: Tukey HSD shows the best response ahead of the expert in every cell."""
    values, parts, holds = {}, [], True
    for row in results["tukey_hsd"]:
        level = row["a_num_features"]
        if level != row["b_num_features"]:
            continue
        means = {row["a_policy"]: row["mean_a"], row["b_policy"]: row["mean_b"]}
        ahead = means[BEST_RESPONSE] < means[EXPERT]
        holds &= ahead and row["p_tukey"] < SIGNIFICANCE
        values[f"{row['measure']}@{level}"] = {
            "diff_br_minus_expert": means[BEST_RESPONSE] - means[EXPERT],
            "p_tukey": row["p_tukey"],
        }
        parts.append(
            f"{MEASURE_NAMES[row['measure']]} at {level}: best response minus expert "
            f"{_num(means[BEST_RESPONSE] - means[EXPERT])}, {_p(row['p_tukey'])}"
        )
    return _row(
        "tukey_br_ahead",
        SECTION_POLICY,
        "Post-hoc Tukey HSD shows the best response outperforming the expert in every cell.",
        f"every measure and feature level: Tukey HSD (ignoring the pairing) p < {SIGNIFICANCE:g} "
        "and the best response's mean lower",
        "; ".join(parts),
        values,
        holds,
        ["tukey_hsd", "figure2_measures"],
    )


def lambda_minimum(results: Results) -> dict[str, Any]:
    """Claim 5: the best response's regret is lowest at an intermediate lambda."""
    curves: dict[int, list[dict[str, Any]]] = {}
    for row in results["lambda_sweep"]:
        if row["measure"] == "regret" and row["policy"] == BEST_RESPONSE:
            curves.setdefault(row["num_features"], []).append(row)
    claim = "The best response's regret is lowest at an intermediate lambda."
    rule = (
        "every feature level: the lambda of lowest mean best-response regret is neither the "
        "smallest nor the largest of the sweep, and its 95% CI's upper end is below the mean "
        "at both ends"
    )
    if not curves or min(len(curve) for curve in curves.values()) < 3:
        return _row(
            "lambda_intermediate",
            SECTION_LAMBDA,
            claim,
            rule,
            "not measured: the run has no lambda sweep with at least three lambdas",
            {},
            False,
            ["lambda_sweep"],
            tested=False,
        )
    values, parts, holds = {}, [], True
    for level, curve in sorted(curves.items()):
        curve = sorted(curve, key=lambda row: row["rationality"])
        best = min(curve, key=lambda row: (row["mean"], row["rationality"]))
        ends = (curve[0]["mean"], curve[-1]["mean"])
        interior = best is not curve[0] and best is not curve[-1]
        holds &= interior and best["ci95_high"] < min(ends)
        values[str(level)] = {
            "argmin_lambda": best["rationality"],
            "min_mean": best["mean"],
            "min_ci95_high": best["ci95_high"],
            "mean_at_smallest_lambda": ends[0],
            "mean_at_largest_lambda": ends[1],
        }
        parts.append(
            f"{level} features: lowest {_num(best['mean'])} (CI upper {_num(best['ci95_high'])}) "
            f"at lambda = {best['rationality']:g}; {_num(ends[0])} at {curve[0]['rationality']:g}, "
            f"{_num(ends[1])} at {curve[-1]['rationality']:g}"
        )
    return _row(
        "lambda_intermediate",
        SECTION_LAMBDA,
        claim,
        rule,
        "; ".join(parts),
        values,
        holds,
        ["lambda_sweep", "figure2_lambda"],
    )


_EXTERNAL_TEXT = ("id", "source", "claim", "rule", "measurement")


def external_claims(theory: Mapping[str, Any]) -> list[dict[str, Any]]:
    """Claim rows supplied by another analysis (e.g. the office-supplies theory results).

    ``theory["claims"]`` must be a list of rows with the string fields ``id, source, claim,
    rule, measurement``, a boolean ``reproduced`` computed by that analysis, and optionally
    ``tested`` (boolean, default true), ``values`` (JSON data) and ``evidence`` (list of
    strings: keys of ``results.json``, figure names or relative links).

    Raises:
        UserError: ``theory`` does not have that shape.
    """
    entries = theory.get("claims") if isinstance(theory, Mapping) else None
    if not isinstance(entries, list):
        raise UserError("theory results: expected a dict with a list under 'claims'")
    claims = []
    for position, entry in enumerate(entries):
        where = f"theory results: claim {position}"
        if not isinstance(entry, Mapping):
            raise UserError(f"{where}: expected a dict, got {type(entry).__name__}")
        for key in _EXTERNAL_TEXT:
            if not isinstance(entry.get(key), str) or not entry[key]:
                raise UserError(f"{where}: '{key}' must be a non-empty string")
        tested = entry.get("tested", True)
        if not isinstance(entry.get("reproduced"), bool) or not isinstance(tested, bool):
            raise UserError(f"{where}: 'reproduced' and 'tested' must be booleans")
        evidence = entry.get("evidence", [])
        if not isinstance(evidence, list) or not all(isinstance(e, str) for e in evidence):
            raise UserError(f"{where}: 'evidence' must be a list of strings")
        claims.append(
            {
                **{key: entry[key] for key in _EXTERNAL_TEXT},
                "values": plain(entry.get("values", {})),
                "tested": tested,
                "reproduced": bool(tested and entry["reproduced"]),
                "evidence": list(evidence),
            }
        )
    return claims


def evaluate_claims(results: Results, theory: Mapping[str, Any] | None = None) -> list[dict]:
    """Every claim row: the paper's (docs/design.md §5), then those of ``theory``."""
    claims = [
        policy_effect(results),
        policy_f(results),
        interaction(results),
        cronbach(results),
        tukey(results),
        lambda_minimum(results),
    ]
    ids = {claim["id"] for claim in claims}
    for claim in external_claims(theory) if theory is not None else []:
        if claim["id"] in ids:
            raise UserError(f"theory results: claim id {claim['id']!r} is already used")
        ids.add(claim["id"])
        claims.append(claim)
    return claims
