"""The refinement of a calibration (``cirl-study calibrate --refine``): the coordinate search
by hand and as properties on synthetic distances (``cirl_study.analysis.calibration.refine``), the
probe pipelines (``cirl_study.study.probes``), and end to end on tiny runs: back to the true sigma
from a neighbour, resumed rather than replayed, within the budget, and refusals."""

from __future__ import annotations

import json
import math
import shutil
import sys
from dataclasses import replace
from pathlib import Path

import msgspec
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from cirl_study.analysis.calibration.refine import (
    MIN_STEP,
    SearchAxis,
    coordinate_search,
    neighbours,
    round_significant,
)
from cirl_study.cli import app
from cirl_study.study.pipeline_file import load_pipeline, parse_pipeline
from cirl_study.study.probes import probe_pipeline, probe_text
from cirl_study.study.spec import AXES

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_multiverse import multiverse_text  # noqa: E402

SIGMA = SearchAxis("sigma", False, lambda v: 0.02 <= v <= 1000)
STEPS = SearchAxis("ascent_steps", True, lambda v: 1 <= v <= 100_000)


def _log_bowl(*optimum: float):
    """A distance with its minimum 0 at ``optimum``: the squared log distance to it."""
    return lambda point: sum(math.log(x / o) ** 2 for x, o in zip(point, optimum, strict=True))


# ---- the search, by hand -------------------------------------------------------------------


def test_the_search_halves_to_the_optimum_and_stops_there_at_distance_0() -> None:
    bowl = _log_bowl(1.5)
    search = coordinate_search((0.75,), [SIGMA], bowl, known={(0.75,): bowl((0.75,))})
    # s = 2: 0.375 is farther, 1.5 is at 0: taken, and nothing is nearer than 0.
    assert [(e.point, e.step, e.accepted) for e in search.evaluations] == [
        ((0.375,), 2.0, False),
        ((1.5,), 2.0, True),
    ]
    assert search.point == (1.5,) and search.distance == 0
    assert search.stop == "exact" and search.probes == 2


def test_the_search_shrinks_its_step_and_stops_when_the_distance_stops_falling() -> None:
    bowl = _log_bowl(1.6)
    known = {(0.75,): bowl((0.75,)), (3.0,): bowl((3.0,))}
    search = coordinate_search((0.75,), [SIGMA], bowl, known=known)
    # s = 2 from 0.75: 0.375, 1.5 (taken); from 1.5: 0.75 (measured), 3 (known, the run's);
    # s = sqrt 2: 1.06, 2.12; s = 2^(1/4): 1.26, 1.78; none nearer than 1.5: converged.
    assert [e.point[0] for e in search.evaluations] == [0.375, 1.5, 3.0, 1.06, 2.12, 1.26, 1.78]
    assert [e.probed for e in search.evaluations] == [True, True, False, True, True, True, True]
    assert [e.step for e in search.evaluations] == pytest.approx(
        [2, 2, 2, 2**0.5, 2**0.5, MIN_STEP, MIN_STEP]
    )
    assert [e.point for e in search.evaluations if e.accepted] == [(1.5,)]
    assert search.point == (1.5,) and search.stop == "converged" and search.probes == 6
    assert search.distance == pytest.approx(math.log(1.5 / 1.6) ** 2)


def test_the_search_moves_one_axis_at_a_time_and_takes_the_nearer_neighbour() -> None:
    bowl = _log_bowl(4.0, 7)
    search = coordinate_search((1.0, 30), [SIGMA, STEPS], bowl, known={(1.0, 30): bowl((1.0, 30))})
    accepted = [e.point for e in search.evaluations if e.accepted]
    assert accepted[:2] == [(2.0, 30), (2.0, 15)]  # sigma first, then steps, in one sweep
    assert search.point == (4.0, 7) and search.stop == "exact"


def test_the_budget_stops_the_search_at_the_last_point_it_could_afford() -> None:
    bowl = _log_bowl(1.6)
    search = coordinate_search((0.75,), [SIGMA], bowl, known={(0.75,): bowl((0.75,))}, max_probes=1)
    assert [e.point for e in search.evaluations] == [(0.375,)]
    assert search.stop == "budget" and search.point == (0.75,) and search.probes == 1


def test_a_point_that_cannot_be_ranked_is_never_taken() -> None:
    search = coordinate_search(
        (1.0,), [SIGMA], lambda point: None, known={(1.0,): 0.5}, max_probes=50
    )
    assert search.point == (1.0,) and search.stop == "converged" and search.probes == 6
    assert all(e.distance is None and not e.accepted for e in search.evaluations)


