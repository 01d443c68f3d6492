"""Logs of every format this version reads are read as the current one
(:mod:`cirl_study.logs.versions`).

``tests/fixtures/logs/format-N-*`` are runs written by the last version of log format ``N``
(their pipeline files beside them), with the trial table that version's ``analyze`` wrote
(``trials-format-N.csv``): read now, they must validate, and give that table in the current
names, number for number.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

import cirl_study
from cirl_study.cli import app
from cirl_study.logs import versions
from cirl_study.logs.reader import read_run
from cirl_study.study.pipeline_file import logged_pipeline
from tests.cli_results import one_line_error

FIXTURES = Path(__file__).parent / "fixtures" / "logs"
FORMAT_5 = sorted(FIXTURES.glob("format-5-*"))
OLD_RUNS = sorted(FIXTURES.glob("format-*"))


def _log_format(run: Path) -> str:
    """The format of a fixture run, from its name ``format-N-...``."""
    return run.name.split("-")[1]


def _in_current_names(table: pd.DataFrame, log_format: str) -> pd.DataFrame:
    """A trial table of ``log_format`` as the current version names it."""
    table = table.rename(columns={"certified": "converged", "policy": "human"})
    if log_format == "5":
        table["robot"] = table["robot"].replace({"literal": "literal_observer"})
    table["trial_id"] = [versions.trial_id(t, log_format) for t in table["trial_id"]]
    # Format 7 logs the second reading of regret; an earlier record reads it as missing.
    if "regret_under_estimate" not in table.columns:
        table.insert(table.columns.get_loc("reward_l2") + 1, "regret_under_estimate", math.nan)
    # Format 8 logs the feature order agreement; an earlier record reads it as missing.
    if "order_agreement" not in table.columns:
        table.insert(
            table.columns.get_loc("regret_under_estimate") + 1, "order_agreement", math.nan
        )
    return table


def test_there_are_runs_of_every_earlier_format() -> None:
    assert [path.name for path in OLD_RUNS] == [
        "format-5-sweep",
        "format-5-teaching",
        "format-6-robots",
        "format-7-ascent",
        "format-8-tiles",
    ]


@pytest.mark.parametrize("run", OLD_RUNS, ids=lambda path: path.name)
def test_a_run_of_an_earlier_format_validates(run: Path) -> None:
    result = CliRunner().invoke(app, ["validate", str(run)])
    assert result.exit_code == 0, result.output
    assert result.output.strip().splitlines()[-1].endswith("design complete")


@pytest.mark.parametrize("run", OLD_RUNS, ids=lambda path: path.name)
def test_a_run_of_an_earlier_format_gives_its_trial_table_in_the_current_names(run: Path) -> None:
    log_format = _log_format(run)
    logged = pd.read_csv(
        run / f"trials-format-{log_format}.csv", keep_default_na=False, na_values=[""]
    )
    want = _in_current_names(logged, log_format).sort_values("trial_id").reset_index(drop=True)
    got = cirl_study.load_trials(run).sort_values("trial_id").reset_index(drop=True)
    # The tables written before the file column lack it: it names the file read now.
    files = {trial: path.name for path, trials in read_run(run, logged_pipeline).files
             for trial in trials}  # fmt: skip
    assert got["file"].tolist() == [files[trial] for trial in got["trial_id"]]
    got = got.drop(columns="file")
    assert list(got.columns) == list(want.columns)
    assert set(got["robot"]) <= {"map", "literal_observer", "posterior_mean", "gradient_ascent"}
    logged = ("regret_under_estimate", "order_agreement")[: max(0, int(log_format) - 6)]
    for column in want.columns:
        if column in ("regret", "kl", "reward_l2", "eta", "rationality", *logged):
            pd.testing.assert_series_equal(
                got[column].astype(float), want[column].astype(float), rtol=1e-15
            )
        elif column in ("universe", "regret_under_estimate", "order_agreement"):
            assert column not in logged
            assert got[column].isna().all() and want[column].isna().all()
        else:
            assert got[column].astype(str).tolist() == want[column].astype(str).tolist(), column


def test_records_of_an_earlier_format_read_the_second_regret_as_missing() -> None:
    for run in (run for run in OLD_RUNS if _log_format(run) < "7"):
        rows = read_run(run, logged_pipeline).rows
        assert rows and all(row.measure("regret_under_estimate") is None for row in rows)
        assert all(row.measure("regret") >= 0 for row in rows)


def test_a_run_of_format_7_is_analysed() -> None:
    results = cirl_study.analyze(FIXTURES / "format-7-ascent")
    assert results.design.robots == ["map", "gradient_ascent"]


def test_a_measure_a_format_did_not_log_is_left_out_and_said_so() -> None:
    """Format 7 did not log the feature order agreement: its records read it as null, and the
    analysis has no statistics of it, saying so."""
    run = FIXTURES / "format-7-ascent"
    rows = read_run(run, logged_pipeline).rows
    assert rows and all(row.measure("order_agreement") is None for row in rows)
    results = cirl_study.analyze(run)
    (undefined,) = results.undefined
    assert (undefined.measure, undefined.trials) == ("order_agreement", len(rows))
    assert undefined.subjects == len({row.subject for row in rows})
    assert "order_agreement" not in {row.measure for row in [*results.cells, *results.anova]}
    assert {row.measure for row in results.cells} == {"regret", "kl", "reward_l2"}


def test_records_before_format_8_read_a_fixed_horizon_and_no_task() -> None:
    for run in (run for run in OLD_RUNS if _log_format(run) < "8"):
        contents = read_run(run, logged_pipeline)
        records = contents.records({row.trial_id for row in contents.rows})
        assert records and all(r.goals == () and r.task is None for r in records)
        assert {r.features.kind for r in records} == {"rbf"}


def test_a_run_of_format_8_reads_its_policies_as_humans() -> None:
    """Format 8 called the player who demonstrates ``policy``, in the record and in the
    pipeline's ``main.policies``; read now, both are the ``human``."""
    run = FIXTURES / "format-8-tiles"
    contents = read_run(run, logged_pipeline)
    assert {row.human for row in contents.rows} == {"expert", "best_response"}
    assert logged_pipeline(contents.identity).main.humans == ("expert", "best_response")
    results = cirl_study.analyze(run)
    assert results.design.humans == ["expert", "best_response"]
    assert {r.task for r in contents.records({row.trial_id for row in contents.rows})} == {
        "oo",
        "ox",
        "xo",
        None,
    }


