"""The typed results (cirl_study.analysis.results.types): a record holds to its contracts
however it is made, every table is a Table with ``to_frame()``, and the per-measure tests are
registered by the fields that hold their rows (cirl_study.analysis.results.registry)."""

from __future__ import annotations

import math
import pickle
from typing import Annotated

import msgspec
import numpy as np
import pandas as pd
import pytest
from analysis_fixtures import pipeline, rows, synthetic_records

from cirl_study.analysis.report.sections import HEADINGS
from cirl_study.analysis.report.study import render_markdown
from cirl_study.analysis.results.per_measure import run_tests
from cirl_study.analysis.results.registry import StudyTest, held_tests, registered
from cirl_study.analysis.results.study import analyse, design_of, with_claims
from cirl_study.analysis.results.types import (
    AnovaEffect,
    CellMean,
    CronbachAlpha,
    PaperSection,
    Probability,
    Record,
    Rows,
    Sphericity,
    StudyResults,
    Table,
    WilcoxonRow,
    checked,
    study_tests,
)
from cirl_study.analysis.table import trial_table
from cirl_study.measure_registry import analysed_measures


@pytest.fixture(scope="module")
def results() -> StudyResults:
    study = analyse(rows(synthetic_records(subjects_per_level=6)), pipeline("synthetic"))
    return with_claims(study, run_id=None, partial=None, theory=None)


def _anova_row(**changes) -> AnovaEffect:
    row = {
        "measure": "kl", "effect": "human", "df1": 2, "df2": 10, "SS": 1.0, "MS": 0.5,
        "F": 2.0, "p": 0.2, "log10_p": math.log10(0.2), "np2": 0.3, "ges": 0.1,
        "sphericity": None,
    }  # fmt: skip
    return AnovaEffect(**(row | changes))


def test_a_record_holds_an_undefined_number_as_none_and_numbers_as_python_numbers():
    row = _anova_row(F=math.nan, p=math.inf, df1=np.int64(2), SS=np.float64(1.5), np2=1)
    assert row.F is None and row.p is None
    assert type(row.df1) is int and type(row.SS) is float and type(row.np2) is float
    alpha = CronbachAlpha(
        raw=0.5, standardised=0.4, ci95=(math.nan, 0.7), ci95_standardised=[0.1, 0.6],
        n_rows=10, n_items=3, items=["a"], rows="r",
    )  # fmt: skip
    assert alpha.ci95 == [None, 0.7]
    assert msgspec.structs.replace(row, ges=-math.inf).ges is None


def test_every_table_is_a_table_built_or_decoded(results):
    assert all(isinstance(table, Table) for table in (results.cells, results.claims))
    assert isinstance(results.paper.wilcoxon, Table)
    decoded = checked(msgspec.to_builtins(results), StudyResults)
    assert decoded == results
    assert isinstance(decoded.paper.tukey_hsd, Table) and decoded.paper.tukey_hsd.row_type
    assert isinstance(decoded.eta_cv.means, Table)
    again = pickle.loads(pickle.dumps(results))
    assert again == results and again.anova.row_type is AnovaEffect


def test_to_frame_has_a_column_per_field_nested_records_flattened():
    sphericity = Sphericity(
        mauchly_w=0.9, mauchly=Probability(p=0.5, log10_p=math.log10(0.5)), gg_epsilon=0.8,
        hf_epsilon=math.inf, gg=Probability(p=0.01, log10_p=-2.0),
        hf=Probability(p=0.02, log10_p=math.log10(0.02)),
    )  # fmt: skip
    table = Table(
        AnovaEffect, [_anova_row(), _anova_row(effect="human:robot", sphericity=sphericity)]
    )
    frame = table.to_frame()
    fields = [f for f in msgspec.structs.fields(AnovaEffect) if f.name != "sphericity"]
    assert list(frame.columns[: len(fields)]) == [f.name for f in fields]
    assert list(frame.columns[len(fields) :]) == [
        "sphericity_mauchly_w", "sphericity_mauchly_p", "sphericity_mauchly_log10_p",
        "sphericity_gg_epsilon", "sphericity_hf_epsilon", "sphericity_gg_p",
        "sphericity_gg_log10_p", "sphericity_hf_p", "sphericity_hf_log10_p",
        "sphericity_reason",
    ]  # fmt: skip
    assert frame["sphericity_gg_p"].tolist()[1] == 0.01
    assert math.isnan(frame["sphericity_gg_p"].tolist()[0])
    assert math.isnan(frame.at[1, "sphericity_hf_epsilon"])  # infinite: undefined
    assert frame["p"].dtype == np.float64 and frame["df1"].tolist() == [2, 2]
    assert list(Table(WilcoxonRow).to_frame().columns) == [
        f.name for f in msgspec.structs.fields(WilcoxonRow)
    ]


