"""Reports compared by value: numbers within the tolerance, text exactly, figures nearly."""

from __future__ import annotations

import json
import math
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from cirl_study.analysis.report.compare import Tolerance, compare_reports
from cirl_study.cli import app
from cirl_study.errors import UserError
from cirl_study.escape import terminal

RESULTS = {
    "pipeline": "paper",
    "anova": [{"measure": "kl", "F": 3716.25, "p": 1e-300, "df1": 1}],
    "claims": [{"reproduced": True, "verdict": "✅ reproduced"}],
    "figure1": {"subject": "main-k03-s0042", "regret_expert": 0.25, "note": None},
}
TRIALS = "trial_id,human,eta,regret\nmain:a,expert,,0.5\nmain:a,best_response,0.316,0.125\n"


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
        (RESULTS, TRIALS.replace("expert,", "oracle,"), "trials.csv row 2 (main:a): human"),
        (RESULTS, TRIALS.rsplit("\n", 2)[0] + "\n", "trials.csv: 2 rows != 1 rows"),
    ],
)
def test_everything_else_must_be_equal(
    tmp_path: Path, results: object, trials: str, expected: str
) -> None:
    differences = compare_reports(report(tmp_path / "a"), report(tmp_path / "b", results, trials))
    assert any(d.startswith(expected) for d in differences), differences


def test_the_log_file_of_a_trial_is_not_compared(tmp_path: Path) -> None:
    """Which file holds a trial depends on the workers that played the run, not the trial;
    every other text cell of the row still counts."""
    files = (
        "trial_id,human,eta,regret,file\n"
        "main:a,expert,,0.5,main-1.mcap\nmain:a,best_response,0.316,0.125,main-1.mcap\n"
    )
    a = report(tmp_path / "a", trials=files)
    b = report(tmp_path / "b", trials=files.replace("main-1.mcap", "main-2.mcap"))
    assert compare_reports(a, b) == []
    c = report(tmp_path / "c", trials=files.replace("expert,", "oracle,"))
    assert compare_reports(a, c) == ["trials.csv row 2 (main:a): human expert != oracle"]
    for directory, name in ((a, "main-1"), (b, "main-2")):  # only trials.csv passes it over
        (directory / "universes.csv").write_text(f"universe,file\nu,{name}.mcap\n")
    assert compare_reports(a, b) == ["universes.csv row 2 (u): file main-1.mcap != main-2.mcap"]


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


def test_an_infinite_tolerance_is_a_tolerance(tmp_path: Path) -> None:
    """``--rtol inf`` or ``--atol inf`` of a report against itself: the same (``inf * 0`` is
    no NaN that fails every zero); against another, ``rtol = inf`` still holds an expected 0
    to ``atol``, ``atol = inf`` agrees any finite numbers."""
    zeros = {**RESULTS, "zero": 0.0, "zeros": [0.0, 0, -0.0]}
    a = report(tmp_path / "a", zeros)
    for option in ("--rtol", "--atol"):
        same = CliRunner().invoke(app, ["compare", str(a), str(a), option, "inf"])
        assert same.exit_code == 0, same.output
        assert same.stdout.endswith(": the same at " + ("rtol=inf, atol=1e-12\n" if option ==
                                    "--rtol" else "rtol=1e-09, atol=inf\n"))  # fmt: skip
    b = report(tmp_path / "b", {**scaled(zeros, 1e6), "zero": 1.0})
    loose = CliRunner().invoke(app, ["compare", str(a), str(b), "--rtol", "inf"])
    assert loose.exit_code == 1 and "different (1 differences)" in loose.stdout, loose.stdout
    assert "results.json.zero: 0.0 != 1.0" in loose.stdout
    assert CliRunner().invoke(app, ["compare", str(a), str(b), "--atol", "inf"]).exit_code == 0


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


def compare(expected: Path, got: Path):
    return CliRunner().invoke(app, ["compare", str(expected), str(got)])


def shown_as_is(text: str) -> None:
    """Nothing a terminal would obey rather than show: line breaks only end lines."""
    assert all(line.isprintable() for line in text.splitlines()), repr(text[:500])
    assert "\r" not in text and "\x1b" not in text


def test_the_help_says_what_is_compared_with_what_in_the_order_given() -> None:
    text = " ".join(CliRunner().invoke(app, ["compare", "--help"]).stdout.split())
    assert "Compare the report directory GOT with EXPECTED: every number of results.json" in text
    assert "Each difference names EXPECTED's value first, then GOT's." in text


