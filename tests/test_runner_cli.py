"""`cirl-study run` from the command line: options, one-line errors, the summary."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from cirl_study.cli import app
from cirl_study.errors import UserError
from cirl_study.logs.lock import LOCK_NAME
from cirl_study.study.engines import DEFAULT_NO_WORKERS_TIMEOUT, DaskEngine
from cirl_study.study.pipeline_file import load_pipeline
from cirl_study.study.runner import run_pipeline

SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"


def test_help_explains_every_option() -> None:
    result = CliRunner().invoke(app, ["run", "--help"], env={"COLUMNS": "120"})
    assert result.exit_code == 0
    options = ("PIPELINE", "--out", "--workers", "--engine", "--scheduler", "paper")
    for option in (*options, "--no-workers-timeout"):
        assert option in result.stdout
    assert f"[default: ({DEFAULT_NO_WORKERS_TIMEOUT:g})]" in " ".join(result.stdout.split())


@pytest.mark.parametrize(
    ("options", "expected"),
    [
        (["--workers", "0"], "error: --workers must be a positive integer, got 0"),
        (["--scheduler", "tcp://127.0.0.1:1"], "error: --scheduler needs --engine dask"),
        (["--no-workers-timeout", "5"], "error: --no-workers-timeout needs --engine dask"),
        (
            ["--engine", "dask", "--no-workers-timeout", "0"],
            "error: --no-workers-timeout must be a positive number of seconds, got 0",
        ),
        (
            ["--engine", "dask", "--no-workers-timeout", "inf"],
            "error: --no-workers-timeout must be a positive number of seconds, got inf",
        ),
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
    *notes, error = result.stderr.splitlines()  # the stage notes of plain progress, then it
    assert error == (
        "error: the dask engine needs Dask: pip install -e '.[dask]' in a checkout, "
        "pip install 'cirl-study[dask]' otherwise"
    )
    assert all(note.startswith(("preparing ", "numerical kernels ready in ")) for note in notes)


def test_unreachable_scheduler_is_one_line_and_leaves_no_directory(tmp_path: Path) -> None:
    engine = DaskEngine(1, scheduler="tcp://127.0.0.1:1", connect_timeout=0.5)
    with pytest.raises(UserError) as caught:
        run_pipeline(load_pipeline(SMOKE), tmp_path / "new" / "run", engine)
    message = str(caught.value)
    assert message.startswith("cannot connect to the Dask scheduler at tcp://127.0.0.1:1: ")
    assert "\n" not in message
    assert list(tmp_path.iterdir()) == []  # neither the run directory nor its parent
    existing = tmp_path / "existing"
    existing.mkdir()
    with pytest.raises(UserError):
        run_pipeline(load_pipeline(SMOKE), existing, engine)
    assert [path.name for path in existing.iterdir()] == [LOCK_NAME]  # it was there before


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
        result.stdout.splitlines()[2] == "eta by cross-validation: none (no human has a trade-off)"
    )


def test_progress_outside_a_terminal_is_plain_lines(tmp_path: Path) -> None:
    """A run's stderr in a log: the stage notes, the trials to play, then a line at most
    every LINE_SECONDS and one when the last trial is logged."""
    import io

    from cirl_study.commands.progress import plain_lines

    stream = io.StringIO()
    hooks = plain_lines(stream, period=3600.0)
    hooks.note("preparing the numerical kernels")
    hooks.start(10, 4)
    for _ in range(6):
        hooks.advance(1, "main")
    lines = stream.getvalue().splitlines()
    assert lines[:2] == ["preparing the numerical kernels", "trials: 4/10 logged, 6 to play"]
    assert len(lines) == 3 and lines[2].startswith("trials: 10/10 (main), ")
    assert "left" not in lines[2]  # nothing is left at the end
    every = io.StringIO()
    hooks = plain_lines(every, period=0.0)
    hooks.start(3, 0)
    for block in ("eta_cv", "main", "lambda_sweep"):
        hooks.advance(1, block)
    lines = every.getvalue().splitlines()[1:]
    assert [line.split(",")[0] for line in lines] == [
        "trials: 1/3 (eta_cv)", "trials: 2/3 (main)", "trials: 3/3 (lambda_sweep)",
    ]  # fmt: skip
    # The time left is the trials left at the rate so far: 2 left at 1 trial per elapsed.
    rate = float(lines[0].split(", ")[1].split()[0])
    left = float(lines[0].split("about ")[1].split()[0])
    assert rate > 0 and left == pytest.approx(2 / rate, rel=0.5, abs=1)
    result = CliRunner().invoke(app, ["run", str(SMOKE), "--out", str(tmp_path / "run")])
    assert result.exit_code == 0, result.output
    assert "trials: 0/82 logged, 82 to play" in result.stderr
    assert "trials: 82/82 (lambda_sweep), " in result.stderr
