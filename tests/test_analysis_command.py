"""``cirl-study analyze RUN``: from MCAP logs to the report directory."""

from __future__ import annotations

import json
import shutil

from typer.testing import CliRunner

from cirl_study.cli import app


def test_analyze_writes_the_report_beside_the_run_by_default(tmp_path, smoke_run):
    run = tmp_path / "run"
    shutil.copytree(smoke_run, run)
    result = CliRunner().invoke(app, ["analyze", str(run)])
    assert result.exit_code == 0, result.output
    out = run / "report"
    assert result.output.strip() == (
        f"report of 82 trials written to {out}: 7 claims on this run's data: 1 reproduced, "
        "6 not reproduced (judged on cells of 4 subjects, fewer than 20: the verdicts mean "
        "little); 4 theorems checked exactly, independent of the run: 4 hold; 5 claims not "
        "tested, the run lacks their cells"
    )
    results = json.loads((out / "results.json").read_text(encoding="utf-8"))
    kinds = [(claim["kind"], claim["tested"], claim["subjects"]) for claim in results["claims"]]
    assert (
        kinds
        == [("data", True, 4)] * 7 + [("data", False, None)] * 5 + [("theory", True, None)] * 4
    )
    text = (out / "report.md").read_text(encoding="utf-8")
    claims = text.split("## Claims\n")[1].split("\n## ")[0]
    assert claims.index("### Claims on this run's data") < claims.index(
        "**Judged on cells of 4 subjects, fewer than 20: the verdicts mean little.**"
    )
    assert claims.index("### Theorems checked exactly") < claims.index("### Claims not tested")
    assert claims.count("✅ holds") == 4 and "| 16 |" in claims
    assert results["pipeline"] == "smoke" and results["partial"] is None
    assert results["run_id"].startswith("smoke-")
    assert {p.name for p in out.glob("*.svg")} == {
        p.name.replace(".png", ".svg") for p in out.glob("*.png")
    }
    assert results["trials"]["total"] == 82
    assert (out / "report.md").is_file() and (out / "figure1_reward_maps.png").is_file()


def test_a_report_of_another_run_is_kept_unless_forced(tmp_path, smoke_run):
    out = tmp_path / "report"
    out.mkdir()
    (out / "results.json").write_text('{"run_id": "paper-0123456789ab"}')
    result = CliRunner().invoke(app, ["analyze", str(smoke_run), "--out", str(out)])
    assert result.exit_code == 2
    assert "holds the report of paper-0123456789ab" in result.stderr
    assert "--force" in result.stderr and result.stderr.count("\n") == 1
    assert json.loads((out / "results.json").read_text()) == {"run_id": "paper-0123456789ab"}
    forced = CliRunner().invoke(app, ["analyze", str(smoke_run), "--out", str(out), "--force"])
    assert forced.exit_code == 0, forced.output
    assert json.loads((out / "results.json").read_text())["run_id"].startswith("smoke-")


def test_analyze_of_a_missing_run_is_a_one_line_error(tmp_path):
    result = CliRunner().invoke(app, ["analyze", str(tmp_path / "nothing")])
    assert result.exit_code == 2
    assert result.output.strip().startswith("error: ") and "no such run directory" in result.output
    assert len(result.output.strip().splitlines()) == 1