def test_a_setting_left_to_be_chosen_moves_from_the_value_chosen_at_the_point() -> None:
    # eta left to cross-validation (None) is chosen as 2 sigma at a point; the distance is
    # the squared log distance of (sigma, eta) to (1, 0.5), eta the value chosen where None.
    asked: list[tuple] = []

    def chosen(point: tuple) -> float:
        asked.append(point)
        return 2 * point[0]

    eta = SearchAxis("eta_k3", False, lambda v: 1e-6 <= v <= 1e6, chosen=chosen)

    def bowl(point: tuple) -> float:
        value = 2 * point[0] if point[1] is None else point[1]
        return math.log(point[0]) ** 2 + math.log(value / 0.5) ** 2

    start = (2.0, None)
    search = coordinate_search(start, [SIGMA, eta], bowl, known={start: bowl(start)})
    # sigma 2 -> 1 keeps eta chosen (now 2); its neighbours fix it at 1 and 4, and 1 -> 0.5
    assert [e.point for e in search.evaluations if e.accepted] == [
        (1.0, None),
        (1.0, 1.0),
        (1.0, 0.5),
    ]
    from_chosen = [(e.point, e.origin) for e in search.evaluations if e.origin[1] is None]
    assert from_chosen == [
        ((1.0, None), (2.0, None)),
        ((4.0, None), (2.0, None)),
        ((1.0, 1.0), (1.0, None)),
        ((1.0, 4.0), (1.0, None)),
    ]
    assert asked == [(1.0, None)] and search.stop == "exact"


def test_neighbours_keep_to_integers_and_to_the_constraint() -> None:
    assert neighbours(30, STEPS, 2.0) == [15, 60]
    assert neighbours(30, STEPS, MIN_STEP) == [25, 36]
    assert neighbours(2, STEPS, MIN_STEP) == [1, 3]  # at least one step either way
    assert neighbours(1, STEPS, 2.0) == [2]  # 0 is not a step budget
    assert neighbours(1.5, SIGMA, 2**0.5) == [1.06, 2.12]  # three significant digits
    assert neighbours(800.0, SIGMA, 2.0) == [400.0]  # 1600 passes sigma's bound
    assert round_significant(1.0606601717798212) == 1.06


# ---- the search, as properties ---------------------------------------------------------------

REAL = parse_pipeline(multiverse_text("[multiverse]\n"), Path("mv.toml"))
"""A 5x5 game, whose sigma may be 0.02 to 1000 grid diagonals."""

REAL_AXES = [
    SearchAxis(name, name == "ascent_steps", AXES[name].levels(REAL.game)[0])
    for name in ("sigma", "ascent_steps", "learning_rate")
]


@settings(max_examples=60, deadline=None)
@given(
    start=st.tuples(
        st.floats(0.02, 5000).map(round_significant),
        st.integers(1, 100_000),
        st.floats(1e-12, 100).map(round_significant),
    ),
    optimum=st.tuples(st.floats(1e-3, 1e5), st.floats(0.1, 1e6), st.floats(1e-14, 1e4)),
    budget=st.integers(1, 30),
)
def test_the_search_keeps_to_each_settings_constraint_and_budget(start, optimum, budget) -> None:
    """Whatever the optimum (often outside a setting's range), every point measured is a
    valid level of each setting, the probes stay within the budget, the distance never
    rises, the same inputs give the same probes, and a converged search ends at a point no
    neighbour at the smallest step is nearer than."""
    if not all(axis.valid(value) for axis, value in zip(REAL_AXES, start, strict=True)):
        return
    bowl = _log_bowl(*optimum)
    search = coordinate_search(
        start, REAL_AXES, bowl, known={start: bowl(start)}, max_probes=budget
    )
    for e in search.evaluations:
        assert all(axis.valid(v) for axis, v in zip(REAL_AXES, e.point, strict=True)), e
        assert isinstance(e.point[1], int)
    assert search.probes == len(search.evaluations) <= budget
    assert search.distance <= bowl(start)
    moved = [e.distance for e in search.evaluations if e.accepted]
    assert moved == sorted(moved, reverse=True)
    again = coordinate_search(start, REAL_AXES, bowl, known={start: bowl(start)}, max_probes=budget)
    assert again == search
    if search.stop == "converged":
        for index, axis in enumerate(REAL_AXES):
            for value in neighbours(search.point[index], axis, MIN_STEP):
                point = search.point[:index] + (value,) + search.point[index + 1 :]
                assert bowl(point) >= search.distance


