"""The report directory (cirl_study.analysis.report.study.write_report)."""

from __future__ import annotations

import json
import random
import re
from pathlib import Path

import msgspec
import pandas as pd
import pingouin as pg
import pytest
from analysis_fixtures import pipeline, records_of, rows, synthetic_records

from cirl_study.analysis.report import figures
from cirl_study.analysis.report import study as report
from cirl_study.analysis.report.markdown import anchor
from cirl_study.analysis.report.study import write_report
from cirl_study.analysis.results.study import estimates
from cirl_study.analysis.table import trial_table
from cirl_study.errors import UserError
from cirl_study.measure_registry import analysed_measures
from cirl_study.record import TrialRecord
from cirl_study.study.eta_cv import choose_etas

FIGURES = {"figure1_reward_maps", "figure2_measures", "other_measures", "figure2_lambda", "eta_cv"}
FILES = {
    "report.md",
    "results.json",
    "trials.csv",
    "provenance.json",
    *(f"{figure}.{kind}" for figure in FIGURES for kind in ("png", "svg")),
}
PROVENANCE = {"report": {"git_commit": "abc"}}
PAPER = pipeline("paper")


def _plain_report(*args, **kwargs) -> dict:
    """What :func:`write_report` returns, as ``results.json`` stores it."""
    return msgspec.to_builtins(write_report(*args, **kwargs))


@pytest.fixture(scope="module")
def records() -> list[TrialRecord]:
    return synthetic_records(subjects_per_level=8)


@pytest.fixture(scope="module")
def reports(records, tmp_path_factory) -> tuple[Path, Path]:
    """The same records written twice, the second time shuffled, to two directories."""
    first = tmp_path_factory.mktemp("first") / "paper"
    second = tmp_path_factory.mktemp("second") / "paper"
    write_report(rows(records), first, PAPER, records_of=records_of(records), provenance=PROVENANCE)
    shuffled = records[:]
    random.Random(3).shuffle(shuffled)
    write_report(
        rows(shuffled), second, PAPER, records_of=records_of(shuffled), provenance=PROVENANCE
    )
    return first, second


def test_the_report_is_byte_identical_for_identical_trials(reports):
    first, second = reports
    assert {path.name for path in first.iterdir()} == FILES
    for name in FILES:
        assert (first / name).read_bytes() == (second / name).read_bytes(), name


def test_no_machine_paths_in_the_report(reports):
    first, _ = reports
    for name in ("report.md", "results.json", "trials.csv"):
        text = (first / name).read_text(encoding="utf-8")
        assert str(first.parent) not in text and "/tmp" not in text


def test_results_json_holds_every_section_at_full_precision(reports, records):
    first, _ = reports
    results = json.loads((first / "results.json").read_text(encoding="utf-8"))
    assert {"anova", "cells", "lambda_sweep", "eta_cv", "claims", "paper"} <= set(results)
    paper = results["paper"]
    assert {"raw", "standardised", "ci95", "rows"} <= set(paper["cronbach_alpha"])
    assert "main block" in paper["cronbach_alpha"]["rows"]
    effects = ("num_features", "human", "human:num_features")
    for anova in (results["anova"], paper["anova"]):
        for row in anova:
            assert {"measure", "effect", "df1", "df2", "F", "p", "log10_p", "np2", "ges"} <= set(
                row
            )
        assert {(r["measure"], r["effect"]) for r in anova} == {
            (m, e) for m in analysed_measures() for e in effects
        }
    table = trial_table(rows(records))
    main = table[table["block"] == "main"]
    expected = pg.mixed_anova(
        data=main, dv="kl", within="human", between="num_features", subject="subject"
    ).set_index("Source")
    got = {r["effect"]: r for r in paper["anova"] if r["measure"] == "kl"}
    for effect, source in zip(effects, ("num_features", "human", "Interaction"), strict=True):
        assert got[effect]["F"] == pytest.approx(expected.at[source, "F"], rel=1e-12)
        assert got[effect]["p"] == pytest.approx(expected.at[source, "p_unc"], rel=1e-9)
    assert results["anova"] == paper["anova"]  # the paper's design: one robot, its two humans
    assert all(
        isinstance(claim["reproduced"], bool) for claim in results["claims"] if claim["tested"]
    )
    assert results["eta_cv"]["chosen"] and results["lambda_sweep"]


