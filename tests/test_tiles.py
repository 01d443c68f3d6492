"""Tile games and tasks: ``[game.tiles]`` and ``[tasks]`` read, refused in one line, planned,
and a small tile study played from the pipeline file to the report."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_logs_helpers import run_records
from typer.testing import CliRunner

import cirl_study
from cirl_study.cli import app
from cirl_study.core.gridworld import Gridworld
from cirl_study.core.maxent import MaxEnt, Phase
from cirl_study.core.trial import check_playable
from cirl_study.errors import UserError
from cirl_study.features import TileFeatures, feature_matrix
from cirl_study.record import MAIN, MAP
from cirl_study.study.pipeline_file import load_pipeline, parse_pipeline
from cirl_study.study.plan import eta_cv_trials, study_trials, trial_counts
from cirl_study.study.settings import Table, written
from cirl_study.study.spec import TilesSpec

REPO = Path(__file__).resolve().parent.parent
TILES = REPO / "pipelines" / "tiles.toml"

SMALL = """\
name = "tiles-small"
description = "A small tile game with two tasks"
seed = 5

[game]
features = "tiles"
start = [0, 1]
learning_steps = 5
deployment_steps = 5
demonstrator_stays = false
deployment_start = "uniform"

[game.tiles]
layout = \"\"\"
.aa.
.bby
.ab.
\"\"\"
legend = { a = "amber", b = "blue", "." = "", y = "" }
goals = "y"
step = "step"

[tasks]
ab = { amber = 0, blue = -1, step = -0.1 }
ba = { amber = -1, blue = 0, step = -0.1 }

[eta_cv]
subjects = 2
etas = [0.1, 1.0]
rationality = 1.0

[main]
rationality = 1.0
humans = ["expert", "best_response", "pedagogic"]
robots = ["map", "gradient_ascent"]

[teaching]
hypotheses = 4
includes_truth = true
alpha = 10.0
demonstration = "draw"