# ---- probe pipelines -----------------------------------------------------------------------

ASCENT = """
[gradient_ascent]
steps = 30
learning_rate = 0.1

[multiverse.alone]
sigma = [1.5]
robot = ["gradient_ascent"]
regret = ["estimate"]
"""


@pytest.mark.parametrize("which", [0, 1, 2, 3])
def test_a_probe_is_its_universe_with_the_runs_subjects_and_cross_validation(which: int) -> None:
    from cirl_study.study.multiverse import cv_universe, universe_pipeline
    from cirl_study.study.plan import eta_cv_trials, gradient_ascent_settings

    run = parse_pipeline(multiverse_text(ASCENT), Path("mv.toml"))
    universe = run.multiverse.universes[which]
    moved = {"sigma": 1.2}
    if universe.robot == "gradient_ascent":
        moved |= {"ascent_steps": 12, "learning_rate": 0.05}
    probe = replace(universe, **moved)
    study = probe_pipeline(run, probe, Path("probe/pipeline.toml"))
    assert study.text == probe_text(run, probe) and study.seed == run.seed
    assert study.multiverse.universes[-1] == probe
    cv = cv_universe(run, probe)
    assert study.multiverse.base == cv and len(study.multiverse.universes) == 1 + (probe != cv)
    # the probe plays what the run would for it: its study, and its cross-validation
    mine, theirs = universe_pipeline(study, probe), universe_pipeline(run, probe)
    assert (mine.game, mine.main, mine.eta_cv) == (theirs.game, theirs.main, theirs.eta_cv)
    assert gradient_ascent_settings(mine, probe.robot) == gradient_ascent_settings(
        theirs, probe.robot
    )
    # the same cross-validation trials, but for the run they belong to
    ours, run_s = (
        [msgspec.structs.replace(t, run_id="") for t in eta_cv_trials(universe_pipeline(p, cv))]
        for p in (study, run)
    )
    assert ours == run_s and len(ours) == 18


@pytest.mark.parametrize(
    "setting",
    [
        {"eta": ((3, 2.0), (10, 0.5))},
        {"eta": ((10, 0.5),)},
        {"eta_measure": "kl"},
        {"eta_grid": (0.5, 5.0)},
        {"eta": ((3, 2.0),), "eta_measure": "reward_l2", "robot": "posterior_mean"},
    ],
)
def test_a_probe_of_an_eta_setting_plays_the_trials_the_run_would(setting: dict) -> None:
    from cirl_study.study.multiverse import cv_universe, universe_pipeline
    from cirl_study.study.plan import eta_cv_trials, study_trials

    run = parse_pipeline(multiverse_text("[multiverse]\n"), Path("mv.toml"))
    probe = replace(run.multiverse.base, **setting).fitted(None, run.game.feature_levels)
    study = probe_pipeline(run, probe, Path("probe/pipeline.toml"))
    assert study.multiverse.universes[-1] == probe and study.seed == run.seed
    etas = {(probe.id, human, k): 1.0 for human in ("best_response",) for k in (3, 10)}

    def trials(pipeline):
        main = study_trials(universe_pipeline(pipeline, probe), etas)
        cv = cv_universe(pipeline, probe)
        validation = [] if cv is None else eta_cv_trials(universe_pipeline(pipeline, cv))
        return [msgspec.structs.replace(t, run_id="") for t in [*validation, *main]]

    assert trials(study) == trials(run) and trials(run)
    fixed_everywhere = "eta" in setting and len(setting["eta"]) == 2
    assert (cv_universe(run, probe) is None) == fixed_everywhere


# ---- end to end ----------------------------------------------------------------------------

