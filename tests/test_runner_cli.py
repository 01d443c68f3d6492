"""`cirl-study run` from the command line: options, one-line errors, the summary."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cirl_study.cli import app
from cirl_study.errors import UserError
from cirl_study.study.engines import DaskEngine

SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"


def test_help_explains_every_option() -> None:
    result = CliRunner().invoke(app, ["run", "--help"], env={"COLUMNS": "120"})
    assert result.exit_code == 0
    for option in ("PIPELINE", "--out", "--workers", "--engine", "--scheduler", "paper"):
        assert option in result.stdout


@pytest.mark.parametrize(
    ("options", "expected"),
    [
        (["--workers", "0"], "error: --workers must be a positive integer, got 0"),
        (["--scheduler", "tcp://127.0.0.1:1"], "error: --scheduler needs --engine dask"),
    ],
)
def test_bad_options_exit_2_with_one_line(
    options: list[str], expected: str, tmp_path: Path
) -> None:
    result = CliRunner().invoke(app, ["run", str(SMOKE), "--out", str(tmp_path), *options])
    assert result.exit_code == 2
    assert result.stderr == expected + "\n"


def test_dask_engine_without_dask_is_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # as if not installed
    result = CliRunner().invoke(
        app, ["run", str(SMOKE), "--out", str(tmp_path), "--engine", "dask"]
    )
    assert result.exit_code == 2
    assert result.stderr == (
        "error: the dask engine needs Dask: pip install -e '.[dask]' in a checkout, "
        "pip install 'cirl-study[dask]' otherwise\n"
    )


def test_unreachable_scheduler_is_one_line() -> None:
    engine = DaskEngine(1, scheduler="tcp://127.0.0.1:1", connect_timeout=0.5)
    with pytest.raises(UserError) as caught, engine:
        pass
    message = str(caught.value)
    assert message.startswith("cannot connect to the Dask scheduler at tcp://127.0.0.1:1: ")
    assert "\n" not in message


def test_run_prints_a_summary(tmp_path: Path) -> None:
    out = tmp_path / "run"
    result = CliRunner().invoke(app, ["run", str(SMOKE), "--out", str(out), "--workers", "1"])
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    assert lines[0].startswith("run smoke-") and f"82 trials logged in {out}" in lines[0]
    assert "82 played now, 0 were already logged" in lines[0]
    assert re.fullmatch(
        r"[\d.]+ s in all; playing [\d.]+ s, \d+ trials/s, in this process "
        r"\(compute floor [\d.]+ s\)",
        lines[1],
    )
    assert lines[2].startswith("eta by cross-validation: best_response at K=3 -> ")
    again = CliRunner().invoke(app, ["run", str(SMOKE), "--out", str(out), "--workers", "1"])
    assert again.exit_code == 0
    assert "0 played now, 82 were already logged" in again.stdout


def test_a_study_of_humans_without_a_trade_off_plays_no_cross_validation(tmp_path: Path) -> None:
    pipeline = tmp_path / "literal.toml"
    text = SMOKE.read_text().replace('["expert", "best_response"]', '["expert", "literal"]')
    pipeline.write_text(text)
    out = tmp_path / "run"
    result = CliRunner().invoke(app, ["run", str(pipeline), "--out", str(out), "--workers", "1"])
    assert result.exit_code == 0, result.output
    assert "64 trials logged" in result.stdout  # main 16 + lambda_sweep 48, no eta_cv
    assert (
        result.stdout.splitlines()[2] == "eta by cross-validation: none (no policy has a trade-off)"
    )
