"""A study with the ``gradient_ascent`` robot beside ``map``, from the pipeline file to the report,
through the command line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import path_enumeration as bf
import pytest
from test_logs_helpers import run_records
from typer.testing import CliRunner

import cirl_study
from cirl_study.cli import app
from cirl_study.core.gradient_ascent import gradient_ascent_estimate
from cirl_study.core.gridworld import Gridworld, rbf_features
from cirl_study.core.maxent import MaxEnt, Phase
from cirl_study.record import GRADIENT_ASCENT, MAIN, MAP

PIPELINE = """\
name = "ascent"
description = "The paper's humans watched by the MAP robot and by gradient ascent"
seed = 29

[game]
width = 5
height = 5
start = [2, 2]
learning_steps = 4
deployment_steps = 4
sigma = 0.75
feature_levels = [3]
centers = "per_draw"
demonstrator_stays = true
deployment_start = "uniform"

[eta_cv]
subjects = 2
etas = [0.1, 1.0]
rationality = 1.0

[main]
subjects = 3
rationality = 1.0
humans = ["expert", "best_response"]
robots = ["map", "gradient_ascent"]

[lambda_sweep]
subjects = 2
rationalities = [0.1, 10.0]

[gradient_ascent]
steps = 40
learning_rate = 0.5
"""


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    base = tmp_path_factory.mktemp("ascent")
    pipeline, out = base / "ascent.toml", base / "run"
    pipeline.write_text(PIPELINE)
    result = CliRunner().invoke(app, ["run", str(pipeline), "--out", str(out), "--workers", "1"])
    assert result.exit_code == 0, result.output
    return out


def test_the_run_validates_and_is_analysed(run: Path) -> None:
    result = CliRunner().invoke(app, ["validate", str(run)])
    assert result.exit_code == 0, result.output
    assert result.output.strip().splitlines()[-1].endswith("design complete")
    result = CliRunner().invoke(app, ["analyze", str(run)])
    assert result.exit_code == 0, result.output
    assert (run / "report" / "report.md").is_file()
    assert cirl_study.analyze(run).design.robots == [MAP, GRADIENT_ASCENT]


def test_every_gradient_ascent_record_carries_its_settings_and_its_estimate(run: Path) -> None:
    records = run_records(run)
    ascent = [r for r in records if r.robot == GRADIENT_ASCENT]
    assert {r.block for r in ascent} == {MAIN, "lambda_sweep"}
    assert all(r.gradient_ascent is None for r in records if r.robot != GRADIENT_ASCENT)
    assert {(r.gradient_ascent.steps, r.gradient_ascent.learning_rate) for r in ascent} == {
        (40, 0.5)
    }
    assert all(r.irl.iterations == 40 and r.irl.converged for r in ascent)
    # The expert's estimate leaves the box, which the record checks accepted.
    assert max(np.abs(r.theta_hat).max() for r in ascent if r.human == "expert") > 1.0
    grid = Gridworld(5, 5)
    for r in ascent:
        phi = rbf_features(grid, r.features.centers, r.features.sigma)[None]
        model = MaxEnt(Phase(grid.successors, grid.index(*r.start), 4), phi, r.rationality)
        demo = np.array([[grid.index(*cell) for cell in r.demonstration.states]])
        want = gradient_ascent_estimate(model, demo, 40, 0.5)
        assert list(r.theta_hat) == want.theta_hat[0].tolist()


def test_both_robots_watch_the_same_demonstrations(run: Path) -> None:
    records = [r for r in run_records(run) if r.block != "eta_cv"]
    shown: dict[tuple, set] = {}
    for r in records:
        key = (r.block, r.subject, r.human, r.rationality, r.eta)
        shown.setdefault(key, set()).add((r.robot, r.demonstration.states))
    for watched in shown.values():
        assert {robot for robot, _ in watched} == {MAP, GRADIENT_ASCENT}
        assert len({states for _, states in watched}) == 1


def test_every_record_logs_both_readings_of_regret(run: Path) -> None:
    """Each main-block record's two regrets, by enumerating every deployment path from every
    start: under the true reward ``V*_theta - V^{pi_theta_hat}_theta``, under the estimate
    ``V*_theta_hat - V^{pi_theta}_theta_hat`` (ties to the lowest action in both)."""
    records = [r for r in run_records(run) if r.block == MAIN]
    assert {r.robot for r in records} == {MAP, GRADIENT_ASCENT}
    table = cirl_study.load_trials(run).set_index("trial_id")
    for r in records:
        features = bf.rbf_features(5, 5, r.features.centers, r.features.sigma)
        readings = {
            "regret": (r.theta, r.theta_hat),
            "regret_under_estimate": (r.theta_hat, r.theta),
        }
        for name, (reward, planner) in readings.items():
            best = bf.optimal_values(5, 5, features, reward, 4)
            human = bf.greedy_actions(5, 5, features, planner, 4)
            gaps = [best[s] - bf.policy_value(5, 5, features, reward, human, s) for s in range(25)]
            scale = max(1.0, float(np.abs(reward).max()))
            assert r.measures[name] == pytest.approx(np.mean(gaps), abs=1e-12 * scale)
            assert table.at[r.trial_id, name] == r.measures[name]
        assert r.measures["regret_under_estimate"] >= 0.0
