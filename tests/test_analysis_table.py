"""The trial table and the design check (cirl_study.analysis.table)."""

from __future__ import annotations

import math
import random
import re

import msgspec
import pytest
from analysis_fixtures import rows, synthetic_records

from cirl_study.analysis.table import check_design, columns, trial_table
from cirl_study.errors import UserError
from cirl_study.measure_registry import MEASURES
from cirl_study.record import TrialRecord, TrialRow, from_builtins, to_builtins


@pytest.fixture(scope="module")
def records() -> list[TrialRecord]:
    return synthetic_records(subjects_per_level=3, lambdas=(0.1, 10.0), etas=(1.0,), cv_subjects=1)


def test_one_row_per_record_with_the_documented_columns(records):
    table = trial_table(rows(records))
    assert list(table.columns) == list(columns())
    assert len(table) == len(records)
    by_id = {record.trial_id: record for record in records}
    for row in table.itertuples(index=False):
        record = by_id[row.trial_id]
        assert row.subject == record.subject and row.human == record.human
        assert row.regret == record.measures["regret"]
        assert row.kl == record.measures["kl"]
        assert row.reward_l2 == record.measures["reward_l2"]
        assert math.isnan(row.eta) if record.eta is None else row.eta == record.eta


def test_columns_have_the_trials_csv_dtypes(records):
    dtypes = trial_table(rows(records)).dtypes
    assert all(dtypes[name].kind == "i" for name in ("num_features", "seed"))
    assert all(dtypes[name].kind == "f" for name in ("rationality", "eta", "regret", "kl"))


def test_row_order_is_sorted_and_independent_of_record_order(records):
    table = trial_table(rows(records))
    shuffled = records[:]
    random.Random(7).shuffle(shuffled)
    assert trial_table(rows(shuffled)).equals(table)
    keys = list(
        zip(table["block"], table["num_features"], table["subject"], table["human"], strict=True)
    )
    assert keys == sorted(keys)


@pytest.mark.parametrize(
    ("path", "value", "where"),
    [
        (("measures", "kl"), "high", "$.measures[...]"),
        (("measures", "kl"), math.inf, "$.measures[...]"),
        (("num_features",), 2.5, "$.num_features"),
        (("rationality",), 0, "$.rationality"),
        (("eta",), "none", "$.eta"),
        (("seed",), True, "$.seed"),
        (("subject",), "", "$.subject"),
    ],
)
def test_malformed_data_is_refused_before_it_becomes_a_record(records, path, value, where):
    """The table trusts its records: the types refuse what it used to check field by field."""
    broken = to_builtins(records[3])
    target = broken
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = value
    with pytest.raises(msgspec.ValidationError, match=re.escape(f"at `{where}`")):
        from_builtins(broken)


def test_a_complete_design_passes(records):
    check_design(rows(records))


def _without(records, predicate):
    return [record for record in records if not predicate(record)]


def _refused(records, pattern: str) -> str:
    with pytest.raises(UserError, match=pattern) as error:
        check_design(rows(records))
    message = str(error.value)
    assert message.startswith("the run's design cannot be analysed: ") and "\n" not in message
    return message


def test_check_design_names_the_subjects_of_a_missing_cell(records):
    kept = _without(
        records, lambda r: r.block == "main" and r.human == "expert" and r.num_features == 10
    )
    message = _refused(kept, r"main block incomplete: 3 subject\(s\)")
    assert "k10-s000 has {'best_response/map': 1}" in message


def test_check_design_names_an_unpaired_subject(records):
    kept = _without(
        records, lambda r: r.block == "main" and r.subject == "k3-s001" and r.human == "expert"
    )
    _refused(
        kept, r"main block incomplete: 1 subject\(s\) .*k3-s001 has \{'best_response/map': 1\}"
    )


def test_check_design_names_repeated_trial_ids(records):
    _refused([*records, records[5]], f"1 trial id\\(s\\) repeated: {records[5].trial_id}")


def test_check_design_refuses_a_subject_at_two_feature_levels(records):
    moved = [
        msgspec.structs.replace(r, subject="k3-s000", trial_id=f"{r.trial_id}-moved")
        if r.block == "main" and r.subject == "k10-s000"
        else r
        for r in records
    ]
    _refused(moved, r"their subject's draw: k3-s000 \(.*: num_features 10 against 3\)")


def test_check_design_refuses_cross_validation_draws_reused_in_the_test_blocks(records):
    cv = next(r for r in records if r.block == "eta_cv")
    reused = [*records, msgspec.structs.replace(cv, block="lambda_sweep", trial_id="reused")]
    _refused(reused, f"eta_cv subject\\(s\\) also used in the test blocks: {cv.subject}")


def test_check_design_takes_any_humans_and_levels_but_needs_two_cells(records):
    """One feature level, one human or a human of the user's own: analysed like the paper's
    design; a main block of one cell, or none, is refused."""
    check_design(rows(_without(records, lambda r: r.num_features == 10)))
    check_design(rows(_without(records, lambda r: r.block == "main" and r.human == "expert")))
    renamed = [
        msgspec.structs.replace(r, human="random")
        if r.block == "main" and r.human == "expert"
        else r
        for r in records
    ]
    check_design(rows(renamed))
    one_cell = _without(records, lambda r: r.num_features == 10 or r.human == "expert")
    _refused(one_cell, r"the main block has one cell \(one human, one robot, one feature level\)")
    _refused(_without(records, lambda r: r.block == "main"), "no trials in the main block")


def test_a_row_keeps_the_identity_measures_and_a_digest_of_the_draw():
    first, second = synthetic_records(subjects_per_level=1)[:2]
    row = TrialRow.of(first)
    for name in ("trial_id", "run_id", "block", "subject", "human", "robot", "eta", "seed"):
        assert getattr(row, name) == getattr(first, name)
    assert {name: row.measure(name) for name in MEASURES} == first.measures and row.converged
    same_draw = msgspec.structs.replace(first, trial_id="other", theta_hat=second.theta_hat)
    assert TrialRow.of(same_draw).draw == row.draw
    for change in (
        {"theta": (0.5, *first.theta[1:])},
        {"features": msgspec.structs.replace(first.features, sigma=2.0)},
        {"start": (0, 0)},
    ):
        assert TrialRow.of(msgspec.structs.replace(first, **change)).draw != row.draw
