"""A new measure is one module and one registry line: register one, play a pipeline with it,
and find it in the records, the trial table, the results and the report; where a trial has no
value of it, the analysis leaves that reward draw out of its statistics and says so."""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import msgspec
import numpy as np
import pandas as pd
import pytest
from test_logs_helpers import make_record, run_records

import cirl_study
from cirl_study.analysis.reading import read_for_analysis
from cirl_study.analysis.report.study import write_report
from cirl_study.analysis.statistics.anova import repeated_measures_anova
from cirl_study.analysis.table import check_design
from cirl_study.core.apprenticeship import Outcome
from cirl_study.core.gridworld import feature_matrix
from cirl_study.logs.record_checks import record_faults
from cirl_study.logs.validate import validate_run
from cirl_study.measure_registry import (
    MEASURES,
    PAPER_MEASURES,
    Measure,
    analysed_measures,
    measure_faults,
    register_measure,
)
from cirl_study.study.pipeline_file import logged_pipeline

SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"

UNDEFINED_BELOW = -0.4
"""The test measure is undefined where ``theta_0`` is below this."""


def reward_l1(outcome: Outcome) -> list[float | None]:
    """The test-only measure: ``||Phi theta - Phi theta_hat||_1`` over all cells, undefined
    (``None``) where ``theta_0 < UNDEFINED_BELOW``."""
    features = outcome.game.deployment.features
    gaps = np.einsum("bsk,bk->bs", features, outcome.theta - outcome.theta_hat)
    distances = np.abs(gaps).sum(axis=1)
    return [
        None if theta[0] < UNDEFINED_BELOW else float(distance)
        for theta, distance in zip(outcome.theta, distances, strict=True)
    ]


@pytest.fixture(scope="class")
def registered() -> Iterator[None]:
    """The test measure, registered for a class's tests and unregistered after them."""
    register_measure(
        "reward_l1",
        Measure(f"{__name__}:reward_l1", label="reward L1 distance", short="L1", unit="reward",
                minimum=0.0, undefined=f"where theta_0 < {UNDEFINED_BELOW}"),
    )  # fmt: skip
    yield
    del MEASURES["reward_l1"]