TRUE_SIGMA = 1.5


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A target made from the cell means of the universe at sigma = 1.5, and a multiverse
    run of the universes at its neighbours 0.75 (the nearest) and 3, but not at 1.5."""
    from cirl_study.api import load_trials
    from cirl_study.study.engines import LocalEngine
    from cirl_study.study.runner import run_pipeline

    directory = tmp_path_factory.mktemp("refine")
    source = directory / "source.toml"
    source.write_text(
        multiverse_text("[multiverse]\n", "source").replace("sigma = 0.75", f"sigma = {TRUE_SIGMA}")
    )
    run_pipeline(load_pipeline(source), directory / "source", LocalEngine(1))
    table = load_trials(directory / "source")
    rows = ["measure,num_features,human,value"]
    for (k, human), cell in table[table["block"] == "main"].groupby(["num_features", "human"]):
        for measure in ("regret", "kl", "reward_l2"):
            mean = float(cell[measure].mean())
            if mean > 0:
                rows.append(f"{measure},{k},{human},{mean!r}")
    target = directory / "target.csv"
    target.write_text("\n".join(rows) + "\n")
    pipeline = directory / "mv.toml"
    pipeline.write_text(multiverse_text("[multiverse.alone]\nsigma = [3.0]\n"))
    run_pipeline(load_pipeline(pipeline), directory / "run", LocalEngine(1))
    return {"run": directory / "run", "target": target, "source": directory / "source"}


def _refine(runs: dict[str, Path], tmp_path: Path, *extra: str, probes: Path | None = None):
    out = tmp_path / "calibration"
    command = ["calibrate", str(runs["run"]), "--target", str(runs["target"]), "--out", str(out)]
    command += ["--refine", "--workers", "1", "--probes", str(probes or tmp_path / "probes")]
    result = CliRunner().invoke(app, [*command, *extra])
    results = json.loads((out / "results.json").read_text()) if result.exit_code == 0 else None
    return result, results


def _probe_files(probes: Path) -> dict[str, int]:
    """Each probe's logs and pipeline file, by path, and when they were last written."""
    files = [*probes.glob("*/*.mcap"), *probes.glob("*/pipeline.toml")]
    return {str(p.relative_to(probes)): p.stat().st_mtime_ns for p in sorted(files)}


def test_the_refinement_returns_to_the_true_sigma_from_a_neighbour(runs, tmp_path) -> None:
    result, results = _refine(runs, tmp_path)
    assert result.exit_code == 0, result.output
    refinement = results["refinement"]
    assert results["universes"][0]["settings"]["sigma"] == 0.75  # the nearest of the run
    assert refinement["axes"] == ["sigma", "eta_k3", "eta_k10"]
    final = refinement["final"]
    assert final["settings"]["sigma"] == TRUE_SIGMA and "eta" not in final["settings"]
    assert final["mean_squared_log_ratio"] < 1e-28  # its own cell means, to rounding
    assert refinement["stop"] == "converged"
    probes = refinement["probes"]
    assert [p["settings"]["sigma"] for p in probes if p["axis"] == "sigma"] == [
        0.375, 1.5, 3.0, 1.06, 2.12, 1.26, 1.78,
    ]  # fmt: skip
    # each eta is cross-validated at sigma = 1.5 (10 at 3 features, 0.1 at 10), and its
    # probes fix it at the neighbours of that choice, the other level's left to its own
    assert [p["settings"]["eta_k3"] for p in probes if p["axis"] == "eta_k3"] == [
        5.0, 20.0, 7.07, 14.1, 8.41, 11.9,
    ]  # fmt: skip
    assert [p["settings"]["eta_k10"] for p in probes if p["axis"] == "eta_k10"] == [
        0.05, 0.2, 0.0707, 0.141, 0.0841, 0.119,
    ]  # fmt: skip
    for p in probes:
        if p["axis"] != "sigma":
            assert p["settings"]["sigma"] == TRUE_SIGMA
            other = "eta_k10" if p["axis"] == "eta_k3" else "eta_k3"
            assert p["settings"][other] == "cv"
    assert [p["source"] for p in probes].count("run") == 1 and len(probes) == 19
    assert (refinement["played"], refinement["reused"]) == (18, 0)
    assert [p["settings"] for p in probes if p["accepted"]] == [refinement["final_settings"]]
    assert refinement["final_settings"] == {"sigma": 1.5, "eta_k3": "cv", "eta_k10": "cv"}
    assert result.stdout.splitlines()[-1] == (
        "refinement over sigma, eta_k3, eta_k10: 18 probe(s) (18 played now, 0 reused), "
        "stopped because no neighbour at the smallest step is nearer: sigma 0.75 -> 1.5, "
        f"eta_k3 cv -> cv, eta_k10 cv -> cv, D = {final['mean_squared_log_ratio']:.4g} (was "
        f"{results['universes'][0]['mean_squared_log_ratio']:.4g})"
    )
    assert "probe 14 (at most 40): sigma=1.78," in result.stderr
    # the eta of a feature level moves only the best response's cells at that level
    for move in refinement["moves"]:
        if move["setting"].startswith("eta_k"):
            level = int(move["setting"].removeprefix("eta_k"))
            taught = (move["human"], move["num_features"]) == ("best_response", level)
            assert taught or move["log_ratio"] == 0, move
    assert any(m["setting"] == "eta_k10" and m["log_ratio"] != 0 for m in refinement["moves"])
    assert all(m["log_ratio"] != 0 for m in refinement["moves"] if m["setting"] == "sigma")
    probe = tmp_path / "probes" / final["id"]
    assert (probe / "pipeline.toml").is_file() and list(probe.glob("*.mcap"))
    # a probe is a run as any other: the same trials as the source run's, under its own id
    validated = CliRunner().invoke(app, ["validate", str(probe)])
    assert validated.exit_code == 0, validated.output
    report = (tmp_path / "calibration" / "report.md").read_text()
    assert "## Refinement" in report and "| `sigma` | `0.75` | `1.5` (moved) |" in report
    assert "| measure | K | human | sigma | eta_k3 | eta_k10 |" in report
    assert (tmp_path / "calibration" / "probes.csv").read_text().count("\n") == 20

    # run again: every probe is read back, none replayed, and the search is the same
    before = _probe_files(tmp_path / "probes")
    again, repeated = _refine(runs, tmp_path)
    assert again.exit_code == 0, again.output
    assert _probe_files(tmp_path / "probes") == before
    assert "0 to play" in again.stderr and "18 played now" not in again.stdout
    second = repeated["refinement"]
    assert (second["played"], second["reused"]) == (0, 18)
    strip = [{k: v for k, v in p.items() if k != "source"} for p in refinement["probes"]]
    assert [{k: v for k, v in p.items() if k != "source"} for p in second["probes"]] == strip
    assert second["final"] == final and second["stop"] == refinement["stop"]


