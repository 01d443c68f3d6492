"""Calibration against a target table: the target's parsing, the distances by hand, and the
recovery of a known universe from its own cell means
(``cirl_study.analysis.calibration.results``)."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from cirl_study.analysis.calibration.results import (
    Z_95,
    calibrate,
    cell_means,
    ranked_distances,
    read_target,
)
from cirl_study.analysis.reading import read_for_analysis
from cirl_study.analysis.results.types import TargetCell
from cirl_study.errors import UserError

ROOT = Path(__file__).resolve().parent.parent
HEADER = "measure,num_features,human,value,se\n"


def _target(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "target.csv"
    path.write_text(text, encoding="utf-8")
    return path


def test_a_target_reads_its_cells_and_their_log_scale_uncertainty(tmp_path: Path) -> None:
    path = _target(
        tmp_path,
        "measure,num_features,human,robot,value,se,ci95_low,ci95_high\n"
        "regret,3,expert,,0.5,0.05,,\n"
        "kl,10,best_response,map,2.0,,1.0,4.0\n"
        "reward_l2,3,expert,,3.0,,,\n",
    )
    cells, sha256 = read_target(path)
    assert len(sha256) == 64
    assert cells[0] == TargetCell(
        measure="regret", num_features=3, human="expert", robot=None, value=0.5, log_se=0.1
    )
    assert cells[1].robot == "map"
    assert cells[1].log_se == pytest.approx(math.log(4.0) / (2 * Z_95), rel=1e-15)
    assert cells[2].log_se is None


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("measure,num_features,human,value,colour\n", "column colour is not one of"),
        ("measure,num_features,value\n", "has no column human"),
        (
            "measure,num_features,human,value,value\nregret,3,expert,0.5,0.7\n",
            "target.csv: names the column value twice",
        ),
        (HEADER, "holds no cell"),
        (HEADER + "regrets,3,expert,0.5,\n", "line 2: measure must be one of regret, kl"),
        (HEADER + "regret,0,expert,0.5,\n", "line 2: num_features must be a positive integer"),
        (HEADER + "regret,3.5,expert,0.5,\n", "num_features must be a positive integer"),
        (HEADER + "regret,3,,0.5,\n", "line 2: human is empty"),
        (HEADER + "regret,3,expert,0,\n", "value must be positive (distances are on the log"),
        (HEADER + "regret,3,expert,nan,\n", "value must be finite"),
        (HEADER + "regret,3,expert,x,\n", "value must be a number, got x"),
        (HEADER + "regret,3,expert,0.5,-1\n", "se must be positive"),
        (HEADER + "regret,3,expert,0.5,\nregret,3,expert,0.7,\n", "line 3: repeats the cell"),
        (HEADER + "regret,3,expert,0.5,,7\n", "line 2: has more fields than the header"),
        (
            "measure,num_features,human,value,ci95_low,ci95_high\nkl,3,expert,2,3,4\n",
            "the 95% interval [3, 4] must hold the value",
        ),
        (
            "measure,num_features,human,value,ci95_low\nkl,3,expert,2,1\n",
            "needs both ci95_low and ci95_high",
        ),
        (
            "measure,num_features,human,value,se,ci95_low,ci95_high\nkl,3,expert,2,1,1,3\n",
            "gives both se and a 95% interval",
        ),
    ],
)
def test_a_bad_target_is_one_line_naming_the_file_and_row(
    tmp_path: Path, text: str, message: str
) -> None:
    with pytest.raises(UserError) as error:
        read_target(_target(tmp_path, text))
    assert message in str(error.value)
    assert str(error.value).startswith(str(tmp_path / "target.csv"))
    assert "\n" not in str(error.value)


def test_a_target_that_is_not_a_regular_file_or_not_text_is_refused(tmp_path: Path) -> None:
    (tmp_path / "target.csv").write_bytes(b"measure\xff\n")
    with pytest.raises(UserError, match="not UTF-8 text"):
        read_target(tmp_path / "target.csv")
    (tmp_path / "link.csv").symlink_to(tmp_path / "target.csv")
    with pytest.raises(UserError, match="symbolic link"):
        read_target(tmp_path / "link.csv")


def _cell(measure: str, k: int, human: str, value: float, log_se: float | None) -> TargetCell:
    return TargetCell(
        measure=measure, num_features=k, human=human, robot=None, value=value, log_se=log_se
    )


def test_the_distances_equal_a_hand_computation() -> None:
    target = [_cell("regret", 3, "expert", 1.0, 0.1), _cell("kl", 3, "expert", 4.0, None)]
    regret, kl = ("regret", 3, "expert", "map"), ("kl", 3, "expert", "map")
    means = {
        "near": {regret: (4, 2.0, 2.0), kl: (4, 2.0, 1.0)},
        "far": {regret: (4, 8.0, 0.0), kl: (4, 4.0, 1.0)},
        "lacking": {regret: (4, 1.0, 1.0)},
    }
    studies = {uid: ({"sigma": 1.0}, "map") for uid in means}
    near, far, lacking = ranked_distances(means, studies, target, base="far")
    assert (near.id, far.id, lacking.id) == ("near", "far", "lacking")
    # near: r = ln 2 and ln(1/2); the measured regret's log se is 2 / (2 * sqrt 4) = 0.5.
    assert near.mean_squared_log_ratio == pytest.approx(math.log(2) ** 2, rel=1e-15)
    chi_square = math.log(2) ** 2 / (0.1**2 + 0.5**2)
    assert near.chi_square == pytest.approx(chi_square, rel=1e-15) and near.chi_square_df == 1
    assert near.p == pytest.approx(stats.chi2.sf(chi_square, 1), rel=1e-12)
    assert near.log10_p == pytest.approx(math.log10(near.p), rel=1e-12)
    # far: r = ln 8 and 0.
    assert far.mean_squared_log_ratio == pytest.approx(math.log(8) ** 2 / 2, rel=1e-15)
    assert far.base and not near.base
    assert lacking.mean_squared_log_ratio is None and lacking.missing == [
        "lacks the cell (kl, K=3, expert)"
    ]


def test_a_cell_no_universe_measures_is_refused() -> None:
    target = [_cell("regret", 5, "expert", 1.0, None)]
    means = {"u": {("regret", 3, "expert", "map"): (4, 2.0, 2.0)}}
    with pytest.raises(UserError, match=r"measures the target's cell \(regret, K=5, expert\)"):
        ranked_distances(means, {"u": ({}, "map")}, target, base=None)


NOISE = 0.05
"""The noise on the log scale of the recovery test: every cell of the target is a
universe's own mean times ``exp(N(0, NOISE^2))``."""