def test_the_chosen_eta_is_the_runs_choice_and_the_main_block_used_it(reports, records):
    first, _ = reports
    results = json.loads((first / "results.json").read_text(encoding="utf-8"))
    choices = choose_etas(rows(records))
    assert results["eta_cv"]["chosen"] == [
        {"num_features": k, "eta": c.eta, "mean": c.means[c.eta]}
        for (_, _, k), c in sorted(choices.items())
    ]
    assert results["eta_cv"]["main_block"] == [
        {"num_features": k, "main_etas": [1.0], "chosen_eta": c.eta, "agree": True}
        for (_, _, k), c in sorted(choices.items())
    ]
    assert [c.eta for c in choices.values()] == [1.0, 1.0]
    text = (first / "report.md").read_text(encoding="utf-8")
    assert "The main block used the cross-validated η." in text
    assert "not played with the cross-validated η" not in text


def test_a_main_block_played_with_another_eta_is_flagged(records, tmp_path):
    """The main block's best response at 10 features played with eta = 10, cross-validated 1."""
    changed = [
        msgspec.structs.replace(r, eta=10.0)
        if r.block == "main" and r.human == "best_response" and r.num_features == 10
        else r
        for r in records
    ]
    results = _plain_report(rows(changed), tmp_path, PAPER, records_of=records_of(changed))
    assert results["eta_cv"]["main_block"] == [
        {"num_features": 3, "main_etas": [1.0], "chosen_eta": 1.0, "agree": True},
        {"num_features": 10, "main_etas": [10.0], "chosen_eta": 1.0, "agree": False},
    ]
    section = (tmp_path / "report.md").read_text(encoding="utf-8").split("## Eta")[1]
    sentence = (
        "**The main block's best response was not played with the cross-validated η**: "
        "η = 10 at 10 features (cross-validated: η = 1)."
    )
    assert sentence in section
    assert "The main block used the cross-validated η." not in section


def test_trials_csv_is_the_trial_table(reports, records):
    first, _ = reports
    written = pd.read_csv(first / "trials.csv", dtype={"subject": str})
    table = trial_table(rows(records))
    assert list(written.columns) == list(table.columns)
    assert written["trial_id"].tolist() == table["trial_id"].tolist()
    assert written["reward_l2"].tolist() == table["reward_l2"].tolist()


def test_trials_csv_is_the_same_made_in_memory_and_written_row_by_row(
    reports, records, tmp_path, monkeypatch
):
    first, _ = reports
    assert len(records) <= report.CSV_IN_MEMORY_ROWS  # the fixture's was made in memory
    monkeypatch.setattr(report, "CSV_IN_MEMORY_ROWS", 0)
    write_report(rows(records), tmp_path, PAPER, records_of=records_of(records))
    assert (tmp_path / "trials.csv").read_bytes() == (first / "trials.csv").read_bytes()


def test_every_claim_has_a_verdict_and_every_link_resolves(reports):
    first, _ = reports
    text = (first / "report.md").read_text(encoding="utf-8")
    results = json.loads((first / "results.json").read_text(encoding="utf-8"))
    claims_section = text.split("## Claims\n")[1].split("\n## ")[0]
    numbered = re.findall(r"^\| (\d+) \|", claims_section, flags=re.MULTILINE)
    assert numbered == [str(k) for k in range(1, len(results["claims"]) + 1)]
    assert len(results["claims"]) == 12  # no theory claims given here
    judged = claims_section.split("### Claims on this run's data")[1].split("### ")[0]
    verdicts = re.findall(r"(✅ reproduced|❌ not reproduced|💬 answered)", judged)
    assert len(verdicts) == sum(claim["tested"] for claim in results["claims"])
    assert "### Theorems checked exactly" not in claims_section
    anchors = {anchor(line.lstrip("#")) for line in text.splitlines() if line.startswith("#")}
    for target in re.findall(r"\]\(([^)]+)\)", text):
        if target.startswith("#"):
            assert target[1:] in anchors, target
        else:
            assert (first / target).is_file(), target