def test_the_budget_bounds_the_probes(runs, tmp_path) -> None:
    result, results = _refine(runs, tmp_path, "--max-probes", "1")
    assert result.exit_code == 0, result.output
    refinement = results["refinement"]
    assert refinement["stop"] == "budget" and refinement["max_probes"] == 1
    assert [p["settings"]["sigma"] for p in refinement["probes"]] == [0.375]
    assert refinement["final"]["id"] == results["universes"][0]["id"]
    assert len(list((tmp_path / "probes").iterdir())) == 1
    assert "stopped because it spent its --max-probes" in result.stdout


def test_eta_is_searched_only_where_the_target_has_a_cell_it_moves(runs, tmp_path) -> None:
    target = tmp_path / "expert.csv"
    lines = runs["target"].read_text().splitlines()
    target.write_text("\n".join([lines[0], *(line for line in lines if ",expert," in line)]))
    out = tmp_path / "calibration"
    command = ["calibrate", str(runs["run"]), "--target", str(target), "--out", str(out)]
    command += ["--refine", "--workers", "1", "--probes", str(tmp_path / "p"), "--max-probes", "1"]
    result = CliRunner().invoke(app, command)
    assert result.exit_code == 0, result.output
    assert json.loads((out / "results.json").read_text())["refinement"]["axes"] == ["sigma"]


# ---- back to a known eta per feature level --------------------------------------------------

TRUE_ETA = {3: 1.6, 10: 0.2}
"""The etas a target is made with: where the smoke game's best responses at either feature
level differ from those at twice the eta and at half of it."""

NOISE = 0.02
"""The target's cell means are its universe's, each times ``exp(NOISE z)``, ``z`` standard
normal: a reading of a figure is not exact."""


def _fixed(etas: dict[int, float]) -> str:
    return "{" + ", ".join(f"{k} = {eta!r}" for k, eta in etas.items()) + "}"


