"""The theory claim rows: verdicts follow the exact office-supplies results."""

import copy

import pytest

from cirl_study.analysis.results.claims import external_claims
from cirl_study.analysis.results.theory_claims import office_supplies_claims
from cirl_study.theory import office_supplies_results


@pytest.fixture(scope="module")
def results():
    return office_supplies_results()


def _verdicts(results):
    return {row.id: row.reproduced for row in external_claims(office_supplies_claims(results))}


def test_every_theory_claim_is_reproduced(results):
    assert _verdicts(results) == dict.fromkeys(
        ["office_supplies_thresholds", "theorem_3", "section_3_3_mean_theta", "expert_not_optimal"],
        True,
    )


@pytest.mark.parametrize(
    ("edit", "flipped"),
    [
        (lambda r: r["pairs"]["optimal"]["human_rule"][1].update(theta="[2/5, 3/5]"),
         "office_supplies_thresholds"),
        (lambda r: r["theorem_3"].update(br_br_expert_equals_expert=True), "theorem_3"),
        (lambda r: r["section_3_3"].update(theta_acting="1/3"), "section_3_3_mean_theta"),
        (lambda r: r["values"].update(optimal="69"), "expert_not_optimal"),
    ],
)  # fmt: skip
def test_a_changed_result_flips_exactly_its_claim(results, edit, flipped):
    changed = copy.deepcopy(results)
    edit(changed)
    verdicts = _verdicts(changed)
    assert not verdicts[flipped]
    assert all(verdicts[key] for key in verdicts if key != flipped)