def test_a_run_of_format_6_is_analysed() -> None:
    results = cirl_study.analyze(FIXTURES / "format-6-robots")
    assert results.design.robots == ["map", "posterior_mean"]


def test_a_run_of_format_5_is_analysed() -> None:
    results = cirl_study.analyze(FIXTURES / "format-5-teaching")
    assert results.design.humans == ["expert", "best_response", "literal", "pedagogic"]
    assert results.design.robots == ["map", "literal_observer"]


def test_a_run_of_format_5_is_not_resumed(tmp_path: Path) -> None:
    """Its trials were seeded from its own ids: a run is resumed by the version that wrote it.
    Its pipeline file is not one of this version, and the current spelling of it is another
    run."""
    run = tmp_path / "run"
    shutil.copytree(FIXTURES / "format-5-sweep", run)
    before = sorted(path.name for path in run.glob("*.mcap"))
    result = CliRunner().invoke(app, ["run", str(run / "pipeline.toml"), "--out", str(run)])
    assert "game.centres is not a known key" in one_line_error(result)
    renamed = run / "renamed.toml"
    text = (run / "pipeline.toml").read_text()
    renamed.write_text(text.replace("centres =", "centers =").replace("policies =", "humans ="))
    result = CliRunner().invoke(app, ["run", str(renamed), "--out", str(run)])
    assert "made from another version of" in one_line_error(result)
    assert sorted(path.name for path in run.glob("*.mcap")) == before  # nothing written


def test_a_log_of_an_unknown_format_is_refused_in_one_line(tmp_path: Path) -> None:
    run = tmp_path / "run"
    shutil.copytree(FIXTURES / "format-5-sweep", run)
    first = sorted(run.glob("*.mcap"))[0]
    data = first.read_bytes()
    assert data.count(b"log_format") == 1
    # The same length, so only the provenance's value changes (its CRCs no longer hold).
    first.write_bytes(data.replace(b"log_format\x01\x00\x00\x005", b"log_format\x01\x00\x00\x009"))
    result = CliRunner().invoke(app, ["validate", str(run)])
    assert result.exit_code == 1
    assert "Traceback" not in result.output
    assert first.name in result.output


def test_every_readable_format_is_named_and_the_current_one_is_written() -> None:
    assert versions.READABLE[-1] == versions.LOG_FORMAT == "10"
    assert (
        versions.readable("5")
        and versions.readable("6")
        and versions.readable("7")
        and versions.readable("8")
        and not versions.readable("4")
        and not versions.readable("")
    )


def test_read_run_renames_every_record_of_format_5() -> None:
    run = read_run(FIXTURES / "format-5-teaching", logged_pipeline)
    assert {row.robot for row in run.rows} == {"map", "literal_observer"}
    assert all(not row.trial_id.endswith("robot=literal") for row in run.rows)
