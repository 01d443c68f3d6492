"""A run killed with SIGKILL and started again ends exactly like an uninterrupted run."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_runner_engines import trial_payloads

from cirl_study.study.engines import LocalEngine
from cirl_study.study.pipeline_file import load_pipeline
from cirl_study.study.runner import run_pipeline

SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"

pytestmark = pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs SIGKILL")


def bigger_smoke(directory: Path) -> Path:
    """The smoke pipeline with more reward draws (164 trials), so a run lasts a while."""
    text = SMOKE.read_text()
    for block, subjects in (("eta_cv", 6), ("main", 8), ("lambda_sweep", 8)):
        old = f"[{block}]\nsubjects = "
        start = text.index(old) + len(old)
        end = text.index("\n", start)
        text = text[:start] + str(subjects) + text[end:]
    path = directory / "resumable.toml"
    path.write_text(text)
    return path


def run_command(pipeline: Path, out: Path) -> list[str]:
    command = [sys.executable, "-m", "cirl_study", "run", str(pipeline)]
    return [*command, "--out", str(out), "--workers", "2"]


def group_alive(group: int) -> bool:
    try:
        os.killpg(group, 0)
    except ProcessLookupError:
        return False
    return True


def test_resume_after_sigkill_matches_an_uninterrupted_run(tmp_path: Path) -> None:
    pipeline = bigger_smoke(tmp_path)
    reference = tmp_path / "reference"
    total = run_pipeline(load_pipeline(pipeline), reference, LocalEngine(1)).total
    out = tmp_path / "killed"

    process = subprocess.Popen(
        run_command(pipeline, out),
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 60
        while not list(out.glob("*.mcap")) and process.poll() is None:
            assert time.monotonic() < deadline, "the run logged nothing within a minute"
            time.sleep(0.005)
        os.kill(process.pid, signal.SIGKILL)
        assert process.wait() == -signal.SIGKILL
        # the pool's workers notice their parent is gone and end too
        deadline = time.monotonic() + 10
        while group_alive(process.pid):
            assert time.monotonic() < deadline, "workers outlived the killed run"
            time.sleep(0.05)
    finally:
        if group_alive(process.pid):
            os.killpg(process.pid, signal.SIGKILL)

    survived = trial_payloads(out)
    assert 0 < len(survived) < total, "the run was not killed mid-run"
    (out / "eta_cv-0000000000000000.mcap.tmp").write_bytes(b"half a file")

    done = subprocess.run(run_command(pipeline, out), capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert f"{total - len(survived)} played now, {len(survived)} were already logged" in (
        done.stdout
    )
    assert not list(out.glob("*.tmp"))
    resumed = trial_payloads(out)
    assert {k: resumed[k] for k in survived} == survived
    assert resumed == trial_payloads(reference)