@pytest.fixture(scope="module")
def eta_runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A target made from the cell means of the universe with :data:`TRUE_ETA` fixed, with
    noise, and a multiverse run of the universe at twice those etas (the nearest) and the
    base (its etas cross-validated), but not at :data:`TRUE_ETA`."""
    import numpy as np

    from cirl_study.api import load_trials
    from cirl_study.study.engines import LocalEngine
    from cirl_study.study.runner import run_pipeline

    directory = tmp_path_factory.mktemp("refine-eta")
    source = directory / "source.toml"
    source.write_text(
        multiverse_text(f"[[multiverse.universes]]\neta = {_fixed(TRUE_ETA)}\n", "source")
    )
    run_pipeline(load_pipeline(source), directory / "source", LocalEngine(1))
    table = load_trials(directory / "source")
    table = table[(table["block"] == "main") & table["universe"].str.contains(",eta=")]
    noise = np.random.default_rng(5)
    rows = ["measure,num_features,human,value"]
    for (k, human), cell in table.groupby(["num_features", "human"]):
        for measure in ("regret", "kl", "reward_l2"):
            value = float(cell[measure].mean()) * math.exp(NOISE * noise.standard_normal())
            rows.append(f"{measure},{k},{human},{value!r}")
    target = directory / "target.csv"
    target.write_text("\n".join(rows) + "\n")
    twice = {k: 2 * eta for k, eta in TRUE_ETA.items()}
    pipeline = directory / "mv.toml"
    pipeline.write_text(multiverse_text(f"[multiverse.alone]\neta = [{_fixed(twice)}]\n"))
    run_pipeline(load_pipeline(pipeline), directory / "run", LocalEngine(1))
    return {"run": directory / "run", "target": target}


def test_the_refinement_recovers_a_known_eta_per_level_from_a_neighbour(eta_runs, tmp_path):
    result, results = _refine(eta_runs, tmp_path)
    assert result.exit_code == 0, result.output
    refinement = results["refinement"]
    assert results["universes"][0]["settings"]["eta"] == "k3:3.2+k10:0.4"  # the start
    assert refinement["start_settings"] == {"sigma": 0.75, "eta_k3": 3.2, "eta_k10": 0.4}
    assert refinement["final_settings"] == {"sigma": 0.75, "eta_k3": 1.6, "eta_k10": 0.2}
    assert refinement["final"]["settings"]["eta"] == "k3:1.6+k10:0.2"
    assert refinement["stop"] == "converged"
    # the noise is all that is left: within a few of its own variance
    assert refinement["final"]["mean_squared_log_ratio"] < 3 * NOISE**2
    moved = [(p["axis"], p["settings"][p["axis"]]) for p in refinement["probes"] if p["accepted"]]
    assert moved == [("eta_k3", 1.6), ("eta_k10", 0.2)]
    for move in refinement["moves"]:
        if move["setting"] == "eta_k3":
            taught = (move["human"], move["num_features"]) == ("best_response", 3)
            assert taught == (move["log_ratio"] != 0), move


def _refused(result, *fragments: str) -> None:
    assert result.exit_code == 2, result.output
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("error: "), result.stderr
    for fragment in fragments:
        assert fragment in last, last


def test_a_probe_directory_of_another_pipeline_is_refused(runs, tmp_path) -> None:
    base = load_pipeline(runs["run"].parent / "mv.toml").multiverse.base
    first = tmp_path / "probes" / replace(base, sigma=0.375).id
    shutil.copytree(runs["source"], first)
    result, _ = _refine(runs, tmp_path, "--max-probes", "1")
    _refused(result, "holds the logs of another run")
    assert not (first / "pipeline.toml").exists()
    shutil.rmtree(first)
    first.mkdir()
    (first / "pipeline.toml").write_text("name = 'mine'\n")
    _refused(_refine(runs, tmp_path, "--max-probes", "1")[0], "holds another pipeline")
    assert (first / "pipeline.toml").read_text() == "name = 'mine'\n"
    shutil.rmtree(first)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    first.symlink_to(elsewhere)
    _refused(_refine(runs, tmp_path, "--max-probes", "1")[0], "symbolic link")
    assert list(elsewhere.iterdir()) == []


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["--max-probes", "3"], "error: --max-probes needs --refine"),
        (["--workers", "1"], "error: --workers needs --refine"),
        (["--refine", "--max-probes", "0"], "error: --max-probes must be a positive integer"),
    ],
)
def test_bad_refine_options_are_one_line(runs, tmp_path, arguments, message) -> None:
    command = ["calibrate", str(runs["run"]), "--target", str(runs["target"])]
    command += ["--out", str(tmp_path / "c"), *arguments]
    result = CliRunner().invoke(app, command)
    assert result.exit_code == 2 and result.stderr.strip().startswith(message), result.output
    assert len(result.stderr.strip().splitlines()) == 1


def test_a_single_study_is_not_refined(smoke_run: Path, runs, tmp_path: Path) -> None:
    command = ["calibrate", str(smoke_run), "--target", str(runs["target"])]
    command += ["--out", str(tmp_path / "c"), "--refine", "--probes", str(tmp_path / "p")]
    result = CliRunner().invoke(app, command)
    assert result.exit_code == 2, result.output
    assert result.stderr.strip().endswith("--refine needs a multiverse run, not a single study")
    assert not (tmp_path / "p").exists()