def test_an_expected_report_without_its_text_differs_on_the_command_line(tmp_path: Path) -> None:
    a, b = report(tmp_path / "a"), report(tmp_path / "b")
    (a / "report.md").unlink()
    result = compare(a, b)
    assert result.exit_code == 1
    assert result.stdout.splitlines() == [
        "report.md: missing from the expected report",
        f"{a} vs {b}: different (1 differences) at rtol=1e-09, atol=1e-12",
    ]


def test_equal_infinities_agree_and_opposite_ones_differ(tmp_path: Path) -> None:
    extremes = {**RESULTS, "F": [math.inf, -math.inf, math.nan], "big": 10**400}
    trials = "trial_id,regret\nmain:a,inf\nmain:b,-inf\nmain:c,nan\n"
    a = report(tmp_path / "a", extremes, trials)
    b = report(tmp_path / "b", extremes, trials)
    assert compare_reports(a, b) == []
    same = compare(a, b)
    assert same.exit_code == 0 and "the same" in same.stdout
    flipped = {**extremes, "F": [-math.inf, -math.inf, math.nan], "big": 10**400 + 1}
    c = report(tmp_path / "c", flipped, trials.replace(",inf", ",-inf"))
    assert compare_reports(a, c) == [
        "results.json.F[0]: inf != -inf",
        f"results.json.big: {terminal(repr(10**400))} != {terminal(repr(10**400 + 1))}",
        "trials.csv row 2 (main:a): regret inf != -inf",
    ]
    assert compare(a, c).exit_code == 1


HOSTILE = "reg\x1b[2J\rret"
"""A name that, printed raw, clears the screen and goes back to the line's start."""


def hostile_report(directory: Path, cell: str) -> Path:
    """A report whose every name and value a difference quotes holds control characters;
    its values vary with ``cell``."""
    report(
        directory,
        {**RESULTS, HOSTILE: f"{cell}\r\x1b[2KOK"},
        f'trial_id,"{HOSTILE}"\n"main:\x1b[31m\r",{cell}\n',
    )
    (directory / "tri\nals.csv").write_text(f"universe,text\nu\x07,{f'{cell}x' * 50_000}\n")
    (directory / "report.md").write_text(f"# Report\n\n\x1b]0;{cell}\x07\n")
    return directory


def test_a_hostile_report_is_quoted_escaped_and_bounded(tmp_path: Path) -> None:
    a = hostile_report(tmp_path / "a\x1b[2J", "1")
    b = hostile_report(tmp_path / "b\r", "2")
    (a / "fig\r\x1b[2Jure.png").write_bytes(b"not looked at: it is missing from GOT")
    (a / "fig\nure.svg").write_text("<svg/>")
    result = compare(a, b)
    assert result.exit_code == 1, result.output
    shown_as_is(result.output)
    assert len(result.output) < 5_000
    lines = result.stdout.splitlines()
    verdict = "different (6 differences) at rtol=1e-09, atol=1e-12"
    assert lines[-1] == f"{terminal(a)} vs {terminal(b)}: {verdict}"
    for escaped in [
        "results.json.reg\\x1b[2J\\rret: '1\\r\\x1b[2KOK' != '2\\r\\x1b[2KOK'",
        "trials.csv row 2 (main:\\x1b[31m\\r): reg\\x1b[2J\\rret 1 != 2",
        "tri\\nals.csv row 2 (u\\x07): text " + "1x" * 100 + "... (100000 characters)",
        "report.md line 3: '\\x1b]0;1\\x07' != '\\x1b]0;2\\x07'",
        "fig\\r\\x1b[2Jure.png: missing",
        "fig\\nure.svg: missing",
    ]:
        assert any(line.startswith(escaped) for line in lines), (escaped, lines)


def _replaced(path: Path, make) -> None:
    """``path`` replaced by what ``make(path)`` makes there: a FIFO, a link, a directory."""
    path.unlink()
    make(path)


