"""The trial table and the design check (cirl_study.analysis.table)."""

from __future__ import annotations

import copy
import math
import random

import pytest
from analysis_fixtures import synthetic_records

from cirl_study.analysis.table import COLUMNS, check_design, trial_table
from cirl_study.errors import UserError


@pytest.fixture(scope="module")
def records() -> list[dict]:
    return synthetic_records(subjects_per_level=3, lambdas=(0.1, 10.0), etas=(1.0,), cv_subjects=1)


def test_one_row_per_record_with_the_documented_columns(records):
    table = trial_table(records)
    assert list(table.columns) == list(COLUMNS)
    assert len(table) == len(records)
    by_id = {record["trial_id"]: record for record in records}
    for row in table.itertuples(index=False):
        record = by_id[row.trial_id]
        assert row.subject == record["subject"] and row.policy == record["policy"]
        assert row.regret == record["measures"]["regret"]
        assert row.kl == record["measures"]["kl"]
        assert row.reward_l2 == record["measures"]["reward_l2"]
        assert math.isnan(row.eta) if record["eta"] is None else row.eta == record["eta"]


def test_row_order_is_sorted_and_independent_of_record_order(records):
    table = trial_table(records)
    shuffled = records[:]
    random.Random(7).shuffle(shuffled)
    assert trial_table(shuffled).equals(table)
    keys = list(
        zip(table["block"], table["num_features"], table["subject"], table["policy"], strict=True)
    )
    assert keys == sorted(keys)


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        (("measures",), {"regret": 1.0, "kl": 1.0}, "missing field 'measures.reward_l2'"),
        (("measures", "kl"), "high", "'measures.kl' must be a finite number"),
        (("measures", "kl"), math.inf, "'measures.kl' must be a finite number"),
        (("num_features",), 2.5, "'num_features' must be a positive integer"),
        (("rationality",), 0, "'rationality' must be a positive number"),
        (("eta",), "none", "'eta' must be a number or null"),
        (("seed",), True, "'seed' must be an integer"),
        (("subject",), "", "'subject' must be a non-empty string"),
    ],
)
def test_a_malformed_record_is_a_one_line_user_error(records, path, value, message):
    broken = copy.deepcopy(records)
    target = broken[3]
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    with pytest.raises(UserError, match="trial record 3") as error:
        trial_table(broken)
    assert message in str(error.value) and "\n" not in str(error.value)


def test_a_complete_design_passes(records):
    check_design(trial_table(records))


def _without(records, predicate):
    return [record for record in records if not predicate(record)]


def test_check_design_names_a_missing_cell(records):
    kept = _without(
        records,
        lambda r: r["block"] == "main" and r["policy"] == "expert" and r["num_features"] == 10,
    )
    with pytest.raises(UserError, match=r"missing cells .*policy=expert, num_features=10"):
        check_design(trial_table(kept))


def test_check_design_names_an_unpaired_subject(records):
    kept = _without(
        records,
        lambda r: r["block"] == "main" and r["subject"] == "k3-s001" and r["policy"] == "expert",
    )
    with pytest.raises(UserError, match=r"k3-s001 \(expert x0, best_response x1\)"):
        check_design(trial_table(kept))


def test_check_design_names_duplicated_trial_ids(records):
    duplicated = [*records, copy.deepcopy(records[5])]
    with pytest.raises(UserError, match=f"duplicated trial ids: {records[5]['trial_id']}"):
        check_design(trial_table(duplicated))


def test_check_design_refuses_a_subject_at_two_feature_levels(records):
    moved = copy.deepcopy(records)
    for record in moved:
        if record["block"] == "main" and record["subject"] == "k10-s000":
            record["subject"] = "k3-s000"
            record["trial_id"] += "-moved"
    with pytest.raises(UserError, match="more than one feature level: k3-s000"):
        check_design(trial_table(moved))


def test_check_design_needs_two_feature_levels_and_known_policies(records):
    single = _without(records, lambda r: r["num_features"] == 10)
    with pytest.raises(UserError, match="only num_features=3"):
        check_design(trial_table(single))
    renamed = copy.deepcopy(records)
    next(r for r in renamed if r["block"] == "main")["policy"] = "random"
    with pytest.raises(UserError, match="unknown policies random"):
        check_design(trial_table(renamed))
    with pytest.raises(UserError, match="no trials in the 'main' block"):
        check_design(trial_table(_without(records, lambda r: r["block"] == "main")))
