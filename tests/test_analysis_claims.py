"""The claim rows and their verdict rules (cirl_study.analysis.results.claims).

Starting from real results of a synthetic study, as ``results.json`` stores them, the numbers
a rule reads are set so that every claim holds; then each test breaks exactly one condition
and checks that exactly that claim flips.
"""

from __future__ import annotations

import copy
from collections.abc import Callable

import msgspec
import pytest
from analysis_fixtures import pipeline, rows, synthetic_records

from cirl_study.analysis.results.claims import MIN_SUBJECTS, ClaimCounts, count_claims
from cirl_study.analysis.results.study import analyse, with_claims
from cirl_study.analysis.results.types import ClaimRow, StudyResults, checked
from cirl_study.errors import UserError
from cirl_study.measure_registry import PAPER_MEASURES

CLAIM_IDS = [
    "human_effect",
    "human_f_above_962",
    "interaction_kl_l2",
    "cronbach_alpha",
    "tukey_br_ahead",
    "lambda_intermediate",
]
"""The paper's claims; :data:`~cirl_study.analysis.results.claims.CLAIMS` lists them first."""

OTHER_IDS = [
    "paper_best_response",
    "milli_dragan_crossover",
    "milli_dragan_robustness",
    "best_response_vs_pedagogic",
    "regret_optimal_gap",
    "showing_beats_doing",
]


def evaluate_claims(results: dict, theory: dict | None = None) -> list[ClaimRow]:
    """The claim rows of the plain ``results``, as a report judges them (decoded first)."""
    typed = checked(results, StudyResults)
    return list(with_claims(typed, run_id=None, partial=None, theory=theory).claims)


def _anova(results: dict, measure: str, effect: str) -> dict:
    return next(
        r for r in results["paper"]["anova"] if r["measure"] == measure and r["effect"] == effect
    )


def _cell(results: dict, measure: str, level: int, human: str) -> dict:
    return next(
        r
        for r in results["cells"]
        if r["measure"] == measure and r["num_features"] == level and r["human"] == human
    )


def _within_level_tukey(results: dict) -> list[dict]:
    return [
        r
        for r in results["paper"]["tukey_hsd"]
        if r["a_num_features"] == r["b_num_features"] and r["measure"] in PAPER_MEASURES
    ]


@pytest.fixture(scope="module")
def holding() -> dict:
    """Results of a synthetic study, edited so that every paper claim holds."""
    study = analyse(rows(synthetic_records(subjects_per_level=10)), pipeline("synthetic"))
    results = msgspec.to_builtins(study)
    for measure in PAPER_MEASURES:
        _anova(results, measure, "human").update(F=1000.0, p=1e-12)
        _anova(results, measure, "human:num_features").update(p=1e-3)
        for level, gap in ((3, 2.0), (10, 1.0)):
            best = _cell(results, measure, level, "best_response")["mean"]
            _cell(results, measure, level, "expert")["mean"] = best + gap
    results["paper"]["cronbach_alpha"]["ci95"] = [0.40, 0.50]
    for row in _within_level_tukey(results):
        row["p_tukey"] = 1e-6
    return results


def _verdicts(results: dict) -> dict[str, bool]:
    """The paper's claims' verdicts."""
    return {c.id: c.reproduced for c in evaluate_claims(results) if c.id in CLAIM_IDS}


def test_every_paper_claim_has_a_row_and_holds_when_its_numbers_do(holding):
    claims = evaluate_claims(holding)
    assert [claim.id for claim in claims] == CLAIM_IDS + OTHER_IDS
    for claim in claims[: len(CLAIM_IDS)]:
        assert claim.tested and claim.reproduced
        assert claim.claim and claim.rule and claim.measurement and claim.evidence
        assert claim.source.startswith("paper, section 4.")


def test_a_claim_whose_cells_the_run_lacks_is_not_tested(holding):
    """The synthetic study plays the paper's humans and robot only: the teaching claims are
    listed, not tested, and say what the run lacks."""
    claims = {claim.id: claim for claim in evaluate_claims(holding)}
    assert claims["paper_best_response"].tested
    for claim in OTHER_IDS[1:]:
        assert not claims[claim].tested and claims[claim].reproduced is False
        lacks = "participants" if claim == "showing_beats_doing" else "the human"
        assert claims[claim].measurement.startswith(f"not tested: the run lacks {lacks}")


def _human_p(results):
    _anova(results, "kl", "human")["p"] = 2e-4


def _expert_better(results):
    for level, gap in ((3, -1.0), (10, -2.0)):  # the gap still shrinks with more features
        best = _cell(results, "reward_l2", level, "best_response")["mean"]
        _cell(results, "reward_l2", level, "expert")["mean"] = best + gap