@pytest.fixture(scope="class")
def run(registered: None, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``pipelines/smoke.toml`` played with the test measure registered."""
    return cirl_study.run(SMOKE, tmp_path_factory.mktemp("registry") / "run")


class TestARegisteredMeasure:
    """The test measure, registered for this class's tests alone."""

    def test_the_measure_is_computed_logged_and_checked(self, run: Path) -> None:
        assert validate_run(run, logged_pipeline).ok
        records = run_records(run)
        undefined = [r for r in records if r.theta[0] < UNDEFINED_BELOW]
        assert records and undefined and len(undefined) < len(records)
        for record in records:
            assert set(record.measures) == set(MEASURES)
            difference = np.subtract(record.theta, record.theta_hat)
            phi = feature_matrix(record)
            want = None if record.theta[0] < UNDEFINED_BELOW else np.abs(phi @ difference).sum()
            if want is None:
                assert record.measures["reward_l1"] is None
            else:
                assert record.measures["reward_l1"] == pytest.approx(want, rel=1e-12)

    def test_the_measure_is_a_column_of_the_trial_table(self, run: Path) -> None:
        table = cirl_study.load_trials(run)
        assert list(table.columns[11:]) == [*MEASURES, "converged", "file"]
        assert list(MEASURES)[-1] == "reward_l1"
        records = {r.trial_id: r for r in run_records(run)}
        for trial_id, value in zip(table["trial_id"], table["reward_l1"], strict=True):
            logged = records[trial_id].measures["reward_l1"]
            assert math.isnan(value) if logged is None else value == logged

    def test_the_analysis_tests_the_measure_on_the_draws_that_have_it(self, run: Path) -> None:
        results = cirl_study.analyze(run)
        table = cirl_study.load_trials(run)
        main = table[table["block"] == "main"]
        missing = table[table["reward_l1"].isna()]
        assert [msgspec.to_builtins(row) for row in results.undefined] == [
            {
                "measure": "reward_l1",
                "trials": len(missing),
                "subjects": missing["subject"].nunique(),
            }
        ]
        kept = main[main["reward_l1"].notna()]
        cells = [row for row in results.cells if row.measure == "reward_l1"]
        assert cells
        for row in cells:
            cell = kept[(kept["num_features"] == row.num_features) & (kept["human"] == row.human)]
            assert (row.n, row.mean) == (len(cell), pytest.approx(cell["reward_l1"].mean(), 1e-12))
        between = ["num_features"] if kept["num_features"].nunique() > 1 else []
        want = repeated_measures_anova(kept, "reward_l1", ["human"], between)
        assert [row for row in results.anova if row.measure == "reward_l1"] == want
        assert {row.measure for row in results.paper.simple_effects} == set(analysed_measures())
        assert {row.measure for row in results.paper.tukey_hsd} == set(analysed_measures())
        # The paper's three alone make Cronbach's alpha and the claims.
        assert results.paper.cronbach_alpha.items == list(PAPER_MEASURES)
        human_effect = next(claim for claim in results.claims if claim.id == "human_effect")
        assert list(human_effect.values) == list(PAPER_MEASURES)

    def test_the_report_draws_the_measure_and_says_which_draws_it_leaves_out(
        self, run: Path, tmp_path: Path
    ) -> None:
        analysed = read_for_analysis(run)
        check_design(analysed.trials)
        results = write_report(
            analysed.trials, tmp_path / "report", analysed.pipeline, records_of=analysed.records
        )
        (undefined,) = results.undefined
        text = (tmp_path / "report" / "report.md").read_text()
        assert (
            f"- No L1 for {undefined.trials} trial(s) of {undefined.subjects} reward draw(s) "
            f"(where theta_0 < {UNDEFINED_BELOW}): those draws are left out of its statistics."
        ) in text
        assert "| L1 | 3 | expert | map |" in text
        assert (tmp_path / "report" / "other_measures.png").is_file()
        trials = pd.read_csv(tmp_path / "report" / "trials.csv")
        assert "reward_l1" in trials.columns


def test_the_measure_is_unregistered_after_its_tests() -> None:
    """Runs after the class's tests (pytest keeps their order in a file), whose fixture has
    removed the measure again."""
    assert "reward_l1" not in MEASURES


def test_a_name_is_registered_once() -> None:
    regret = MEASURES["regret"]
    with pytest.raises(ValueError, match="a measure named 'regret' is already registered"):
        register_measure("regret", Measure("x:y", label="x", short="x", unit="x"))
    assert MEASURES["regret"] is regret


def test_the_paper_s_three_are_registered_and_analysed_in_its_order() -> None:
    assert PAPER_MEASURES == ("regret", "kl", "reward_l2")
    assert analysed_measures()[:3] == PAPER_MEASURES
    assert list(MEASURES)[:4] == [*PAPER_MEASURES, "regret_under_estimate"]
    assert "regret_under_estimate" not in analysed_measures()


def test_a_measure_json_cannot_hold_is_refused_naming_the_trial(tmp_path: Path) -> None:
    from test_logs_writer import PROVENANCE

    from cirl_study.logs.writer import TrialLogWriter

    record = make_record(1)
    for value, shown in ((math.nan, "nan"), (math.inf, "inf")):
        broken = msgspec.structs.replace(record, measures={**record.measures, "kl": value})
        assert f"measures.kl is {shown}, not a finite number" in record_faults(broken)
        with TrialLogWriter(tmp_path / f"{shown}.mcap", PROVENANCE) as log:
            with pytest.raises(
                ValueError,
                match=f"trial {record.trial_id} cannot be logged: measures.kl is {shown}, not a",
            ):
                log.write(broken)
            log.write(record)


@pytest.mark.parametrize(
    ("change", "fault"),
    [
        ({"kl": None}, "measures.kl is null, but every record has a value of it"),
        ({"kl": "1"}, "measures.kl is a str, not a number"),
        ({"kl": True}, "measures.kl is a bool, not a number"),
        ({"regret": -0.5}, "measures.regret is -0.5 < 0"),
        ({"other": 1.0}, "measures.other is not a registered measure"),
    ],
)
def test_measures_that_break_the_registry_are_faults(change: dict, fault: str) -> None:
    measures = {**make_record(1).measures, **change}
    assert measure_faults(measures) == [fault]


def test_rounding_past_a_range_is_tolerated() -> None:
    measures = {**make_record(1).measures, "regret": -1e-12}
    assert measure_faults(measures) == []
    del measures["kl"]
    assert measure_faults(measures) == ["measures has no kl"]


def one_value(outcome: Outcome) -> list[float]:
    """A computation that returns one value whatever the batch."""
    return [1.0]


def test_a_computation_of_another_length_is_refused() -> None:
    measure = Measure(f"{__name__}:one_value", label="x", short="x", unit="x")
    outcome = Outcome(game=None, theta=np.zeros((2, 3)), theta_hat=np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"one_value returned 1 values for 2 trials"):
        measure.computed(outcome)
