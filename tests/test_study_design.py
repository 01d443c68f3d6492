"""A study of the user's own design: three humans (one registered here) x two robots x one
feature level plays, validates and is analysed like any other, with the corrected ANOVA,
every pairwise comparison and the figure."""

from __future__ import annotations

import json
import struct
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats
from typer.testing import CliRunner

from cirl_study.analysis.report import figures
from cirl_study.cli import app
from cirl_study.core.apprenticeship import Apprenticeship
from cirl_study.core.players import HUMANS, Human, register_human
from cirl_study.logs.validate import validate_run
from cirl_study.measure_registry import analysed_measures
from cirl_study.study.pipeline_file import logged_pipeline

HUMAN_NAMES = '["expert", "best_response", "first_step"]'
SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"


def first_step_expert(
    game: Apprenticeship, theta: np.ndarray, eta: np.ndarray | None, seeds: np.ndarray
) -> np.ndarray:
    """The expert's path for its first step, then staying put: a human who half teaches."""
    expert = HUMANS["expert"].demonstrate(game, theta, eta, seeds)
    path = np.repeat(expert[:, 1:2], expert.shape[1], axis=1)
    path[:, 0] = expert[:, 0]
    return path


@pytest.fixture(scope="module")
def study(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, str, dict]]:
    """The run, analyze's output and the results of a 3 x 2 x 1 study."""
    register_human("first_step", Human(first_step_expert, takes_eta=False))
    try:
        root = tmp_path_factory.mktemp("study")
        text = SMOKE.read_text(encoding="utf-8")
        for old, new in (
            ('name = "smoke"', 'name = "three-humans"'),
            ("feature_levels = [3, 10]", "feature_levels = [3]"),
            ('humans = ["expert", "best_response"]', f"humans = {HUMAN_NAMES}"),
            ('robots = ["map"]', 'robots = ["map", "posterior_mean"]'),
            ("[main]\nsubjects = 4", "[main]\nsubjects = 8"),
        ):  # fmt: skip
            assert old in text
            text = text.replace(old, new)
        pipeline = root / "three-humans.toml"
        pipeline.write_text(text, encoding="utf-8")
        run = root / "run"
        played = CliRunner().invoke(app, ["run", str(pipeline), "--out", str(run)])
        assert played.exit_code == 0, played.output
        out = root / "report"
        analysed = CliRunner().invoke(app, ["analyze", str(run), "--out", str(out)])
        assert analysed.exit_code == 0, analysed.output
        results = json.loads((out / "results.json").read_text(encoding="utf-8"))
        yield run, analysed.output, results
    finally:
        del HUMANS["first_step"]


def test_the_study_plays_and_validates(study: tuple[Path, str, dict]) -> None:
    run, _, results = study
    assert validate_run(run, logged_pipeline).ok
    assert results["design"]["humans"] == ["expert", "best_response", "first_step"]
    assert results["design"]["robots"] == ["map", "posterior_mean"]
    assert results["design"]["feature_levels"] == [3]


def test_the_anova_has_both_within_factors_and_corrects_the_three_level_one(
    study: tuple[Path, str, dict],
) -> None:
    _, _, results = study
    for measure in analysed_measures():
        rows = {r["effect"]: r for r in results["anova"] if r["measure"] == measure}
        assert set(rows) == {"human", "robot", "human:robot"}  # one level: no between factor
        assert (rows["human"]["df1"], rows["human"]["df2"]) == (2, 14)
        assert (rows["robot"]["df1"], rows["robot"]["df2"]) == (1, 7)
        assert rows["robot"]["sphericity"] is None
        sphericity = rows["human"]["sphericity"]
        assert 0.5 <= sphericity["gg_epsilon"] <= 1.0
        row, epsilon = rows["human"], sphericity["gg_epsilon"]
        corrected = stats.f.sf(row["F"], epsilon * row["df1"], epsilon * row["df2"])
        assert sphericity["gg"]["p"] == pytest.approx(corrected, rel=1e-12)
        assert rows["human"]["log10_p"] == pytest.approx(np.log10(rows["human"]["p"]))