[gradient_ascent]
steps = 10
learning_rate = 0.1
"""


def parse(text: str):
    return parse_pipeline(text, Path("x.toml"))


def test_the_small_pipeline_reads_as_a_tile_game_with_tasks() -> None:
    pipeline = parse(SMALL)
    game = pipeline.game
    assert (game.features, game.width, game.height) == ("tiles", 4, 3)
    assert game.tiles.layout == (".aa.", ".bby", ".ab.")
    assert game.tile_features.names == ("amber", "blue", "step")
    assert game.feature_levels == (3,) and game.goals == ((3, 1),)
    assert (game.sigma, game.centers) == (None, None)
    assert [(t.name, t.weights) for t in pipeline.tasks] == [
        ("ab", (0.0, -1.0, -0.1)),
        ("ba", (-1.0, 0.0, -0.1)),
    ]
    assert pipeline.main.subjects == 2
    assert trial_counts(pipeline) == {"eta_cv": 4, "main": 12, "lambda_sweep": 0}


def test_a_layout_may_be_a_list_of_rows_and_the_legend_orders_the_features() -> None:
    text = SMALL.replace('layout = """\n.aa.\n.bby\n.ab.\n"""', 'layout = [".aa.", ".bby", ".ab."]')
    text = text.replace(
        'legend = { a = "amber", b = "blue", "." = "", y = "" }',
        'legend = { b = "blue", "." = "", a = "amber", y = "" }',
    )
    text = text.replace("ab = { amber = 0, blue = -1", "ab = { blue = -1, amber = 0")
    pipeline = parse(text)
    assert pipeline.game.tiles.layout == (".aa.", ".bby", ".ab.")
    assert pipeline.game.tile_features.names == ("blue", "amber", "step")
    assert pipeline.tasks[0].weights == (-1.0, 0.0, -0.1)


BAD = [
    # (replace this, with that, the one line expected)
    (
        'features = "tiles"',
        'features = "hex"',
        "game.features must be one of rbf, tiles",
    ),
    (
        "[game.tiles]",
        "[game.tile]",
        "game.tile is not a known key",
    ),
    (
        'goals = "y"',
        'goals = "y"\ncolour = 1',
        "game.tiles.colour is not a known key",
    ),
    (
        'features = "tiles"',
        'features = "tiles"\nwidth = 4',
        'game.width must not be given with game.features = "tiles"',
    ),
    (
        'features = "tiles"',
        'features = "tiles"\nsigma = 1.0',
        'game.sigma must not be given with game.features = "tiles"',
    ),
    (
        'features = "tiles"',
        'features = "tiles"\nfeature_levels = [3]',
        "game.feature_levels must not be given",
    ),
    (
        'features = "tiles"',
        'features = "tiles"\ncenters = "shared"',
        "game.centers must not be given",
    ),
    (
        'features = "tiles"\n',
        "",
        'game.tiles must not be given unless game.features = "tiles"',
    ),
    (
        ".bby\n",
        ".bbyy\n",
        "game.tiles.layout must be a rectangle",
    ),
    (
        ".bby\n",
        ".b y\n",
        "game.tiles.layout must be printable ASCII characters other than a space",
    ),
    (
        ".bby\n",
        ".bqy\n",
        "game.tiles.legend must name every character of the layout, not ['q']",
    ),
    (
        'y = "" }',
        'y = "", z = "" }',
        "game.tiles.legend must name only characters of the layout, not ['z']",
    ),
    (
        'y = "" }',
        'yy = "" }',
        "game.tiles.legend.yy must be one printable ASCII character",
    ),
    (
        'a = "amber"',
        'a = "1amber"',
        'game.tiles.legend.a must be "" (no feature) or a feature name',
    ),
    (
        'legend = { a = "amber", b = "blue"',
        'legend = { a = "", b = ""',
        "game.tiles.legend must name at least one feature",
    ),
    (
        'goals = "y"',
        'goals = "yy"',
        "game.tiles.goals must be a string of distinct characters",
    ),
    (
        'goals = "y"',
        'goals = "q"',
        "game.tiles.goals must be characters of the legend, not ['q']",
    ),
    (
        'y = "" }',
        'y = "gold" }',
        "game.tiles.goals must not all carry 'gold', a feature of no other cell",
    ),
    (
        'goals = "y"',
        'goals = ""',
        "game.tiles.step must not be given without goals",
    ),
    (
        'step = "step"',
        'step = "blue"',
        "game.tiles.step must not be a feature of the legend",
    ),
    (
        "start = [0, 1]",
        "start = [4, 1]",
        "game.start must be a cell [x, y] of the 4x3 grid",
    ),
    (
        "start = [0, 1]",
        "start = [3, 1]",
        "game.start must not be a goal cell",
    ),
    (
        "learning_steps = 5",
        "learning_steps = 2",
        "game.learning_steps must be at least the 3 moves",
    ),
    (
        "deployment_steps = 5",
        "deployment_steps = 3",
        "game.deployment_steps must be at least the 4 moves from cell [0, 0]",
    ),
    (
        "amber = 0, blue = -1",
        "amber = 0, blue = -1.5",
        "tasks.ab.blue must be a number in [-1, 1]",
    ),
    (
        "amber = 0, blue = -1",
        "amber = true, blue = -1",
        "tasks.ab.amber must be a number in [-1, 1]",
    ),
    (
        "amber = 0, blue = -1, ",
        "amber = 0, ",
        "tasks.ab must give every feature a weight (amber, blue, step); blue is missing",
    ),
    (
        "blue = -1, step",
        "blue = -1, red = 0, step",
        "tasks.ab.red is not a feature of the game",
    ),
    (
        "\nab = {",
        '\n"a b" = {',
        "tasks must be a task name",
    ),
    (
        "\nab = {",
        "\nab = 3\nx = {",
        "tasks.ab must be a table of weights",
    ),
    (
        "rationality = 1.0\nhumans",
        "subjects = 2\nrationality = 1.0\nhumans",
        "main.subjects must not be given with [tasks] (each task is one subject)",
    ),
    (
        "learning_steps = 5",
        "learning_steps = 17\ndemonstrator_stays_ = 1",
        "game.demonstrator_stays_ is not a known key",
    ),
    (
        "[eta_cv]",
        "[multiverse.alone]\nsteps = [7]\n\n[eta_cv]",
        'multiverse must not be given with game.features = "tiles"',
    ),
]


@pytest.mark.parametrize(("old", "new", "message"), BAD, ids=[case[2][:40] for case in BAD])
def test_a_bad_tile_game_or_task_is_refused_in_one_line(old: str, new: str, message: str) -> None:
    assert old in SMALL
    with pytest.raises(UserError) as refused:
        parse(SMALL.replace(old, new, 1))
    line = str(refused.value)
    assert "\n" not in line and line.startswith("x.toml: ")
    assert message in line, line


@pytest.mark.parametrize(
    ("new", "message"),
    [
        ('hypotheses = "tasks"\nincludes_truth = false', "teaching.includes_truth must be true"),
        ('hypotheses = "all"', 'must be an integer of at least 2, or "tasks"'),
    ],
)
def test_hypotheses_of_tasks_are_refused_in_one_line_where_wrong(new: str, message: str) -> None:
    text = SMALL.replace("hypotheses = 4\nincludes_truth = true", new, 1)
    with pytest.raises(UserError) as refused:
        parse(text)
    assert "\n" not in str(refused.value) and message in str(refused.value)


def test_a_study_of_tasks_needs_two_tasks() -> None:
    """Each task is a subject, and the analysis needs the spread of two; so do hypotheses
    that are the tasks."""
    text = SMALL.replace("ba = { amber = -1, blue = 0, step = -0.1 }\n", "")
    with pytest.raises(UserError, match="tasks must name at least 2 tasks .*, got 1$"):
        parse(text)
    with pytest.raises(UserError, match="tasks must name at least 2 tasks"):
        parse(text.replace("hypotheses = 4", 'hypotheses = "tasks"', 1))


def test_the_hypotheses_of_tasks_are_the_tasks_the_trials_own_first() -> None:
    """With ``hypotheses = "tasks"`` every task's trial lists the tasks, and the pedagogic
    human's space is exactly them, her own task first; a cross-validation draw, no task,
    draws its space and plays."""
    pipeline = parse(SMALL.replace("hypotheses = 4", 'hypotheses = "tasks"', 1))
    assert pipeline.hypothesis_count == 2
    cv = eta_cv_trials(pipeline)
    assert cv and all(spec.teaching.listed == () and spec.task is None for spec in cv)
    for spec in cv:
        check_playable(spec)
    etas = {(None, human, 3): 1.0 for human in pipeline.humans_with_eta}
    specs = [spec for spec in study_trials(pipeline, etas) if spec.human == "pedagogic"]
    assert specs and all(spec.teaching.listed == ((0.0, -1.0, -0.1), (-1.0, 0.0, -0.1))
                         for spec in specs)  # fmt: skip
    from cirl_study.core.trial import _Setting

    for spec in specs:
        check_playable(spec)

    setting = _Setting.of(specs)
    space = setting.game.space().thetas
    for b, spec in enumerate(specs):
        assert space[b].tolist() == [list(spec.theta)] + [
            list(task) for task in spec.teaching.listed if task != spec.theta
        ]


def test_tasks_need_a_tile_game() -> None:
    rbf = (REPO / "pipelines" / "smoke.toml").read_text()
    text = rbf + "\n[tasks]\nab = { phi1 = 0 }\n"
    with pytest.raises(UserError, match='tasks must not be given unless game.features = "tiles"'):
        parse(text)


def test_a_hypothesis_space_is_refused_past_the_paths_it_enumerates() -> None:
    text = SMALL.replace('"""\n.aa.\n.bby\n.ab.\n"""', '"""\n.aa...\n.bby..\n.ab...\n......\n"""')
    text = text.replace("learning_steps = 5", "learning_steps = 21")
    with pytest.raises(UserError, match="game.learning_steps gives .* learning paths, more than"):
        parse(text)


def test_the_rbf_pipelines_write_the_keys_they_read() -> None:
    """A spec read from an ``rbf`` file writes back the keys that file holds: the optional
    ``features`` and the tile game's keys are not written (a probe's pipeline text, written
    from the specs, stays the same)."""
    import tomllib

    for path in sorted((REPO / "pipelines").glob("*.toml")):
        data = tomllib.loads(path.read_text())
        if data["game"].get("features", "rbf") != "rbf":
            continue
        pipeline = load_pipeline(path)
        assert list(written(pipeline.game)) == list(data["game"]), path.name
        assert pipeline.game.goals == () and pipeline.tasks is None


def test_the_shipped_tiles_pipeline_is_ho_et_als_task() -> None:
    pipeline = load_pipeline(TILES)
    game = pipeline.game
    assert (game.width, game.height, game.start, game.goals) == (6, 5, (0, 2), ((5, 2),))
    assert game.tiles.layout == (".oooo.", ".oppp.", ".opccy", ".oppc.", ".cccc.")
    assert game.tile_features.names == ("orange", "purple", "cyan", "step")
    assert not game.demonstrator_stays
    names = ["".join(code) for code in itertools.product("ox", repeat=3)]
    assert [task.name for task in pipeline.tasks] == names
    for task in pipeline.tasks:
        *colours, step = task.weights
        assert colours == [0.0 if code == "o" else -1.0 for code in task.name]
        assert step < 0


def test_the_plan_of_tiles_has_goals_tasks_and_tile_features() -> None:
    pipeline = load_pipeline(TILES)
    cv = eta_cv_trials(pipeline)
    etas = {(None, human, 4): 1.0 for human in pipeline.humans_with_eta}
    study = study_trials(pipeline, etas)
    assert cv and study
    for spec in cv + study:
        assert isinstance(spec.features, TileFeatures)
        assert spec.features == pipeline.game.tile_features
        assert spec.goals == ((5, 2),) and spec.num_features == 4
    assert {spec.task for spec in cv} == {None}
    assert all(spec.subject.startswith("cv-k04-s") for spec in cv)
    tasks = {spec.subject: spec.task for spec in study}
    assert tasks == {f"main-k04-{task.name}": task.name for task in pipeline.tasks}
    weights = {task.name: task.weights for task in pipeline.tasks}
    assert all(spec.theta == weights[spec.task] for spec in study)


def test_a_tasks_trials_do_not_depend_on_the_order_of_the_tasks() -> None:
    text = SMALL
    swapped = text.replace(
        "ab = { amber = 0, blue = -1, step = -0.1 }\nba = { amber = -1, blue = 0, step = -0.1 }",
        "ba = { amber = -1, blue = 0, step = -0.1 }\nab = { amber = 0, blue = -1, step = -0.1 }",
    )
    assert swapped != text
    planned = []
    for version in (text, swapped):
        pipeline = parse(version)
        etas = {(None, "best_response", 3): 0.1}
        planned.append({(s.trial_id, s.seed, s.theta) for s in study_trials(pipeline, etas)})
    assert planned[0] == planned[1]


def test_the_feature_matrix_of_ho_et_als_layout_by_hand() -> None:
    """Columns orange, purple, cyan, step; row ``y * 6 + x``; rows of the layout from y = 4."""
    layout = [".oooo.", ".oppp.", ".opccy", ".oppc.", ".cccc."]
    onehot = {"o": [1, 0, 0], "p": [0, 1, 0], "c": [0, 0, 1], ".": [0, 0, 0], "y": [0, 0, 0]}
    expected = np.zeros((30, 4))
    for y in range(5):
        for x in range(6):
            expected[y * 6 + x] = [*onehot[layout[4 - y][x]], 1]
    # spot checks written out: the start (0, 2) is white, (3, 2) cyan, (1, 4) orange, the
    # goal (5, 2) has the step feature only.
    assert expected[2 * 6 + 0].tolist() == [0, 0, 0, 1]
    assert expected[2 * 6 + 3].tolist() == [0, 0, 1, 1]
    assert expected[4 * 6 + 1].tolist() == [1, 0, 0, 1]
    assert expected[2 * 6 + 5].tolist() == [0, 0, 0, 1]
    features = load_pipeline(TILES).game.tile_features
    np.testing.assert_array_equal(feature_matrix(6, 5, features), expected)


SYMBOLS = "abcde.#"
NAMES = ("red", "green", "blue", "")


@st.composite
def tile_tables(draw):
    """A ``[game.tiles]`` table of a random layout and legend, with or without a step."""
    width = draw(st.integers(1, 6))
    height = draw(st.integers(1 if width > 1 else 2, 5))
    rows = [
        "".join(draw(st.lists(st.sampled_from(SYMBOLS), min_size=width, max_size=width)))
        for _ in range(height)
    ]
    used = list(dict.fromkeys("".join(rows)))
    legend = {char: draw(st.sampled_from(NAMES)) for char in draw(st.permutations(used))}
    if not any(legend.values()):
        legend[used[0]] = "red"
    table = {"layout": "\n".join(rows) if draw(st.booleans()) else rows, "legend": legend}
    if draw(st.booleans()):
        goal = draw(st.sampled_from(used))
        named_elsewhere = {name for char, name in legend.items() if char != goal}
        if legend[goal] and legend[goal] not in named_elsewhere:
            legend[goal] = ""
            if not any(legend.values()):
                return None
        table["goals"] = goal
        table["step"] = "step"
    return table


@settings(max_examples=200, deadline=None)
@given(tile_tables())
def test_a_tile_layout_reads_into_one_hot_features_and_the_step(table) -> None:
    if table is None:
        return
    spec: TilesSpec = Table("x.toml", "game.", {"tiles": table}, ["tiles"]).spec("tiles", TilesSpec)
    features = spec.features
    legend = table["legend"]
    named = list(dict.fromkeys(name for name in legend.values() if name))
    assert features.names == tuple(named + (["step"] if "step" in table else []))
    assert features.faults(spec.width, spec.height) == []
    phi = feature_matrix(spec.width, spec.height, features)
    rows = spec.layout
    for y in range(spec.height):
        for x in range(spec.width):
            row = phi[y * spec.width + x]
            name = legend[rows[spec.height - 1 - y][x]]
            colours = row[: len(named)]
            assert set(colours.tolist()) <= {0.0, 1.0}
            assert colours.sum() == (1.0 if name else 0.0)
            if name:
                assert colours[named.index(name)] == 1.0
            if "step" in table:
                assert row[-1] == 1.0


@pytest.fixture(scope="module")
def small_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    base = tmp_path_factory.mktemp("tiles")
    pipeline, out = base / "tiles-small.toml", base / "run"
    pipeline.write_text(SMALL)
    result = CliRunner().invoke(app, ["run", str(pipeline), "--out", str(out), "--workers", "1"])
    assert result.exit_code == 0, result.output
    return out


def test_a_small_tile_study_runs_validates_and_is_analysed(small_run: Path) -> None:
    result = CliRunner().invoke(app, ["validate", str(small_run)])
    assert result.exit_code == 0, result.output
    assert result.output.strip().splitlines()[-1].endswith("design complete")
    result = CliRunner().invoke(app, ["analyze", str(small_run)])
    assert result.exit_code == 0, result.output
    report = small_run / "report"
    assert (report / "report.md").is_file() and (report / "figure1_reward_maps.png").is_file()
    assert cirl_study.analyze(small_run).design.humans == ["expert", "best_response", "pedagogic"]


def test_every_tile_record_ends_in_the_goal_and_names_its_task(small_run: Path) -> None:
    records = run_records(small_run)
    for record in records:
        assert record.demonstration.states[-1] == (3, 1)
        assert (3, 1) not in record.demonstration.states[:-1]
        assert len(record.demonstration.actions) <= 5
        assert (record.task is None) == (record.block != MAIN)


def test_the_map_robot_reports_the_exact_likelihood_of_its_estimate(small_run: Path) -> None:
    """Each MAP fit's logged log-likelihood is the MaxEnt model's at its estimate, by the
    backward recursion over the paths that reach the goal in time."""
    grid = Gridworld(4, 3)
    for record in run_records(small_run):
        if record.robot != MAP:
            continue
        phi = feature_matrix(4, 3, record.features)[None]
        phase = Phase(grid.demonstrator_moves(False), grid.index(0, 1), 5, (grid.index(3, 1),))
        model = MaxEnt(phase, phi, record.rationality)
        cells = [grid.index(*cell) for cell in record.demonstration.states]
        demo = np.array([cells + [phase.sink] * (6 - len(cells))])
        exact = model.log_likelihood(np.array([record.theta_hat]), model.path_counts(demo))[0]
        assert record.irl.log_likelihood == pytest.approx(exact, rel=1e-9, abs=1e-12)


def test_the_limits_count_the_sink_and_the_longer_paths() -> None:
    """A goal game's programmes run over one more cell (the sink), and the enumeration of
    13-move paths on 31 cells keys each class by a bit string (5 bits x 13 > 63)."""
    from cirl_study.study.limits import batch_memory, enumeration_bytes, game_cells

    pipeline = load_pipeline(TILES)
    assert game_cells(pipeline) == 31
    assert enumeration_bytes(9, 100) == 200  # the paper's phase, as before
    assert enumeration_bytes(13, 31) == 448  # measured peak: 325 bytes a path
    assert enumeration_bytes(12, 31) == 260  # keys of 60 bits still fit an integer
    assert batch_memory(pipeline) < 2**30