def _small_f(results):
    _anova(results, "regret", "human")["F"] = 961.0


def _no_interaction(results):
    _anova(results, "reward_l2", "human:num_features")["p"] = 0.2


def _gap_larger_with_more_features(results):
    best = _cell(results, "kl", 10, "best_response")["mean"]
    _cell(results, "kl", 10, "expert")["mean"] = best + 5.0


def _alpha_elsewhere(results):
    results["paper"]["cronbach_alpha"]["ci95"] = [0.48, 0.60]


def _tukey_not_significant(results):
    _within_level_tukey(results)[-1]["p_tukey"] = 0.06


def _tukey_expert_ahead(results):
    row = _within_level_tukey(results)[0]
    row["mean_a"], row["mean_b"] = row["mean_b"], row["mean_a"]


def _lambda_minimum_at_an_end(results):
    for row in results["lambda_sweep"]:
        if row["measure"] == "regret" and row["rationality"] == 100.0:
            row.update(mean=0.01, ci95_low=0.0, ci95_high=0.02)


def _lambda_minimum_not_clear(results):
    for row in results["lambda_sweep"]:
        if row["measure"] == "regret" and row["rationality"] == 1.0:
            row["ci95_high"] = 10.0


@pytest.mark.parametrize(
    ("edit", "flipped"),
    [
        (_human_p, "human_effect"),
        (_expert_better, "human_effect"),
        (_small_f, "human_f_above_962"),
        (_no_interaction, "interaction_kl_l2"),
        (_gap_larger_with_more_features, "interaction_kl_l2"),
        (_alpha_elsewhere, "cronbach_alpha"),
        (_tukey_not_significant, "tukey_br_ahead"),
        (_tukey_expert_ahead, "tukey_br_ahead"),
        (_lambda_minimum_at_an_end, "lambda_intermediate"),
        (_lambda_minimum_not_clear, "lambda_intermediate"),
    ],
)
def test_breaking_one_condition_flips_only_its_claim(holding, edit: Callable, flipped: str):
    results = copy.deepcopy(holding)
    edit(results)
    assert _verdicts(results) == {claim: claim != flipped for claim in CLAIM_IDS}


def test_the_regret_interaction_does_not_decide_the_kl_l2_claim(holding):
    results = copy.deepcopy(holding)
    _anova(results, "regret", "human:num_features")["p"] = 0.9
    assert _verdicts(results)["interaction_kl_l2"]


@pytest.mark.parametrize("lambdas", [[], [0.01, 1.0]])
def test_the_lambda_claim_is_not_tested_without_a_sweep_of_three_lambdas(holding, lambdas):
    results = copy.deepcopy(holding)
    results["lambda_sweep"] = [r for r in results["lambda_sweep"] if r["rationality"] in lambdas]
    results["design"]["sweep_rationalities"] = lambdas
    claim = evaluate_claims(results)[len(CLAIM_IDS) - 1]
    assert claim.id == "lambda_intermediate"
    assert not claim.tested and not claim.reproduced
    assert claim.measurement == (
        "not tested: the run lacks a lambda sweep of at least 3 rationalities"
    )


def _theory_claim(**changes) -> dict:
    claim = {
        "id": "office_supplies_instructive",
        "source": "paper, section 3.3",
        "claim": "The instructive demonstration differs from the expert's.",
        "rule": "the optimal demonstration is not the expert's",
        "measurement": "optimal demonstration (0, 2); expert (2, 0)",
        "reproduced": True,
        "values": {"theta": [0.5, 0.4]},
        "evidence": ["theory"],
    }
    claim.update(changes)
    return claim


def test_theory_claims_are_appended_after_the_papers(holding):
    theory = {"claims": [_theory_claim(), _theory_claim(id="untested", tested=False)]}
    claims = evaluate_claims(holding, theory)
    assert [claim.id for claim in claims] == [
        *CLAIM_IDS,
        *OTHER_IDS,
        "office_supplies_instructive",
        "untested",
    ]
    assert claims[-2].reproduced and claims[-2].tested
    assert not claims[-1].reproduced and not claims[-1].tested


@pytest.mark.parametrize(
    ("theory", "message"),
    [
        ({"claims": "none"}, "a list under 'claims'"),
        ({"claims": [_theory_claim(reproduced="yes")]}, "'reproduced' and 'tested' must be"),
        ({"claims": [_theory_claim(rule="")]}, "'rule' must be a non-empty string"),
        ({"claims": [_theory_claim(evidence="theory")]}, "'evidence' must be a list"),
        ({"claims": [_theory_claim(id="cronbach_alpha")]}, "'cronbach_alpha' is already used"),
    ],
)
def test_malformed_theory_results_are_user_errors(holding, theory, message):
    with pytest.raises(UserError, match=message):
        evaluate_claims(holding, theory)


