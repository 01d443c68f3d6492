"""A new human or robot is one function and one registry line: play a pipeline with them."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from test_logs_helpers import run_records

from cirl_study.core.apprenticeship import Apprenticeship
from cirl_study.core.estimate import Estimate
from cirl_study.core.players import HUMANS, ROBOTS, Human, Robot, register_human, register_robot
from cirl_study.errors import UserError
from cirl_study.logs.validate import validate_run
from cirl_study.study.engines import LocalEngine
from cirl_study.study.pipeline_file import load_pipeline, logged_pipeline, parse_pipeline
from cirl_study.study.runner import run_pipeline

SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"


def stay_put(
    game: Apprenticeship, theta: np.ndarray, eta: np.ndarray | None, seeds: np.ndarray
) -> np.ndarray:
    """A human who never moves: ``s_0`` at every step (``stay`` is always available)."""
    phase = game.learning.phase
    return np.full((len(theta), phase.horizon + 1), phase.start_cell)


def prior_mean(game: Apprenticeship, demos: np.ndarray, seeds: np.ndarray) -> Estimate:
    """A robot that ignores the demonstration and acts on the prior mean, theta = 0."""
    model = game.learning
    batch, k = len(demos), model.features.shape[2]
    theta_hat = np.zeros((batch, k))
    return Estimate(
        theta_hat=theta_hat,
        log_likelihood=model.log_likelihood(theta_hat, model.path_counts(demos)),
        iterations=np.zeros(batch, dtype=np.int64),
        converged=np.ones(batch, dtype=bool),
    )


@pytest.fixture
def registered() -> Iterator[None]:
    register_human("stay_put", Human(stay_put, takes_eta=False))
    register_robot("prior_mean", Robot(prior_mean))
    yield
    del HUMANS["stay_put"], ROBOTS["prior_mean"]


def pipeline_text(humans: str, robots: str) -> str:
    text = SMOKE.read_text()
    text = text.replace('humans = ["expert", "best_response"]', f"humans = {humans}")
    return text.replace('robots = ["map"]', f"robots = {robots}")


@pytest.mark.parametrize("workers", [1, 2])
def test_a_registered_human_and_robot_play_a_pipeline(
    registered: None, tmp_path: Path, workers: int
) -> None:
    path = tmp_path / "seams.toml"
    path.write_text(pipeline_text('["stay_put", "best_response"]', '["prior_mean"]'))
    pipeline = load_pipeline(path)
    assert pipeline.humans_with_eta == ("best_response",)
    result = run_pipeline(pipeline, tmp_path / "run", LocalEngine(workers))
    assert result.played == result.total == 82
    assert validate_run(tmp_path / "run", logged_pipeline).ok
    records = run_records(tmp_path / "run")
    assert {r.human for r in records} == {"stay_put", "best_response"}
    assert {r.robot for r in records} == {"prior_mean"}
    for record in records:
        assert all(v == 0.0 for v in record.theta_hat)
        if record.human == "stay_put":
            assert record.eta is None
            assert set(record.demonstration.states) == {record.start}
            assert set(record.demonstration.actions) == {"stay"}


def test_unknown_names_are_refused_before_anything_runs(tmp_path: Path) -> None:
    with pytest.raises(UserError, match=r"main.humans must be a non-empty list of distinct"):
        parse_pipeline(pipeline_text('["stay_put"]', '["map"]'), tmp_path / "x.toml")
    with pytest.raises(UserError, match=r"main.robots must be a non-empty list of distinct known"):
        parse_pipeline(pipeline_text('["expert"]', '["oracle"]'), tmp_path / "x.toml")
    with pytest.raises(UserError, match=r"main.robots must be a non-empty list of distinct known"):
        parse_pipeline(pipeline_text('["expert"]', '["map", "map"]'), tmp_path / "x.toml")


def test_a_name_is_registered_once(registered: None) -> None:
    with pytest.raises(ValueError, match="already registered"):
        register_human("stay_put", Human(stay_put, takes_eta=False))
    with pytest.raises(ValueError, match="already registered"):
        register_robot("map", Robot(prior_mean))


def test_the_posterior_mean_robot_plays_a_pipeline_and_logs_its_error(tmp_path: Path) -> None:
    path = tmp_path / "posterior.toml"
    path.write_text(pipeline_text('["expert", "best_response"]', '["posterior_mean"]'))
    result = run_pipeline(load_pipeline(path), tmp_path / "run", LocalEngine(2))
    assert result.played == 82
    assert validate_run(tmp_path / "run", logged_pipeline).ok
    records = run_records(tmp_path / "run")
    assert {r.robot for r in records} == {"posterior_mean"}
    for record in records:
        assert record.theta_hat_se is not None and record.effective_sample_size is not None
        assert len(record.theta_hat_se) == record.num_features
        if record.irl.converged:
            assert max(record.theta_hat_se) <= 0.01