def test_a_run_without_sweep_or_cross_validation_still_reports(records, tmp_path):
    out = tmp_path / "report"
    main_only = [record for record in records if record.block == "main"]
    theory = {
        "claims": [
            {
                "id": "office_supplies",
                "source": "paper, section 3.3",
                "claim": "An instructive demonstration.",
                "rule": "computed by the theory module",
                "measurement": "(0, 2) vs (2, 0)",
                "reproduced": True,
            }
        ]
    }
    results = _plain_report(
        rows(main_only),
        out,
        pipeline("main-only"),
        records_of=records_of(main_only),
        theory=theory,
        provenance=PROVENANCE,
    )
    gone = {
        f"{figure}.{kind}" for figure in ("figure2_lambda", "eta_cv") for kind in ("png", "svg")
    }
    assert {path.name for path in out.iterdir()} == FILES - gone
    lambda_claim = next(c for c in results["claims"] if c["id"] == "lambda_intermediate")
    assert not lambda_claim["tested"]
    text = (out / "report.md").read_text(encoding="utf-8")
    not_tested = text.split("### Claims not tested")[1].split("\n## ")[0]
    assert "the run lacks a lambda sweep" in not_tested
    assert "no trials in the `lambda_sweep` block" in text
    assert results["claims"][-1]["id"] == "office_supplies"
    assert results["theory"] == theory
    assert results["eta_cv"] == {
        "means": [],
        "uncertainty": [],
        "chosen": [],
        "main_block": [
            {"num_features": k, "main_etas": [1.0], "chosen_eta": None, "agree": None}
            for k in (3, 10)
        ],
    }


def test_an_incomplete_design_writes_nothing(records, tmp_path):
    unpaired = [r for r in records if not (r.block == "main" and r.subject == "k10-s002")]
    unpaired.append(next(r for r in records if r.block == "main" and r.subject == "k10-s002"))
    with pytest.raises(UserError, match="k10-s002"):
        write_report(rows(unpaired), tmp_path / "out", PAPER, records_of=records_of(unpaired))
    assert not (tmp_path / "out").exists()


def test_the_reports_results_are_analyses_whether_its_figures_are_drawn_in_workers_or_here(
    records, tmp_path, monkeypatch
):
    from cirl_study import workers
    from cirl_study.analysis.results.study import analyse

    here = analyse(rows(records), PAPER)
    for cores, name in ((1, "here"), (2, "workers")):
        monkeypatch.setattr(workers, "forkable", lambda: True)
        monkeypatch.setattr(workers, "cores", lambda cores=cores: cores)
        results = write_report(
            rows(records), tmp_path / name, PAPER, records_of=records_of(records)
        )
        assert results.claims  # the report judges the claims; analyse leaves them to it
        assert msgspec.structs.replace(results, claims=here.claims) == here, name


def test_figure2_lambda_draws_every_human_and_robot_of_the_sweep(records):
    """Not only the expert and the best response with the reference robot: the sweep's whole
    table goes to the figure, with the run's humans and robots in its pipeline's order."""
    humans, robots = ("expert", "best_response", "literal"), ("map", "posterior_mean")

    def played(record: TrialRecord, human: str, robot: str) -> TrialRecord:
        return msgspec.structs.replace(
            record, human=human, robot=robot, trial_id=f"{record.trial_id}/{human}/{robot}"
        )

    more = [
        played(record, human, robot)
        for record in records
        for human in ("literal", record.human)
        for robot in robots
        if record.block != "eta_cv"
        and (human, robot) != (record.human, "map")
        and (human != "literal" or record.human == "expert")
    ]
    trials = rows([*records, *more])
    estimated = estimates(trials, trial_table(trials), pipeline("many", humans, robots))
    drawing, (sweep, drawn_humans, drawn_robots) = report._drawings(
        trials, records_of([*records, *more]), estimated
    )["figure2_lambda.png"]
    assert drawing is figures.lambda_curve
    assert (tuple(drawn_humans), tuple(drawn_robots)) == (humans, robots)
    regret = sweep[sweep["measure"] == "regret"]
    assert set(zip(regret["human"], regret["robot"], strict=True)) == {
        (human, robot) for human in humans for robot in robots
    }