def test_calibration_recovers_each_committed_universe_from_its_own_noisy_means() -> None:
    results = json.loads((ROOT / "reports" / "multiverse" / "results.json").read_text())
    universes = results["universes"]
    assert len(universes) >= 20
    means = {
        u["id"]: {
            (c["measure"], c["num_features"], c["human"], c["robot"]): (c["n"], c["mean"], c["sd"])
            for c in u["cells"]
        }
        for u in universes
    }
    studies = {u["id"]: (u["settings"], u["settings"]["robot"]) for u in universes}
    rng = np.random.default_rng(29)
    for truth in universes:
        target = [
            _cell(measure, k, human, mean * math.exp(rng.normal(0.0, NOISE)), NOISE)
            for (measure, k, human, _), (_, mean, _) in means[truth["id"]].items()
        ]
        nearest = ranked_distances(means, studies, target, base=None)[0]
        assert nearest.id == truth["id"]
        assert nearest.mean_squared_log_ratio < 4 * NOISE**2


def test_a_single_study_is_calibrated_as_one_universe(smoke_run: Path, tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from cirl_study.api import load_trials
    from cirl_study.cli import app

    table = load_trials(smoke_run)
    cell = table[(table["block"] == "main") & (table["num_features"] == 3)]
    expert = float(cell[cell["human"] == "expert"]["kl"].mean())
    target = _target(tmp_path, f"measure,num_features,human,value\nkl,3,expert,{2 * expert!r}\n")
    out = tmp_path / "calibration"
    command = ["calibrate", str(smoke_run), "--target", str(target), "--out", str(out)]
    result = CliRunner().invoke(app, command)
    assert result.exit_code == 0, result.output
    results = json.loads((out / "results.json").read_text())
    (universe,) = results["universes"]
    assert universe["id"] == "" and results["axes"] == []
    assert universe["mean_squared_log_ratio"] == pytest.approx(math.log(2) ** 2, rel=1e-12)
    assert "nearest the run, D = 0.4805 (within a factor of 2)" in result.stdout


def test_a_single_study_is_calibrated_on_regret_under_the_estimate(
    smoke_run: Path, tmp_path: Path
) -> None:
    from cirl_study.api import load_trials

    table = load_trials(smoke_run)
    cell = table[(table["block"] == "main") & (table["num_features"] == 3)]
    expert = cell[cell["human"] == "expert"]
    measured = float(expert["regret_under_estimate"].mean())
    assert measured > 0 and measured != float(expert["regret"].mean())
    target = _target(
        tmp_path,
        f"measure,num_features,human,value\nregret_under_estimate,3,expert,{3 * measured!r}\n",
    )
    cells, _ = read_target(target)
    analysed = read_for_analysis(smoke_run)
    results = calibrate(
        analysed.trials, analysed.pipeline, cells, target_file="t.csv", target_sha256="0",
        run_id=analysed.run_id,
    )  # fmt: skip
    (universe,) = results.universes
    assert universe.mean_squared_log_ratio == pytest.approx(math.log(3) ** 2, rel=1e-12)


def test_a_cell_whose_trials_lack_a_measure_is_missing() -> None:
    table = pd.DataFrame(
        {
            "universe": [None, None],
            "num_features": [3, 3],
            "human": ["expert", "expert"],
            "robot": ["map", "map"],
            **{measure: [1.0, 2.0] for measure in ("regret", "kl", "reward_l2")},
            "regret_under_estimate": [float("nan"), float("nan")],
            "order_agreement": [0.5, 1.0],
        }
    )
    means = cell_means(table)[""]
    assert means[("regret", 3, "expert", "map")] == (2, 1.5, pytest.approx(math.sqrt(0.5)))
    assert ("regret_under_estimate", 3, "expert", "map") not in means


def test_the_calibrate_command_reports_a_target_on_regret_under_the_estimate(
    smoke_run: Path, tmp_path: Path
) -> None:
    """Every registered measure may be a target, and the report names it as the registry does
    (the report's table of target cells once knew only the paper's three)."""
    from typer.testing import CliRunner

    from cirl_study.api import load_trials
    from cirl_study.cli import app

    table = load_trials(smoke_run)
    cell = table[(table["block"] == "main") & (table["num_features"] == 10)]
    measured = float(cell[cell["human"] == "best_response"]["regret_under_estimate"].mean())
    target = _target(
        tmp_path,
        "measure,num_features,human,value\n"
        f"regret_under_estimate,10,best_response,{measured / 2!r}\n",
    )
    out = tmp_path / "calibration"
    command = ["calibrate", str(smoke_run), "--target", str(target), "--out", str(out)]
    result = CliRunner().invoke(app, command)
    assert result.exit_code == 0, result.output
    (universe,) = json.loads((out / "results.json").read_text())["universes"]
    assert universe["mean_squared_log_ratio"] == pytest.approx(math.log(2) ** 2, rel=1e-12)
    assert "| regret under the estimate | 10 | `best_response` |" in (out / "report.md").read_text()
    assert (out / "calibration.png").is_file()


ASCENT_MULTIVERSE = """
[gradient_ascent]
steps = 30
learning_rate = 0.1

[multiverse.cross]
robot = ["map", "gradient_ascent"]
ascent_steps = [30, 300]
sigma = [0.75, 1.5]
"""
"""Six universes: two of the map robot, which lacks the gradient-ascent settings, and four of
the gradient-ascent robot."""


@pytest.fixture(scope="module")
def ascent_calibration(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """The calibration report of a multiverse of the map and gradient-ascent robots against
    the cell means of one of its gradient-ascent universes, and that universe's id."""
    import sys

    from typer.testing import CliRunner

    from cirl_study.api import load_trials
    from cirl_study.cli import app
    from cirl_study.study.engines import LocalEngine
    from cirl_study.study.pipeline_file import load_pipeline
    from cirl_study.study.runner import run_pipeline

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from test_multiverse import multiverse_text

    directory = tmp_path_factory.mktemp("ascent-calibration")
    (directory / "mva.toml").write_text(multiverse_text(ASCENT_MULTIVERSE, "mva"))
    pipeline = load_pipeline(directory / "mva.toml")
    run_pipeline(pipeline, directory / "run", LocalEngine(1))
    source = next(u.id for u in pipeline.multiverse.universes if "ga_steps=30," in u.id)
    table = load_trials(directory / "run")
    main = table[(table["block"] == "main") & (table["universe"] == source)]
    rows = [HEADER.strip()]
    for (k, human), cell in main.groupby(["num_features", "human"]):
        for measure in ("regret", "kl"):
            rows.append(f"{measure},{k},{human},{float(cell[measure].mean())!r},0.1")
    target = _target(directory, "\n".join(rows) + "\n")
    out = directory / "calibration"
    command = ["calibrate", str(directory / "run"), "--target", str(target), "--out", str(out)]
    result = CliRunner().invoke(app, command)
    assert result.exit_code == 0, result.output
    return out, source


def test_a_setting_that_does_not_apply_reads_n_a(ascent_calibration: tuple[Path, str]) -> None:
    out, _ = ascent_calibration
    text = (out / "report.md").read_text(encoding="utf-8")
    assert "–" not in text
    assert re.search(r"^\| `ascent_steps` \| n/a( \(best\))? \| 2 \|", text, flags=re.MULTILINE)
    nearest = text.split("## The nearest universes")[1].split("\n## ")[0]
    assert "n/a: the setting does not apply (the universe's robot lacks it)." in nearest
    assert re.search(r"\| `map` \| n/a \| n/a \|$", nearest, flags=re.MULTILINE)
    universes = pd.read_csv(out / "universes.csv")
    lacking = universes[universes["robot"] == "map"]
    assert len(lacking) == 2 and lacking["ascent_steps"].isna().all()


def test_each_universe_of_the_table_and_figure_is_named(
    ascent_calibration: tuple[Path, str],
) -> None:
    from cirl_study.analysis.calibration.report import SHOWN, comparison_frame, short_labels
    from cirl_study.analysis.results.types import CalibrationResults, checked

    out, source = ascent_calibration
    results = checked(json.loads((out / "results.json").read_text()), CalibrationResults)
    shown = results.universes[:SHOWN]
    labels = short_labels(list(shown))
    assert labels[0] == "sigma=0.75,ga_steps=30" and source == shown[0].id
    assert len(set(labels)) == SHOWN and all(len(label) <= 40 for label in labels)
    assert all(label.startswith("sigma=") for label in labels)
    text = (out / "report.md").read_text(encoding="utf-8")
    legend = text.split("`#k` is the universe of rank k:")[1].split("\n## ")[0]
    for rank, (universe, label) in enumerate(zip(shown, labels, strict=True), start=1):
        assert f"| #{rank} | `{label}` | `{universe.id}` |" in legend
    frame = comparison_frame(results)
    assert frame.groupby("rank")["universe"].first().tolist() == labels


def test_every_universes_cell_means_are_a_table(ascent_calibration: tuple[Path, str]) -> None:
    from cirl_study.analysis.calibration.report import CELL_COLUMNS

    out, _ = ascent_calibration
    results = json.loads((out / "results.json").read_text())
    cells = pd.read_csv(out / "cells.csv", keep_default_na=False, na_values=[""])
    assert list(cells.columns) == CELL_COLUMNS
    expected = [
        (u["id"], rank, c["measure"], c["num_features"], c["human"], c["robot"], c["n"],
         c["measured"], c["target"])
        for rank, u in enumerate(results["universes"], start=1)
        for c in u["cells"]
    ]  # fmt: skip
    assert len(expected) == 6 * len(results["target"])
    got = cells[CELL_COLUMNS[:9]].itertuples(index=False, name=None)
    assert [tuple(row) for row in got] == expected
    assert (cells["n"] == 4).all()
    assert "[`cells.csv`](cells.csv)" in (out / "report.md").read_text(encoding="utf-8")


def test_a_single_study_is_the_run_in_the_legend_and_cells(smoke_run: Path, tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from cirl_study.cli import app

    target = _target(tmp_path, HEADER + "kl,3,expert,0.5,\nregret,10,best_response,0.1,0.01\n")
    out = tmp_path / "calibration"
    command = ["calibrate", str(smoke_run), "--target", str(target), "--out", str(out)]
    result = CliRunner().invoke(app, command)
    assert result.exit_code == 0, result.output
    assert "| #1 | `the run` | the run |" in (out / "report.md").read_text(encoding="utf-8")
    cells = pd.read_csv(out / "cells.csv")
    assert cells["universe"].isna().all() and cells["rank"].tolist() == [1, 1]
    assert cells[["measure", "n"]].values.tolist() == [["kl", 4], ["regret", 4]]
