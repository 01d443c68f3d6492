"""Test-wide settings.

Under CI (the environment variable ``CI`` is set) hypothesis runs derandomized: every run of
the suite draws the same examples, so a landing never depends on the luck of the draw. Locally
the draws are random (and failures are replayed from ``.hypothesis/``), which is where new
counterexamples are found; each one found is kept as an explicit test.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

settings.register_profile("ci", derandomize=True)
if os.environ.get("CI"):
    settings.load_profile("ci")


SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"


@pytest.fixture(scope="session")
def smoke_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A complete run of ``pipelines/smoke.toml`` (82 trials), played once per session.

    Read-only: a test that changes a run copies it first (``shutil.copytree``).
    """
    from cirl_study.study.engines import LocalEngine
    from cirl_study.study.pipeline_file import load_pipeline
    from cirl_study.study.runner import run_pipeline

    out = tmp_path_factory.mktemp("smoke") / "run"
    run_pipeline(load_pipeline(SMOKE), out, LocalEngine(2))
    return out
