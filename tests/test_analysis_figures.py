"""The figures (cirl_study.analysis.figures): reward maps and deterministic PNG bytes."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import msgspec
import numpy as np
import pytest
from analysis_fixtures import synthetic_records

from cirl_study.analysis import figures
from cirl_study.core.gridworld import feature_matrix
from cirl_study.record import TrialRecord, from_builtins, to_builtins

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def pair() -> tuple[TrialRecord, TrialRecord]:
    records = synthetic_records(subjects_per_level=1, lambdas=(), etas=(), cv_subjects=0)
    main = [r for r in records if r.block == "main" and r.num_features == 3]
    return main[0], main[1]


def test_reward_map_is_theta_dot_rbf_features_with_row_y_and_column_x(pair):
    record = pair[0]
    scene = figures.RewardScene.from_record(record)
    rewards = scene.reward_map(scene.theta)
    width, height = record.grid.width, record.grid.height
    assert rewards.shape == (height, width)
    sigma = record.features.sigma
    for x, y in [(0, 0), (width - 1, 0), (2, height - 1)]:
        expected = sum(
            weight * math.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * sigma**2))
            for weight, (cx, cy) in zip(record.theta, record.features.centers, strict=True)
        )
        assert rewards[y, x] == pytest.approx(expected)


def test_the_scene_is_the_records_own_data(pair):
    record = pair[1]
    scene = figures.RewardScene.from_record(record)
    np.testing.assert_array_equal(scene.features, feature_matrix(record))
    np.testing.assert_array_equal(scene.theta_hat, record.theta_hat)
    np.testing.assert_array_equal(scene.states, record.demonstration.states)
    np.testing.assert_array_equal(scene.centers, record.features.centers)


@pytest.fixture(scope="module")
def png(pair) -> bytes:
    return figures.reward_maps(*pair, "draw")


def test_png_bytes_carry_no_software_or_time_metadata(png):
    assert png.startswith(PNG_SIGNATURE)
    assert b"Software" not in png and b"tIME" not in png


_RENDER = """
import sys
sys.path.insert(0, {tests!r})
from analysis_fixtures import synthetic_records
from cirl_study.analysis import figures
records = synthetic_records(subjects_per_level=1, lambdas=(), etas=(), cv_subjects=0)
main = [r for r in records if r.block == "main" and r.num_features == 3]
sys.stdout.buffer.write(figures.reward_maps(main[0], main[1], "draw"))
"""


def test_png_bytes_are_the_same_in_a_fresh_process_with_another_hash_seed(png):
    script = _RENDER.format(tests=str(Path(__file__).parent))
    environment = {**os.environ, "PYTHONHASHSEED": "12345", "MPLBACKEND": "pdf"}
    fresh = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, check=True, env=environment
    ).stdout
    assert fresh == png


def test_a_record_without_a_drawable_reward_map_is_refused_before_it_becomes_a_record(pair):
    broken = to_builtins(pair[0])
    del broken["features"]["sigma"]
    with pytest.raises(msgspec.ValidationError, match="missing required field `sigma`"):
        from_builtins(broken)
