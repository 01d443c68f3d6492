"""Engines and worker counts log byte-identical trial payloads; run directories stay pure."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from mcap.reader import make_reader

from cirl_study.errors import UserError
from cirl_study.logs.format import TRIAL_TOPIC
from cirl_study.study.engines import DaskEngine, LocalEngine
from cirl_study.study.pipeline_file import load_pipeline
from cirl_study.study.plan import eta_cv_trials, study_trials
from cirl_study.study.runner import RunResult, batch_size, run_pipeline, split_batches
from cirl_study.study.spec import Pipeline

SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"


def trial_payloads(run_dir: Path) -> dict[str, bytes]:
    """Every ``/cirl/trial`` payload of a run directory by trial id; no id twice."""
    payloads: dict[str, bytes] = {}
    for path in sorted(run_dir.glob("*.mcap")):
        with path.open("rb") as stream:
            for _, _, message in make_reader(stream).iter_messages(topics=[TRIAL_TOPIC]):
                trial_id = json.loads(message.data)["trial_id"]
                assert trial_id not in payloads, f"{trial_id} logged twice"
                payloads[trial_id] = message.data
    return payloads


def planned_ids(pipeline: Pipeline, result: RunResult) -> set[str]:
    etas = {k: choice.eta for k, choice in result.etas.items()}
    trials = eta_cv_trials(pipeline) + study_trials(pipeline, etas)
    return {trial.trial_id for trial in trials}


@pytest.fixture(scope="module")
def smoke() -> Pipeline:
    return load_pipeline(SMOKE)


@pytest.fixture(scope="module")
def serial_run(smoke: Pipeline, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("serial")
    result = run_pipeline(smoke, out, LocalEngine(1))
    assert (result.total, result.played, result.resumed) == (82, 82, 0)
    assert set(trial_payloads(out)) == planned_ids(smoke, result)
    return out


@pytest.mark.parametrize(
    "engine",
    [LocalEngine(2), DaskEngine(2, processes=False)],
    ids=["local-2-workers", "dask-local-cluster"],
)
def test_engines_log_identical_payloads(
    engine: LocalEngine | DaskEngine, smoke: Pipeline, serial_run: Path, tmp_path: Path
) -> None:
    result = run_pipeline(smoke, tmp_path, engine)
    assert result.played == 82
    assert trial_payloads(tmp_path) == trial_payloads(serial_run)


def test_a_complete_run_plays_nothing_again(
    smoke: Pipeline, serial_run: Path, tmp_path: Path
) -> None:
    out = tmp_path / "run"
    shutil.copytree(serial_run, out)
    result = run_pipeline(smoke, out, LocalEngine(1))
    assert (result.played, result.resumed) == (0, 82)
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in serial_run.iterdir())


def test_a_directory_of_another_pipeline_is_refused(serial_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    shutil.copytree(serial_run, out)
    other = tmp_path / "other.toml"
    other.write_text(SMOKE.read_text().replace('name = "smoke"', 'name = "other"'))
    expected = r"holds the logs of another run \(run smoke-\w+ against other-"
    with pytest.raises(UserError, match=expected) as caught:
        run_pipeline(load_pipeline(other), out, LocalEngine(1))
    assert "\n" not in str(caught.value)


def test_batches_never_mix_blocks_and_cover_every_trial(smoke: Pipeline) -> None:
    trials = eta_cv_trials(smoke) + study_trials(
        smoke, {(None, "best_response", 3): 1.0, (None, "best_response", 10): 1.0}
    )
    batches = split_batches(trials, 7)
    assert [t for batch in batches for t in batch] == trials
    assert all(len({t.block for t in batch}) == 1 and 0 < len(batch) <= 7 for batch in batches)
    assert batch_size(19800, 2) == 250 and batch_size(1800, 2) == 225 and batch_size(3, 8) == 1