@pytest.mark.parametrize(
    ("spoil", "says"),
    [
        (lambda d: (d / "tri\nals.csv").unlink(), "tri\\nals.csv: cannot read: No such file"),
        (lambda d: (d / "trials.csv").write_bytes(b"trial_id\n\xff\xfe\n"), "can't decode"),
        (lambda d: (d / "trials.csv").write_text("a\n" + "x" * 200_000), "field limit"),
        (
            lambda d: (d / "trials.csv").write_text("trial_id,regret,regret\nmain:a,0.5,0.7\n"),
            "trials.csv: cannot read: names the column regret twice",
        ),
        (lambda d: (d / "report.md").write_bytes(b"\xff"), "report.md: cannot read: "),
        (lambda d: (d / "results.json").write_text("[" * 100_000), "results.json: cannot read"),
        (lambda d: (d / "results.json").write_bytes(b'{"\xff": 1}'), "results.json: cannot"),
        (lambda d: (d / "f\r.png").write_bytes(b"\x89PNG\r\n\x1a\n"), "f\\r.png: cannot read: "),
        (lambda d: _replaced(d / "trials.csv", os.mkfifo), "trials.csv: is a FIFO"),
        (
            lambda d: _replaced(d / "report.md", lambda p: p.symlink_to("/dev/zero")),
            "symbolic link",
        ),
        (lambda d: _replaced(d / "results.json", os.mkdir), "results.json: is a directory"),
    ],
)
def test_a_report_that_cannot_be_read_is_one_line(tmp_path: Path, spoil, says: str) -> None:
    a = hostile_report(tmp_path / "a", "1")
    (a / "f\r.png").write_bytes(b"not a PNG file")
    b = hostile_report(tmp_path / "b", "1")
    shutil.copy(a / "f\r.png", b / "f\r.png")
    spoil(b)
    result = compare(a, b)
    assert result.exit_code == 2, result.output
    assert result.stderr.startswith("error: ") and result.stderr.count("\n") == 1, result.stderr
    assert says in result.stderr, result.stderr
    shown_as_is(result.output)


def _with_runs(directory: Path, *run_ids: str) -> Path:
    provenance = {"run": [{"run_id": run_id} for run_id in run_ids], "report": {}}
    (directory / "provenance.json").write_text(json.dumps(provenance))
    return directory


def test_reports_of_different_runs_are_said_to_be_so_first(tmp_path: Path) -> None:
    expected = _with_runs(report(tmp_path / "a"), "paper-1a2b3c4d5e6f")
    got = _with_runs(report(tmp_path / "b", scaled(RESULTS, 2.0)), "smoke-0f9e8d7c6b5a")
    differences = compare_reports(expected, got)
    assert differences[0].startswith(
        "provenance.json: the reports are of different runs (expected: paper-1a2b3c4d5e6f; "
        "got: smoke-0f9e8d7c6b5a)"
    )
    assert len(differences) > 1 and all("provenance" not in d for d in differences[1:])
    same_run = _with_runs(report(tmp_path / "c", scaled(RESULTS, 2.0)), "paper-1a2b3c4d5e6f")
    assert not any("provenance" in d for d in compare_reports(expected, same_run))
    without = report(tmp_path / "d", scaled(RESULTS, 2.0))
    assert not any("provenance" in d for d in compare_reports(expected, without))


def test_what_a_report_would_make_us_allocate_is_bounded_before_it_is(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A results.json of more values than a report holds, and a figure of more pixels than a
    report draws, are refused from their bytes and header, before they are parsed or
    decoded."""
    from cirl_study.analysis.report import compare as module

    monkeypatch.setattr(module, "MAX_JSON_VALUES", 1000)
    a, b = report(tmp_path / "a"), report(tmp_path / "b")
    (b / "results.json").write_text("[" + ",".join(["{}"] * 2000) + "]")
    with pytest.raises(UserError, match=r"results.json: cannot read: up to 4000 values, more"):
        compare_reports(a, b)
    b = report(tmp_path / "c")
    header = b"\x89PNG\r\n\x1a\n" + (13).to_bytes(4, "big") + b"IHDR"
    huge = header + (9000).to_bytes(4, "big") + (9000).to_bytes(4, "big") + b"\x08\x06\0\0\0"
    (a / "f.png").write_bytes(huge)
    (b / "f.png").write_bytes(huge)
    with pytest.raises(UserError, match=r"f.png: cannot read: 9000 x 9000 pixels, more than"):
        compare_reports(a, b)


def test_tables_of_different_lengths_say_so(tmp_path: Path) -> None:
    longer = TRIALS + "main:b,expert,,0.5\n"
    differences = compare_reports(report(tmp_path / "a"), report(tmp_path / "b", trials=longer))
    assert differences == ["trials.csv: 2 rows != 3 rows"]
    differences = compare_reports(report(tmp_path / "c", trials=longer), report(tmp_path / "d"))
    assert differences == ["trials.csv: 3 rows != 2 rows"]