def test_every_pair_is_compared_in_every_cell(study: tuple[Path, str, dict]) -> None:
    _, _, results = study
    pairs = results["pairwise"]
    humans = [r for r in pairs if r["factor"] == "human"]
    robots = [r for r in pairs if r["factor"] == "robot"]
    measures = len(analysed_measures())
    assert len(humans) == measures * 3 * 2  # measures x pairs of humans x robots
    assert len(robots) == measures * 1 * 3  # measures x pairs of robots x humans
    assert {(r["level_a"], r["level_b"]) for r in robots} == {("map", "posterior_mean")}
    # order agreement may not differ at all between two robots: a test of no variance, p null
    assert all(r["n"] == 8 and (r["p"] is None or r["p_holm"] >= r["p"]) for r in pairs)
    baseline = results["against_baseline"]
    assert {r["level"] for r in baseline} == {"best_response", "first_step"}


def test_the_report_shows_the_design_and_the_figure(study: tuple[Path, str, dict]) -> None:
    run, output, results = study
    assert output.startswith("report of ")
    out = run.parent / "report"
    assert (out / "cell_means.png").stat().st_size > 0 and (out / "cell_means.svg").is_file()
    report = (out / "report.md").read_text(encoding="utf-8")
    assert report.startswith("# Report: `three-humans`")
    for heading in (
        "## Repeated-measures ANOVA",
        "## Pairwise comparisons",
        "## Lambda sweep",
    ):
        assert heading in report
    claims = {claim["id"]: claim for claim in results["claims"]}
    assert claims["paper_best_response"]["tested"] and claims["human_effect"]["tested"]
    assert not claims["interaction_kl_l2"]["tested"]  # one feature level
    assert "at least 2 feature levels" in claims["interaction_kl_l2"]["measurement"]
    assert {r["human"] for r in results["lambda_sweep"]} == {
        "expert",
        "best_response",
        "first_step",
    }


@pytest.mark.parametrize(("humans", "robots", "levels"), [(2, 1, 1), (5, 3, 2), (8, 4, 2)])
def test_the_cell_figure_keeps_its_panels_readable(humans: int, robots: int, levels: int) -> None:
    """From 2 to 8 humans and 1 to 4 robots every panel is at least 3 inches wide: past
    WIDE_CELLS bars a panel the measures go down the figure instead of across."""
    names = [f"human_{i}" for i in range(humans)]
    robot_names = [f"robot_{i}" for i in range(robots)]
    cells = pd.DataFrame(
        {
            "measure": m, "num_features": 3 + 7 * k, "human": h, "robot": r,
            "mean": 0.5, "ci95_low": 0.4, "ci95_high": 0.6,
        }
        for m in analysed_measures() for k in range(levels) for h in names for r in robot_names
    )  # fmt: skip
    png = figures.cell_bars(cells, names, robot_names).png
    width, height = struct.unpack(">II", png[16:24])
    columns = levels if humans * robots > figures.WIDE_CELLS else len(analysed_measures())
    assert width / figures.DPI / columns >= 3.0
    assert height / figures.DPI >= 2.9 * (len(analysed_measures()) if columns == levels else levels)


def test_a_human_identical_to_another_is_analysed_without_an_error(tmp_path: Path) -> None:
    """At eta -> 0 the best response is the expert: every difference between them is 0, so
    their F, p and Wilcoxon test are undefined (null), their claims not reproduced, and no
    warning reaches the user."""
    text = SMOKE.read_text().replace("etas = [0.1, 1.0, 10.0]", "etas = [0.000001]")
    pipeline = tmp_path / "identical.toml"
    pipeline.write_text(text.replace('name = "smoke"', 'name = "identical"'))
    run = tmp_path / "run"
    assert CliRunner().invoke(app, ["run", str(pipeline), "--out", str(run)]).exit_code == 0
    result = CliRunner().invoke(app, ["analyze", str(run)])
    assert result.exit_code == 0, result.output
    assert result.stderr == ""
    results = json.loads((run / "report" / "results.json").read_text())
    human = [row for row in results["anova"] if row["effect"] == "human"]
    measures = len(analysed_measures())
    assert len(human) == measures and all(row["F"] is None and row["p"] is None for row in human)
    wilcoxon = results["paper"]["wilcoxon"]
    assert len(wilcoxon) == 2 * measures and all(row["p"] is None for row in wilcoxon)
    verdicts = {claim["id"]: claim["reproduced"] for claim in results["claims"]}
    assert verdicts["human_effect"] is False and verdicts["tukey_br_ahead"] is False