def test_a_results_table_as_a_frame_is_the_rows(results):
    frame = results.cells.to_frame()
    assert len(frame) == len(results.cells)
    first = results.cells[0]
    assert frame.iloc[0][["measure", "human", "n"]].tolist() == [
        first.measure,
        first.human,
        first.n,
    ]
    assert frame.iloc[0]["mean"] == first.mean
    kl = results.cells.filter(lambda row: row.measure == "kl")
    assert isinstance(kl, Table) and kl.row_type is CellMean
    assert set(kl.to_frame()["measure"]) == {"kl"}
    claims = results.claims.to_frame()
    assert list(claims["id"]) == [claim.id for claim in results.claims]


def test_the_registered_tests_are_the_fields_that_hold_them():
    keys = list(study_tests())
    assert keys == [
        "anova", "pairwise", "against_baseline",
        "paper.anova", "paper.simple_effects", "paper.tukey_hsd", "paper.wilcoxon",
    ]  # fmt: skip
    assert [test.name for test in registered(PaperSection)] == [
        "anova",
        "simple_effects",
        "tukey_hsd",
        "wilcoxon",
    ]
    for key, test in study_tests().items():
        assert HEADINGS[key] == test.test.heading
        for name in (test.test.compute, test.test.render):
            module, _, function = name.partition(":")
            assert callable(getattr(__import__(module, fromlist=[function]), function)), name


def test_the_report_has_the_section_of_every_registered_test_with_rows(results):
    text = render_markdown(results)
    held = {key for key, _, _ in held_tests(results)}
    assert held == set(study_tests())
    assert "### The paper's mixed ANOVA" in text and "### Wilcoxon signed-rank tests" in text
    # The paper's own design: the whole design's ANOVA is the paper's, pairs of humans its
    # simple effects; their renderers leave those sections out.
    assert "### Repeated-measures ANOVA" not in text and "### Pairwise comparisons" not in text


def _means(frame: pd.DataFrame, measure: str, design) -> list[CellMean]:
    """A test of the test below: each human's mean of ``measure`` at each feature level."""
    from cirl_study.analysis.statistics.procedures import group_mean_rows

    return group_mean_rows(frame, measure, ["num_features", "human", "robot"], CellMean)


def _render(rows: Table[CellMean], results: StudyResults) -> list[str]:
    return [f"{len(rows)} means"]


class WithMeans(Record, kw_only=True):
    """A record registering one test: its field is the whole registration."""

    means: Annotated[
        Rows[CellMean],
        StudyTest("Means", "test_study_tests:_means", "test_study_tests:_render"),
    ]


def test_a_field_registers_a_test_computed_for_every_measure():
    (test,) = registered(WithMeans)
    assert (test.name, test.row_type) == ("means", CellMean)
    records = synthetic_records(subjects_per_level=4)
    table = trial_table(rows(records))
    main = table[table["block"] == "main"]
    tested = WithMeans(**run_tests(WithMeans, main, design_of(table, pipeline("synthetic"))))
    assert isinstance(tested.means, Table)
    measures = list(dict.fromkeys(row.measure for row in tested.means))
    assert measures == [m for m in analysed_measures() if main[m].notna().any()]
    assert len(tested.means) == len(measures) * 2 * 2  # two feature levels, two humans
    assert test.test.rendered(tested.means, None) == [f"{len(tested.means)} means"]
