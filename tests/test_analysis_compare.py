"""Reports compared by value: numbers within the tolerance, text exactly, figures nearly."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from cirl_study.analysis.compare import Tolerance, compare_reports
from cirl_study.cli import app

RESULTS = {
    "pipeline": "paper",
    "anova": [{"measure": "kl", "F": 3716.25, "p": 1e-300, "df1": 1}],
    "claims": [{"reproduced": True, "verdict": "✅ reproduced"}],
    "figure1": {"subject": "main-k03-s0042", "regret_expert": 0.25, "note": None},
}
TRIALS = "trial_id,policy,eta,regret\nmain:a,expert,,0.5\nmain:a,best_response,0.316,0.125\n"


def report(directory: Path, results: object = None, trials: str = TRIALS) -> Path:
    directory.mkdir()
    (directory / "results.json").write_text(json.dumps(RESULTS if results is None else results))
    (directory / "trials.csv").write_text(trials)
    (directory / "report.md").write_text("# Report\n")
    return directory


def scaled(value: object, factor: float) -> object:
    """``value`` with every float multiplied by ``factor``."""
    if isinstance(value, dict):
        return {key: scaled(item, factor) for key, item in value.items()}
    if isinstance(value, list):
        return [scaled(item, factor) for item in value]
    return value * factor if isinstance(value, float) else value


def test_identical_reports_agree(tmp_path: Path) -> None:
    assert compare_reports(report(tmp_path / "a"), report(tmp_path / "b")) == []


@pytest.mark.parametrize(("factor", "same"), [(1 + 1e-12, True), (1 + 1e-7, False)])
def test_numbers_agree_within_the_relative_tolerance(
    tmp_path: Path, factor: float, same: bool
) -> None:
    differences = compare_reports(
        report(tmp_path / "a"), report(tmp_path / "b", scaled(RESULTS, factor))
    )
    assert (differences == []) is same
    if not same:
        assert "results.json.anova[0].F: 3716.25 != " in differences[0]


def test_tiny_numbers_fall_back_on_the_absolute_tolerance() -> None:
    assert Tolerance(rtol=1e-9, atol=1e-12).agree(0.0, 5e-13)
    assert not Tolerance(rtol=1e-9, atol=1e-12).agree(0.0, 5e-12)
    assert Tolerance().agree(float("nan"), float("nan"))
    assert not Tolerance().agree(float("nan"), 1.0)
    assert Tolerance().agree(float("inf"), float("inf"))
    assert not Tolerance().agree(float("inf"), float("-inf"))
    assert not Tolerance().agree(float("inf"), 1e308)


def test_an_expected_report_without_its_text_is_a_difference(tmp_path: Path) -> None:
    a, b = report(tmp_path / "a"), report(tmp_path / "b")
    (a / "report.md").unlink()
    assert compare_reports(a, b) == ["report.md: missing from the expected report"]


@pytest.mark.parametrize(
    ("results", "trials", "expected"),
    [
        ({**RESULTS, "pipeline": "smoke"}, TRIALS, "results.json.pipeline: 'paper' != 'smoke'"),
        ({**RESULTS, "extra": 1}, TRIALS, "results.json: keys ['extra'] are in only one report"),
        (
            {**RESULTS, "claims": [{"reproduced": False, "verdict": "✅ reproduced"}]},
            TRIALS,
            "results.json.claims[0].reproduced: True != False",
        ),
        (RESULTS, TRIALS.replace("0.125", "0.25"), "trials.csv row 3 (main:a): regret 0.125"),
        (RESULTS, TRIALS.replace("expert,", "oracle,"), "trials.csv row 2 (main:a): policy"),
        (RESULTS, TRIALS.rsplit("\n", 2)[0] + "\n", "trials.csv: 2 rows != 1 rows"),
    ],
)
def test_everything_else_must_be_equal(
    tmp_path: Path, results: object, trials: str, expected: str
) -> None:
    differences = compare_reports(report(tmp_path / "a"), report(tmp_path / "b", results, trials))
    assert any(d.startswith(expected) for d in differences), differences


def test_command_line(tmp_path: Path) -> None:
    a, b = report(tmp_path / "a"), report(tmp_path / "b", scaled(RESULTS, 1 + 1e-6))
    same = CliRunner().invoke(app, ["compare", str(a), str(a)])
    assert same.exit_code == 0 and same.stdout.endswith("the same at rtol=1e-09, atol=1e-12\n")
    assert same.stdout.startswith(f"{a} vs {a}: ")
    in_order = CliRunner().invoke(app, ["compare", str(a), str(b)])
    assert f"{a} vs {b}: different" in in_order.stdout  # EXPECTED first, as given
    loose = CliRunner().invoke(app, ["compare", str(a), str(b), "--rtol", "1e-5"])
    assert loose.exit_code == 0
    strict = CliRunner().invoke(app, ["compare", str(a), str(b)])
    assert strict.exit_code == 1 and "different (2 differences)" in strict.stdout
    missing = CliRunner().invoke(app, ["compare", str(a), str(tmp_path / "nowhere")])
    assert missing.exit_code == 2 and missing.stderr.startswith("error: ")


def test_report_text_must_be_identical(tmp_path: Path) -> None:
    a, b = report(tmp_path / "a"), report(tmp_path / "b")
    (a / "report.md").write_text("# Report\n\nF = 76.73\n")
    (b / "report.md").write_text("# Report\n\nF = 76.74\n")
    assert compare_reports(a, b) == ["report.md line 3: 'F = 76.73' != 'F = 76.74'"]
    (b / "report.md").write_text("# Report\n\nF = 76.73\n")
    assert compare_reports(a, b) == []


def test_figures_agree_within_the_image_tolerance(tmp_path: Path) -> None:
    from matplotlib.image import imsave

    a, b = report(tmp_path / "a"), report(tmp_path / "b")
    image = np.random.default_rng(0).uniform(size=(100, 100, 3))
    imsave(a / "figure.png", image)
    nudged = image.copy()
    nudged[0, :5] = 1.0 - nudged[0, :5]  # 5 of 10,000 pixels: anti-aliasing
    imsave(b / "figure.png", nudged)
    assert compare_reports(a, b) == []
    nudged[:10] = 1.0 - nudged[:10]  # a tenth of the figure
    imsave(b / "figure.png", nudged)
    (difference,) = compare_reports(a, b)
    assert difference.startswith("figure.png: ") and "% of the pixels differ" in difference
    (b / "figure.png").unlink()
    assert compare_reports(a, b) == ["figure.png: missing"]
