"""Pipeline files: the shipped ones, and every kind of bad key refused in one line."""

from __future__ import annotations

import copy
import itertools
import json
import math
import tomllib
from pathlib import Path
from typing import Any

import pytest

from cirl_study.errors import UserError
from cirl_study.record import GradientAscent
from cirl_study.study.pipeline_file import load_pipeline, parse_pipeline, resolve_pipeline
from cirl_study.study.plan import study_trials, trial_counts

REPO = Path(__file__).resolve().parent.parent
SMOKE = REPO / "pipelines" / "smoke.toml"


def to_toml(data: dict[str, Any]) -> str:
    """A TOML document of scalars, arrays and one level of tables (enough for pipelines)."""

    def value(v: Any) -> str:
        if isinstance(v, float) and not math.isfinite(v):
            return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
        if isinstance(v, list):
            return "[" + ", ".join(value(item) for item in v) + "]"
        return json.dumps(v)

    lines = [f"{k} = {value(v)}" for k, v in data.items() if not isinstance(v, dict)]
    for name, table in data.items():
        if isinstance(table, dict):
            lines.append(f"\n[{name}]")
            lines += [f"{k} = {value(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"


def smoke_data() -> dict[str, Any]:
    return tomllib.loads(SMOKE.read_text())


def test_to_toml_round_trips_the_smoke_pipeline() -> None:
    assert tomllib.loads(to_toml(smoke_data())) == smoke_data()


def test_paper_pipeline_is_the_study_of_the_issue() -> None:
    paper = load_pipeline(REPO / "pipelines" / "paper.toml")
    game = paper.game
    assert (game.width, game.height, game.start) == (10, 10, (5, 5))
    assert (game.learning_steps, game.deployment_steps) == (9, 9)
    assert game.feature_levels == (3, 10)
    assert paper.eta_cv.subjects == 100 and paper.eta_cv.rationality == 1.0
    etas = paper.eta_cv.etas
    assert etas[0] == 0.01 and etas[-1] == 100.0 and len(etas) == 9
    # a log grid: every step is half a decade (to the 3 significant digits written)
    assert all(abs(math.log10(b / a) - 0.5) < 2e-3 for a, b in itertools.pairwise(etas))
    assert (paper.main.subjects, paper.main.rationality) == (500, 1.0)
    assert paper.lambda_sweep.subjects == 500
    assert paper.lambda_sweep.rationalities == tuple(10.0**e for e in range(-4, 4))
    assert trial_counts(paper) == {"eta_cv": 1800, "main": 2000, "lambda_sweep": 16000}
    assert (game.centers, game.demonstrator_stays, game.deployment_start) == (
        "per_draw",
        True,
        "uniform",
    )
    assert paper.multiverse is None


def test_smoke_pipeline_has_the_paper_shape() -> None:
    smoke = load_pipeline(SMOKE)
    assert smoke.name == "smoke" and smoke.game.feature_levels == (3, 10)
    assert sum(trial_counts(smoke).values()) == 82


def test_run_id_and_hash_follow_the_file_bytes(tmp_path: Path) -> None:
    text = SMOKE.read_text()
    a = parse_pipeline(text, tmp_path / "a.toml")
    b = parse_pipeline(text + "# a comment\n", tmp_path / "a.toml")
    assert a.sha256 != b.sha256 and a.run_id != b.run_id
    assert a.run_id.startswith("smoke-") and a == parse_pipeline(text, tmp_path / "a.toml")


def _set(data: dict[str, Any], key: str, new: Any) -> dict[str, Any]:
    changed = copy.deepcopy(data)
    *tables, last = key.split(".")
    target = changed
    for table in tables:
        target = target[table]
    if new is _DELETE:
        del target[last]
    else:
        target[last] = new
    return changed


_DELETE = object()

BAD_VALUES = [
    ("nmae", "x", "nmae is not a known key"),
    ("game.colour", 3, "game.colour is not a known key"),
    ("main.subject", 4, "main.subject is not a known key"),
    ("name", _DELETE, "name is missing"),
    ("name", "", "name must be letters"),
    ("name", "a/b", "name must be letters"),
    ("name", 3, "name must be a string, got 3"),
    ("description", ["x"], "description must be a string"),
    ("seed", -1, "seed must be a non-negative integer, got -1"),
    ("seed", 1.5, "seed must be a non-negative integer, got 1.5"),
    ("game", 3, "game must be a table"),
    ("game", _DELETE, "game is missing"),
    ("game.width", 1, "game.width must be an integer of at least 2, got 1"),
    ("game.height", 0, "game.height must be an integer of at least 2, got 0"),
    ("game.width", 5.0, "game.width must be an integer of at least 2, got 5.0"),
    ("game.start", [5, 2], "game.start must be a cell [x, y] of the 5x5 grid"),
    ("game.start", [2, -1], "game.start must be a cell [x, y] of the 5x5 grid"),
    ("game.start", [2], "game.start must be a cell [x, y]"),
    ("game.start", [2.0, 2], "game.start must be a cell [x, y]"),
    ("game.learning_steps", 0, "game.learning_steps must be a positive integer, got 0"),
    ("game.deployment_steps", -2, "game.deployment_steps must be a positive integer, got -2"),
    ("game.sigma", 0, "game.sigma must be a number in ["),
    ("game.sigma", -1.5, "game.sigma must be a number in ["),
    ("game.sigma", math.inf, "game.sigma must be a number in ["),
    ("game.sigma", math.nan, "game.sigma must be a number in ["),
    ("game.sigma", "1.5", "game.sigma must be a number in ["),
    ("game.sigma", True, "game.sigma must be a number in ["),
    ("game.feature_levels", [], "game.feature_levels must be a non-empty list"),
    ("game.feature_levels", [0, 3], "game.feature_levels must be a non-empty list"),
    ("game.feature_levels", [3.5], "game.feature_levels must be a non-empty list"),
    ("game.feature_levels", 3, "game.feature_levels must be a non-empty list"),
    ("game.feature_levels", [3, 3], "game.feature_levels must not repeat a value"),
    ("game.centers", "random", "game.centers must be one of per_draw, shared, lattice"),
    ("game.centers", _DELETE, "game.centers is missing"),
    ("game.demonstrator_stays", 1, "game.demonstrator_stays must be true or false, got 1"),
    ("game.deployment_start", "corner", "game.deployment_start must be one of uniform, demo"),
    ("eta_cv.subjects", 0, "eta_cv.subjects must be an integer of at least 2 (the analysis"),
    ("eta_cv.subjects", 1, "eta_cv.subjects must be an integer of at least 2 (the analysis"),
    ("eta_cv.etas", [], "eta_cv.etas must be a non-empty list of numbers in ["),
    ("eta_cv.etas", [0.0, 1.0], "eta_cv.etas must be a non-empty list of numbers in ["),
    ("eta_cv.etas", [-1.0], "eta_cv.etas must be a non-empty list of numbers in ["),
    ("eta_cv.etas", [1, 1.0], "eta_cv.etas must not repeat a value"),
    ("eta_cv.rationality", 0, "eta_cv.rationality must be a number in ["),
    ("main.subjects", 0, "main.subjects must be an integer of at least 2 (the analysis"),
    ("main.subjects", 1, "main.subjects must be an integer of at least 2 (the analysis"),
    ("main.subjects", True, "main.subjects must be an integer of at least 2 (the"),
    ("main.subjects", "4", "main.subjects must be an integer of at least 2"),
    ("main.rationality", -1.0, "main.rationality must be a number in ["),
    ("main", _DELETE, "main is missing"),
    ("lambda_sweep.subjects", 5, "lambda_sweep.subjects must be at most main.subjects = 4"),
    ("lambda_sweep.subjects", 1, "lambda_sweep.subjects must be an integer of at least 2"),
    ("lambda_sweep.rationalities", [], "lambda_sweep.rationalities must be a non-empty list"),
    ("lambda_sweep.rationalities", [1e-4, 0.0], "lambda_sweep.rationalities must be a non-empty"),
    ("lambda_sweep.rationalities", 1.0, "lambda_sweep.rationalities must be a non-empty list"),
]


@pytest.mark.parametrize(("key", "value", "expected"), BAD_VALUES)
def test_bad_key_is_one_line_naming_file_and_key(
    key: str, value: Any, expected: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    path = Path("pipelines") / "bad.toml"
    path.parent.mkdir()
    path.write_text(to_toml(_set(smoke_data(), key, value)))
    with pytest.raises(UserError) as caught:
        load_pipeline(path)
    message = str(caught.value)
    assert message.startswith("pipelines/bad.toml: "), message
    assert expected in message, message
    assert "\n" not in message


def test_good_variation_is_accepted(tmp_path: Path) -> None:
    data = _set(smoke_data(), "game.start", [4, 0])
    data = _set(data, "game.width", 6)
    path = tmp_path / "ok.toml"
    path.write_text(to_toml(data))
    assert load_pipeline(path).game.start == (4, 0)


def test_unreadable_and_invalid_files_are_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text("name = \n")
    with pytest.raises(UserError, match=r"bad\.toml: not valid TOML: .*line 1"):
        load_pipeline(bad)
    bad.write_bytes(b"name = '\xff'\n")
    with pytest.raises(UserError, match="not valid TOML"):
        load_pipeline(bad)
    with pytest.raises(UserError, match="missing.toml: cannot read"):
        load_pipeline(tmp_path / "missing.toml")


def test_resolve_pipeline_by_name_and_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert resolve_pipeline("smoke") == SMOKE  # the source tree's, from anywhere
    assert resolve_pipeline("smoke.toml") == SMOKE
    local = tmp_path / "pipelines" / "smoke.toml"
    local.parent.mkdir()
    local.write_text(SMOKE.read_text())
    assert resolve_pipeline("smoke").resolve() == local  # the current directory's first
    mine = tmp_path / "mine.toml"
    mine.write_text("")
    assert resolve_pipeline(str(mine)) == mine
    with pytest.raises(UserError, match=r"no pipeline named 'nope' \(known pipelines: .*paper"):
        resolve_pipeline("nope")
    with pytest.raises(UserError, match="no such pipeline file"):
        resolve_pipeline("some/where.toml")


ASCENT = {"steps": 30, "learning_rate": 0.1}


def ascent_data(**table: Any) -> dict[str, Any]:
    """The smoke pipeline watched by ``map`` and ``gradient_ascent``, with these settings."""
    data = _set(smoke_data(), "main.robots", ["map", "gradient_ascent"])
    data["gradient_ascent"] = {**ASCENT, **table}
    return data


BAD_ASCENT = [
    (_set(ascent_data(), "gradient_ascent", _DELETE), "gradient_ascent is missing (robot gradi"),
    (_set(smoke_data(), "gradient_ascent", ASCENT), "gradient_ascent is given, but robot gradie"),
    (ascent_data(steps=0), "gradient_ascent.steps must be an integer in [1, 100000], got 0"),
    (ascent_data(steps=100_001), "gradient_ascent.steps must be an integer in [1, 100000] (each"),
    (ascent_data(steps=2.5), "gradient_ascent.steps must be an integer in [1, 100000], got 2.5"),
    (ascent_data(learning_rate=0), "gradient_ascent.learning_rate must be a number in [1e-12, 1"),
    (ascent_data(learning_rate=1e3), "gradient_ascent.learning_rate must be a number in [1e-12,"),
    (ascent_data(learning_rate="0.1"), "gradient_ascent.learning_rate must be a number in [1e-1"),
    (ascent_data(stpes=3), "gradient_ascent.stpes is not a known key (expected one of: steps, "),
    (_set(ascent_data(), "gradient_ascent.steps", _DELETE), "gradient_ascent.steps is missing"),
]


@pytest.mark.parametrize(("data", "expected"), BAD_ASCENT)
def test_a_bad_gradient_ascent_table_is_one_line(
    data: dict[str, Any], expected: str, tmp_path: Path
) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(to_toml(data))
    with pytest.raises(UserError) as caught:
        load_pipeline(path)
    message = str(caught.value)
    assert message.startswith(f"{path}: ") and expected in message and "\n" not in message


def test_a_multiverse_level_of_the_robot_needs_the_table(tmp_path: Path) -> None:
    text = (REPO / "pipelines" / "multiverse.toml").read_text()
    text += '\n[[multiverse.universes]]\nrobot = "gradient_ascent"\n'
    with pytest.raises(UserError, match="gradient_ascent is missing"):
        parse_pipeline(text, tmp_path / "m.toml")
    text += "\n[gradient_ascent]\nsteps = 7\nlearning_rate = 0.5\n"
    settings = parse_pipeline(text, tmp_path / "m.toml").gradient_ascent
    assert (settings.steps, settings.learning_rate) == (7, 0.5)


def test_the_gradient_ascent_settings_reach_its_trials_alone(tmp_path: Path) -> None:
    path = tmp_path / "ascent.toml"
    path.write_text(to_toml(ascent_data(steps=12, learning_rate=2)))
    pipeline = load_pipeline(path)
    trials = study_trials(pipeline, {(None, "best_response", k): 1.0 for k in (3, 10)})
    settings = {(t.robot, t.gradient_ascent) for t in trials}
    ascent = GradientAscent(steps=12, learning_rate=2.0)
    assert settings == {("map", None), ("gradient_ascent", ascent)}


def test_the_shipped_gradient_ascent_pipeline_watches_with_both_robots() -> None:
    pipeline = load_pipeline(REPO / "pipelines" / "gradient-ascent.toml")
    assert pipeline.main.robots == ("map", "gradient_ascent")
    assert (pipeline.gradient_ascent.steps, pipeline.gradient_ascent.learning_rate) == (30, 0.1)
    assert trial_counts(pipeline) == {"eta_cv": 1800, "main": 800, "lambda_sweep": 320}
