"""`cirl-study run` refuses a bad pipeline with one line naming file and key, exit code 2."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from cirl_study.cli import app

SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        ("subjects = 4\nrationality", "subjects = 0\nrationality",
         "pipelines/bad.toml: main.subjects must be an integer of at least 2 (the analysis needs"),
        ("width = 5", "width = 1",
         "pipelines/bad.toml: game.width must be an integer of at least 2, got 1"),
        ("start = [2, 2]", "start = [2, 5]", "pipelines/bad.toml: game.start must be a cell"),
        ("rationalities = [0.1, 1.0, 10.0]", "rationalities = [0.1, 0.0]",
         "pipelines/bad.toml: lambda_sweep.rationalities must be a non-empty list of numbers in ["),
        ("etas = [0.1, 1.0, 10.0]", "etas = [-0.1]",
         "pipelines/bad.toml: eta_cv.etas must be a non-empty list of numbers in ["),
        ("seed = 7", "seed = 7\ncolour = 3", "pipelines/bad.toml: colour is not a known key"),
        ("seed = 7", "seed = ", "pipelines/bad.toml: not valid TOML"),
    ],
)  # fmt: skip
def test_bad_pipeline_exits_2_with_one_line(
    old: str, new: str, expected: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    bad = tmp_path / "pipelines" / "bad.toml"
    bad.parent.mkdir()
    text = SMOKE.read_text()
    assert old in text
    bad.write_text(text.replace(old, new, 1))
    result = CliRunner().invoke(app, ["run", "bad", "--out", str(tmp_path / "out")])
    assert result.exit_code == 2
    assert result.stderr.startswith(f"error: {expected}"), result.stderr
    assert result.stderr.count("\n") == 1
    assert not (tmp_path / "out").exists()


def test_unknown_pipeline_name_exits_2(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(app, ["run", "no-such-study"])
    assert result.exit_code == 2
    assert result.stderr.startswith("error: no pipeline named 'no-such-study' (known pipelines:")
    assert result.stderr.count("\n") == 1


def test_a_missing_pipeline_file_is_no_such_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(app, ["run", "missing.toml"])
    assert result.exit_code == 2
    assert result.stderr.startswith("error: missing.toml: no such file, nor a shipped pipeline")
    assert result.stderr.count("\n") == 1 and not (tmp_path / "data").exists()