def _p_objects(value: object) -> list[dict]:
    """Every dict of ``value`` that holds a p-value (``p``, ``p_holm`` or ``p_tukey``)."""
    found = []
    if isinstance(value, dict):
        if {"p", "p_holm", "p_tukey"} & set(value):
            found.append(value)
        for item in value.values():
            found += _p_objects(item)
    elif isinstance(value, list):
        for item in value:
            found += _p_objects(item)
    return found


def test_every_p_of_a_claims_values_carries_its_log10(holding):
    """A claim's values repeat the ANOVA's p beside its log10, which holds it where the double
    underflows: a human effect of log10 p = -500 (p = 0 in doubles) keeps its value."""
    results = copy.deepcopy(holding)
    for measure in PAPER_MEASURES:
        _anova(results, measure, "human").update(p=0.0, log10_p=-500.0)
    claims = {claim.id: claim for claim in evaluate_claims(results)}
    for measure in PAPER_MEASURES:
        assert claims["human_effect"].values[measure]["log10_p"] == -500.0
        interaction = _anova(results, measure, "human:num_features")
        assert claims["interaction_kl_l2"].values[measure]["log10_p"] == interaction["log10_p"]
    for claim in claims.values():
        for row in _p_objects(claim.values):
            for key in {"p", "p_holm", "p_tukey"} & set(row):
                assert f"log10_{key}" in row, (claim.id, row)


def test_every_claim_of_the_run_is_data_judged_on_its_cells_subjects(holding):
    """The synthetic study has 10 reward draws per feature level: each judged claim says so,
    the lambda claim from its sweep's cells; a claim not tested counts none."""
    claims = evaluate_claims(holding)
    assert {claim.kind for claim in claims} == {"data"}
    assert {claim.id: claim.subjects for claim in claims if claim.tested} == dict.fromkeys(
        [*CLAIM_IDS, "paper_best_response"], 10
    )
    assert all(claim.subjects is None for claim in claims if not claim.tested)
    results = copy.deepcopy(holding)
    for row in results["lambda_sweep"]:
        row["n"] = 7
    lambda_claim = next(c for c in evaluate_claims(results) if c.id == "lambda_intermediate")
    assert lambda_claim.subjects == 7


def test_external_claims_are_theorems_unless_they_say_otherwise(holding):
    theory = {"claims": [_theory_claim(), _theory_claim(id="on_data", kind="data")]}
    claims = {claim.id: claim for claim in evaluate_claims(holding, theory)}
    assert claims["office_supplies_instructive"].kind == "theory"
    assert claims["on_data"].kind == "data"
    assert claims["on_data"].subjects is None
    with pytest.raises(UserError, match="'kind' must be 'data' or 'theory'"):
        evaluate_claims(holding, {"claims": [_theory_claim(kind="theorem")]})


def test_the_counts_keep_data_theorems_and_untested_claims_apart(holding):
    theory = {
        "claims": [
            _theory_claim(),
            _theory_claim(id="broken", reproduced=False),
            _theory_claim(id="untested", tested=False),
        ]
    }
    counts = count_claims(evaluate_claims(holding, theory))
    # the paper's claims and paper_best_response judged; the teaching ones, the people's and
    # "untested" not
    assert (counts.data, counts.reproduced + counts.not_reproduced, counts.answered) == (7, 7, 0)
    assert (counts.theorems, counts.theorems_hold, counts.not_tested) == (2, 1, 6)
    assert counts.subjects == 10 < MIN_SUBJECTS and counts.few_subjects
    summary = counts.summary()
    assert summary.startswith(f"7 claims on this run's data: {counts.reproduced} reproduced, ")
    assert "(judged on cells of 10 subjects, fewer than 20: the verdicts mean little)" in summary
    assert summary.endswith(
        "; 2 theorems checked exactly, independent of the run: 1 holds, 1 does not; "
        "6 claims not tested, the run lacks their cells"
    )


def test_enough_subjects_leave_out_the_warning():
    counts = ClaimCounts(
        data=1,
        reproduced=0,
        not_reproduced=0,
        answered=1,
        theorems=0,
        theorems_hold=0,
        not_tested=0,
        subjects=MIN_SUBJECTS,
    )
    assert not counts.few_subjects and counts.subjects_text() is None
    assert counts.summary() == (
        "1 claim on this run's data: 0 reproduced, 0 not reproduced, 1 question answered"
    )
    assert ClaimCounts(0, 0, 0, 0, 0, 0, 3, None).summary() == (
        "no claim on this run's data judged; 3 claims not tested, the run lacks their cells"
    )
