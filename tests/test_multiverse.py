"""The multiverse (cirl_study.study.multiverse and cirl_study.analysis.multiverse.results).

Expansion of ``[multiverse]`` into universes, their ids and trials, the open settings each
axis varies (center placement, a demonstrator who may not stay, the deployment start), the
base universe against the single study, resuming mid-multiverse, the joint sign-flip test
against exact enumeration, and the report end to end.
"""

from __future__ import annotations

import errno
import itertools
import json
import math
import os
import re
import shutil
from dataclasses import replace
from pathlib import Path

import mpmath
import msgspec
import numpy as np
import path_enumeration as pe
import pytest
from scipy import special, stats
from test_logs_helpers import run_records
from typer.testing import CliRunner

from cirl_study.analysis.multiverse.results import analyse_multiverse
from cirl_study.analysis.results.study import analyse
from cirl_study.analysis.statistics import procedures as statistics
from cirl_study.cli import app
from cirl_study.core.gridworld import Gridworld, rbf_features
from cirl_study.core.maxent import MaxEnt, Phase
from cirl_study.core.trial import play_trials
from cirl_study.errors import UserError
from cirl_study.logs.format import log_files
from cirl_study.logs.reader import read_run
from cirl_study.logs.validate import validate_run
from cirl_study.record import MAIN, encode
from cirl_study.study.engines import LocalEngine
from cirl_study.study.multiverse import cv_universe, played_universes, universe_pipeline
from cirl_study.study.pipeline_file import load_pipeline, logged_pipeline, parse_pipeline
from cirl_study.study.plan import (
    draw_reward,
    eta_cv_trials,
    lattice_centers,
    study_trials,
    subject_id,
    trial_counts,
)
from cirl_study.study.runner import run_pipeline

SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"

MULTIVERSE = """
[multiverse.cross]
sigma = [0.75, 1.5]
centers = ["per_draw", "lattice"]

[multiverse.alone]
demonstrator_stays = [false]
deployment_start = ["demonstration"]
robot = ["posterior_mean"]
"""


def multiverse_text(tables: str = MULTIVERSE, name: str = "mv") -> str:
    """The smoke pipeline as a multiverse: no lambda sweep, the given ``[multiverse]``."""
    text = SMOKE.read_text()
    text = text[: text.index("[lambda_sweep]")].replace('name = "smoke"', f'name = "{name}"')
    return text + tables


def multiverse(tmp_path: Path, tables: str = MULTIVERSE, name: str = "mv") -> Path:
    path = tmp_path / f"{name}.toml"
    path.write_text(multiverse_text(tables, name))
    return path


def etas_for(pipeline):
    """The same eta for every universe that plays trials, human and feature level."""
    return {
        (universe.id, human, k): 1.0
        for universe in played_universes(pipeline)
        for human in pipeline.humans_with_eta
        for k in pipeline.game.feature_levels
    }


# ---- expansion and identity --------------------------------------------------------------


def test_the_universes_are_the_base_the_cross_product_the_alone_levels_and_the_listed():
    tables = MULTIVERSE + "\n[[multiverse.universes]]\nsigma = 1.5\nsteps = 3\n"
    pipeline = parse_pipeline(multiverse_text(tables), Path("mv.toml"))
    universes = pipeline.multiverse.universes
    base = pipeline.multiverse.base
    assert universes[0] == base and base.id == (
        "sigma=0.75,centers=per_draw,stays=yes,steps=4,lambda=1,robot=map,start=uniform"
    )
    crossed = {(u.sigma, u.centers) for u in universes[:4]}
    assert crossed == set(itertools.product((0.75, 1.5), ("per_draw", "lattice")))
    assert len(universes) == 1 + 4 - 1 + 3 + 1  # the base is in the cross product once
    assert universes[-1].steps == 3 and universes[-1].sigma == 1.5
    assert len({u.id for u in universes}) == len(universes)
    assert pipeline.lambda_sweep is None
    counts = trial_counts(pipeline)
    # cross-validation shared by the posterior-mean universe and the base
    assert counts == {"eta_cv": 18 * (len(universes) - 1), "main": 16 * len(universes),
                      "lambda_sweep": 0}  # fmt: skip
    assert len(eta_cv_trials(pipeline)) == counts["eta_cv"]
    assert len(study_trials(pipeline, etas_for(pipeline))) == counts["main"]


def test_universe_ids_tell_close_numbers_apart():
    pipeline = parse_pipeline(
        multiverse_text("[multiverse.alone]\nsigma = [0.7500001, 1.0, 2.0000000001]\n"),
        Path("mv.toml"),
    )
    ids = [u.id for u in pipeline.multiverse.universes]
    assert len(set(ids)) == 4
    assert [i.split(",")[0] for i in ids] == [
        "sigma=0.75", "sigma=0.7500001", "sigma=1", "sigma=2.0000000001",
    ]  # fmt: skip


@pytest.mark.parametrize(
    "tables, message",
    [
        (MULTIVERSE + "[lambda_sweep]\nsubjects = 1\nrationalities = [1.0]\n",
         "lambda_sweep must not be given with [multiverse]"),
        ("[multiverse.cross]\nsigma = [0.75, 0.75]\n", "multiverse.cross.sigma must not repeat"),
        ("[multiverse.cross]\nsigma = [0.001]\n", "multiverse.cross.sigma must be a non-empty"),
        ('[multiverse.alone]\nrobot = ["oracle"]\n', "multiverse.alone.robot must be a non"),
        ("[multiverse.alone]\ncenters = [\"random\"]\n", "centers must be a non-empty list"),
        ("[multiverse.alone]\nsteps = [0]\n", "multiverse.alone.steps must be a non-empty list"),
        ("[multiverse.alone]\ncolour = [1]\n", "multiverse.alone.colour is not a known key"),
        ("[[multiverse.universes]]\nrationality = 1e9\n",
         "multiverse.universes[0].rationality must be one of numbers in"),
        ("[multiverse]\nuniverses = 3\n", "multiverse.universes must be an array of tables"),
    ],
)  # fmt: skip
def test_a_bad_multiverse_is_one_line_naming_the_key(tables: str, message: str):
    with pytest.raises(UserError, match=message.replace("[", r"\[").replace("]", r"\]")):
        parse_pipeline(multiverse_text(tables), Path("mv.toml"))


def test_a_multiverse_has_one_robot_and_one_horizon():
    text = multiverse_text().replace('robots = ["map"]', 'robots = ["map", "posterior_mean"]')
    with pytest.raises(UserError, match="main.robots must name one robot"):
        parse_pipeline(text, Path("mv.toml"))
    text = multiverse_text().replace("deployment_steps = 4", "deployment_steps = 3")
    with pytest.raises(UserError, match="game.deployment_steps must equal game.learning_steps"):
        parse_pipeline(text, Path("mv.toml"))


def test_adding_a_level_changes_no_existing_universe_or_trial(tmp_path: Path):
    small = load_pipeline(multiverse(tmp_path, "[multiverse.cross]\nsigma = [0.75, 1.5]\n", "a"))
    more = '[multiverse.cross]\nsigma = [0.75, 1.5, 3.0]\ncenters = ["per_draw", "shared"]\n'
    large = load_pipeline(multiverse(tmp_path, more, "a"))

    def by_id(trials):
        # the run id is the pipeline's hash: the same trial in another run differs only there
        return {t.trial_id: msgspec.structs.replace(t, run_id="-") for t in trials}

    small_trials = by_id(eta_cv_trials(small) + study_trials(small, etas_for(small)))
    large_trials = by_id(eta_cv_trials(large) + study_trials(large, etas_for(large)))
    assert set(small_trials) < set(large_trials)
    for trial_id, trial in small_trials.items():
        assert large_trials[trial_id] == trial


def test_the_base_universe_plays_the_single_study_and_reports_its_numbers(
    tmp_path: Path, smoke_run: Path
):
    # The universe with the pipeline's own settings is the pipeline played as a single study:
    # the same trials (ids up to the universe suffix, seeds, draws), the same records, and the
    # same main-block statistics as the single study's report.
    pipeline = load_pipeline(multiverse(tmp_path, "[multiverse.alone]\nsigma = [1.5]\n"))
    single = load_pipeline(SMOKE)
    base = universe_pipeline(pipeline, pipeline.multiverse.base)
    suffix = f"@{pipeline.multiverse.base.id}"
    mine = {t.trial_id.removesuffix(suffix): t for t in eta_cv_trials(base)}
    theirs = {t.trial_id: t for t in eta_cv_trials(single)}
    assert mine.keys() == theirs.keys()
    for trial_id, trial in theirs.items():
        assert mine[trial_id].seed == trial.seed
        assert (mine[trial_id].theta, mine[trial_id].features) == (trial.theta, trial.features)

    run = tmp_path / "run"
    run_pipeline(pipeline, run, LocalEngine(2))
    records = {
        r.trial_id.removesuffix(suffix): r
        for r in run_records(run)
        if r.universe == pipeline.multiverse.base.id
    }
    single_records = {r.trial_id: r for r in run_records(smoke_run) if r.block != "lambda_sweep"}
    assert records.keys() == single_records.keys()
    for trial_id, record in single_records.items():
        assert records[trial_id].measures == record.measures
        assert records[trial_id].demonstration == record.demonstration

    results = analyse_multiverse(read_run(run, logged_pipeline).rows, pipeline, run_id=None)
    (base_results,) = [u for u in results.universes if u.base]
    contents = read_run(smoke_run, logged_pipeline)
    alone = analyse(contents.rows, logged_pipeline(contents.identity))
    assert base_results.anova == alone.paper.anova
    assert base_results.cells == alone.cells
    assert base_results.cronbach_alpha == alone.paper.cronbach_alpha
    assert base_results.eta == alone.eta_cv.chosen


# ---- the open settings ---------------------------------------------------------------------


def test_centers_shared_by_every_draw_or_on_a_lattice_keep_each_draws_theta():
    pipeline = parse_pipeline(multiverse_text(), Path("mv.toml"))
    per_draw, shared, lattice = (
        universe_pipeline(pipeline, replace(pipeline.multiverse.base, centers=c))
        for c in ("per_draw", "shared", "lattice")
    )
    rewards = {
        name: [draw_reward(p, subject_id("main", 3, i), 3) for i in range(1, 5)]
        for name, p in (("per_draw", per_draw), ("shared", shared), ("lattice", lattice))
    }
    for i in range(4):
        assert len({rewards[name][i][1] for name in rewards}) == 1
    assert len({features.centers for features, _ in rewards["per_draw"]}) == 4
    assert len({features.centers for features, _ in rewards["shared"]}) == 1
    assert rewards["shared"][0][0].centers != rewards["per_draw"][0][0].centers
    (centers,) = {features.centers for features, _ in rewards["lattice"]}
    assert np.allclose(centers, [(2 / 3, 2), (2, 2), (10 / 3, 2)])  # 5 x 5 grid, 1 x 3 lattice


@pytest.mark.parametrize(
    "width, height, count, shape",
    [(10, 10, 10, (2, 5)), (10, 10, 3, (1, 3)), (10, 10, 4, (2, 2)), (10, 5, 8, (2, 4)),
     (5, 10, 8, (4, 2)), (10, 10, 7, (1, 7))],
)  # fmt: skip
def test_lattice_centers_are_the_cells_of_the_closest_to_square_factorisation(
    width, height, count, shape
):
    centers = lattice_centers(width, height, count)
    rows, columns = shape
    assert centers.shape == (count, 2)
    assert len(set(centers[:, 0])) == columns and len(set(centers[:, 1])) == rows
    assert np.allclose(
        np.sort(np.unique(centers[:, 0])), (width - 1) * (np.arange(columns) + 0.5) / columns
    )
    assert centers[:, 0].min() > 0 and centers[:, 0].max() < width - 1


def test_a_demonstrator_who_may_not_stay_never_stays_and_the_robot_knows_it(tmp_path: Path):
    pipeline = load_pipeline(
        multiverse(tmp_path, "[multiverse.alone]\ndemonstrator_stays = [false]\n")
    )
    universe = next(u for u in pipeline.multiverse.universes if not u.demonstrator_stays)
    trials = [t for t in study_trials(pipeline, etas_for(pipeline)) if t.universe == universe.id]
    records = play_trials(trials)
    assert all("stay" not in r.demonstration.actions for r in records)
    stays = play_trials([msgspec.structs.replace(t, demonstrator_stays=True) for t in trials])
    assert any("stay" in r.demonstration.actions for r in stays)  # else the test shows nothing
    # The robot's model of the learning phase is MaxEnt over the paths without a stay.
    spec = trials[0]
    grid = Gridworld(spec.grid.width, spec.grid.height)
    features = rbf_features(grid, spec.features.centers, spec.features.sigma)
    start = grid.index(*spec.start)
    model = MaxEnt(
        Phase(grid.demonstrator_moves(spec.demonstrator_stays), start, 3), features[None], 1.0
    )
    paths = [
        path
        for path in pe.enumerate_paths(spec.grid.width, spec.grid.height, start, 3)
        if all(a != b for a, b in itertools.pairwise(path))
    ]
    counts = pe.feature_counts(paths, features)
    theta = np.array(spec.theta)
    want = pe.log_partition(counts, theta, 1.0)
    assert model.log_partition(theta[None])[0] == pytest.approx(want, rel=1e-12)


def test_a_deployment_from_the_demonstrations_start_is_measured_there(tmp_path: Path):
    pipeline = load_pipeline(
        multiverse(tmp_path, '[multiverse.alone]\ndeployment_start = ["demonstration"]\n')
    )
    universe = next(u for u in pipeline.multiverse.universes if u.deployment_start != "uniform")
    trials = [t for t in study_trials(pipeline, etas_for(pipeline)) if t.universe == universe.id]
    trials = trials[:6]
    there = play_trials(trials)
    everywhere = play_trials(
        [msgspec.structs.replace(t, deployment_start="uniform") for t in trials]
    )
    for at_start, uniform in zip(there, everywhere, strict=True):
        assert at_start.theta_hat == uniform.theta_hat  # the same demonstration and estimate
        assert at_start.measures["reward_l2"] == uniform.measures["reward_l2"]
        assert at_start.deployment.starts == (at_start.start,)
    assert any(
        a.measures["regret"] != b.measures["regret"] for a, b in zip(there, everywhere, strict=True)
    )


# ---- runs: resume, validate, the report ------------------------------------------------------


@pytest.fixture(scope="module")
def multiverse_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    directory = tmp_path_factory.mktemp("multiverse")
    pipeline = load_pipeline(multiverse(directory))
    run = directory / "run"
    run_pipeline(pipeline, run, LocalEngine(2))
    return run


def payloads(run: Path) -> dict[str, bytes]:
    return {record.trial_id: encode(record) for record in run_records(run)}


def test_an_interrupted_multiverse_resumes_to_the_same_trials(tmp_path: Path, multiverse_run: Path):
    run = tmp_path / "run"
    shutil.copytree(multiverse_run, run)
    files = log_files(run)
    for victim in (files[0], files[len(files) // 2], files[-1]):
        victim.unlink()
    result = CliRunner().invoke(app, ["analyze", str(run)])
    assert result.exit_code == 2 and "missing" in result.stderr and "--partial" not in result.stderr
    assert "resume with `cirl-study run" in result.stderr
    pipeline = load_pipeline(multiverse_run.parent / "mv.toml")
    resumed = run_pipeline(pipeline, run, LocalEngine(1))
    assert resumed.played > 0 and resumed.resumed > 0
    assert payloads(run) == payloads(multiverse_run)
    assert validate_run(run, logged_pipeline).ok


def test_the_multiverse_report(tmp_path: Path, multiverse_run: Path):
    result = CliRunner().invoke(app, ["analyze", str(multiverse_run), "--out", str(tmp_path / "r")])
    assert result.exit_code == 0, result.output
    assert "multiverse report of" in result.stdout and "universes" in result.stdout
    report = tmp_path / "r"
    results = json.loads((report / "results.json").read_text())
    pipeline = load_pipeline(multiverse_run.parent / "mv.toml")
    assert [u["id"] for u in results["universes"]] == [u.id for u in pipeline.multiverse.universes]
    assert sum(u["base"] for u in results["universes"]) == 1
    for claim in results["claims"]:
        assert claim["reproduced"] == len(claim["holds_in"]) <= claim["universes"]
        for levels in claim["by_level"].values():
            assert sum(level["universes"] for level in levels) == claim["universes"]
            assert sum(level["reproduced"] for level in levels) == claim["reproduced"]
    assert len((report / "universes.csv").read_text().splitlines()) == len(results["universes"]) + 1
    for measure in ("regret", "kl", "reward_l2"):
        assert (report / f"specification_curve_{measure}.png").is_file()
        assert (report / f"specification_curve_{measure}.svg").is_file()
        test = results["joint_test"][measure]
        assert test["resamples"] >= 500 and 0 < test["stouffer_z"]["p"] <= 1
    text = (report / "report.md").read_text()
    assert "## Claims across universes" in text and "Specification curve" in text
    assert text.startswith(f"# Multiverse report: `{results['pipeline']}`")
    assert "(1 universes)" not in text and "| p | share significant | p |" not in text
    assert "| p (median) | share significant | p (share) | Stouffer Z | p (Z) |" in text
    again = CliRunner().invoke(app, ["compare", str(report), str(report)])
    assert again.exit_code == 0
    # the cross-validation a universe used is that of its cross-validation universe
    posterior = next(u for u in results["universes"] if u["settings"]["robot"] != "map")
    base = next(u for u in results["universes"] if u["base"])
    assert posterior["eta"] == base["eta"]
    robots = [u for u in pipeline.multiverse.universes if u.robot != "map"]
    assert [cv_universe(pipeline, u) for u in robots] == [pipeline.multiverse.base]


def test_calibrate_finds_the_universe_a_target_was_taken_from(tmp_path: Path, multiverse_run: Path):
    from cirl_study.analysis.results.types import CalibrationResults
    from cirl_study.api import load_trials

    table = load_trials(multiverse_run)
    pipeline = load_pipeline(multiverse_run.parent / "mv.toml")
    source = pipeline.multiverse.universes[2]
    main = table[(table["block"] == MAIN) & (table["universe"] == source.id)]
    rows = ["measure,num_features,human,value,se"]
    for (k, human), cell in main.groupby(["num_features", "human"]):
        for measure in ("regret", "kl", "reward_l2"):
            values = cell[measure]
            rows.append(f"{measure},{k},{human},{float(values.mean())!r},{float(values.sem())!r}")
    target = tmp_path / "target.csv"
    target.write_text("\n".join(rows) + "\n")
    out = tmp_path / "calibration"
    command = ["calibrate", str(multiverse_run), "--target", str(target), "--out", str(out)]
    result = CliRunner().invoke(app, command)
    assert result.exit_code == 0, result.output
    assert f"nearest {source.id}, D = " in result.stdout
    results = msgspec.json.decode((out / "results.json").read_bytes(), type=CalibrationResults)
    nearest = results.universes[0]
    assert nearest.id == source.id and nearest.mean_squared_log_ratio < 1e-28
    others = results.universes[1:]
    assert len(others) == len(pipeline.multiverse.universes) - 1
    for universe in others:  # ranked farther, or not ranked for a reason
        assert (universe.mean_squared_log_ratio or 0) > 0 or universe.missing, universe
    assert {claim.id for claim in results.nearest_claims} <= {
        "human_effect", "human_f_above_962", "interaction_kl_l2", "cronbach_alpha",
        "tukey_br_ahead",
    }  # fmt: skip
    ranked = [u for u in results.universes if u.mean_squared_log_ratio is not None]
    varied = {a for a in ("sigma", "centers", "demonstrator_stays", "deployment_start", "robot")
              if len({u.settings[a] for u in ranked}) > 1}  # fmt: skip
    assert {axis.axis for axis in results.axes} == varied >= {"sigma", "centers"}
    for name in ("report.md", "universes.csv", "calibration.png", "calibration.svg"):
        assert (out / name).is_file()
    text = (out / "report.md").read_text()
    assert text.startswith("# Calibration: `mv` against `target.csv`")
    assert f"| 1 | `{source.id}` |" in text
    # a target of a cell no universe has is refused in one line, and the report is kept
    target.write_text("measure,num_features,human,value\nregret,7,expert,0.5\n")
    refused = CliRunner().invoke(app, command)
    assert refused.exit_code == 2
    assert refused.stderr.strip() == (
        "error: no universe of the run measures the target's cell (regret, K=7, expert)"
    )
    assert (out / "report.md").read_text() == text
    # a target naming a column twice is refused in one line, not read by its last column
    target.write_text("measure,num_features,human,value,value\nregret,3,expert,0.5,0.7\n")
    refused = CliRunner().invoke(app, command)
    assert refused.exit_code == 2 and refused.stderr.count("\n") == 1, refused.output
    assert refused.stderr == f"error: {target}: names the column value twice\n"
    assert (out / "report.md").read_text() == text


def test_a_full_disk_while_calibrating_is_one_line_and_keeps_the_report(
    tmp_path: Path, multiverse_run: Path, monkeypatch: pytest.MonkeyPatch
):
    """The report's lock file cannot be written (``ENOSPC``): one line naming it, the
    report there kept."""
    target = tmp_path / "target.csv"
    target.write_text("measure,num_features,human,value\nregret,3,expert,0.5\n")
    out = tmp_path / "calibration"
    out.mkdir()
    (out / "report.md").write_text("kept\n")

    def pwrite(descriptor: int, data: bytes, offset: int) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "pwrite", pwrite)
    command = ["calibrate", str(multiverse_run), "--target", str(target), "--out", str(out)]
    result = CliRunner().invoke(app, command)
    assert result.exit_code == 2 and "Traceback" not in result.output, result.output
    assert result.stderr == (
        f"error: {out}: cannot lock the report directory: {tmp_path / '.calibration.lock'}: "
        "No space left on device; the report there is unchanged\n"
    )
    assert [path.name for path in out.iterdir()] == ["report.md"]
    assert (out / "report.md").read_text() == "kept\n"


def test_reproduce_compares_a_multiverse_report_with_the_one_it_replaces(
    tmp_path: Path, multiverse_run: Path
):
    run, report = tmp_path / "run", tmp_path / "report"
    shutil.copytree(multiverse_run, run)
    arguments = ["reproduce", str(multiverse_run.parent / "mv.toml"), "--out", str(run)]
    arguments += ["--report", str(report), "--workers", "1"]
    first = CliRunner().invoke(app, arguments)
    assert first.exit_code == 0, first.output
    assert first.output.rstrip().endswith("a new report (there was none to compare with)")
    second = CliRunner().invoke(app, arguments)
    assert second.exit_code == 0, second.output
    assert second.output.rstrip().endswith(
        f"{report}: equals the report there, number by number; its files are kept"
    )


# ---- the joint test --------------------------------------------------------------------------


def _exact_joint_p(d: np.ndarray) -> dict[str, float]:
    """The p-values of the joint test over all 2^S sign vectors (the exact null)."""
    universes, subjects = d.shape
    critical = stats.t.ppf(0.975, subjects - 1)

    def statistics_of(x):
        mean = x.mean(axis=1)
        t = mean / (x.std(axis=1, ddof=1) / math.sqrt(subjects))
        z = -special.ndtri_exp(stats.t.logcdf(t, subjects - 1))
        return np.median(mean), np.mean(t < -critical), z.sum() / math.sqrt(universes)

    observed = statistics_of(d)
    null = np.array(
        [
            statistics_of(d * np.array(signs))
            for signs in itertools.product((-1, 1), repeat=subjects)
        ]
    )
    return {
        "median_effect": float(np.mean(null[:, 0] <= observed[0])),
        "share_significant": float(np.mean(null[:, 1] >= observed[1])),
        "stouffer_z": float(np.mean(null[:, 2] >= observed[2])),
    }


@pytest.mark.parametrize("shift", [0.0, -0.4])
def test_the_joint_test_agrees_with_the_exact_sign_flip_null(shift: float):
    rng = np.random.default_rng(7)
    subject = rng.normal(0, 1, 12)  # shared by every universe: the universes are dependent
    d = subject[None, :] + rng.normal(0, 0.5, (4, 12)) + shift
    exact = _exact_joint_p(d)
    got = statistics.joint_sign_flip_test(d, resamples=20000, seed=3)
    for key, p in exact.items():
        # Monte Carlo p against the exact one: within 4 standard errors (+ the +1 correction)
        assert abs(getattr(got, key).p - p) <= 4 * math.sqrt(p * (1 - p) / 20000) + 1e-4, key


def test_the_joint_test_finds_a_clear_effect_and_holds_its_level_under_the_null():
    rng = np.random.default_rng(11)
    clear = rng.normal(-1.0, 1.0, (6, 40))
    result = statistics.joint_sign_flip_test(clear, resamples=500)
    assert result.median_effect.p == result.stouffer_z.p == 1 / 501
    rejections = 0
    for seed in range(200):
        null = np.random.default_rng(seed).normal(0.0, 1.0, (5, 30))
        rejections += (
            statistics.joint_sign_flip_test(null, resamples=200, seed=seed).stouffer_z.p <= 0.05
        )
    assert 2 <= rejections <= 20  # 5% of 200 is 10; a binomial 99.9% range


def test_every_joint_p_carries_its_exact_log10():
    """``log10_p`` beside each sign-flip p, against the exact ratio ``(1 + k) / (1 + B)`` at
    60 digits: down to its floor ``1 / (1 + B)``, where a clear effect leaves it."""
    rng = np.random.default_rng(11)
    for d, resamples in ((rng.normal(-1.0, 1.0, (6, 40)), 500), (rng.normal(0, 1, (4, 12)), 999)):
        result = statistics.joint_sign_flip_test(d, resamples=resamples)
        for key in ("median_effect", "share_significant", "stouffer_z"):
            statistic = getattr(result, key)
            extreme = round(statistic.p * (1 + resamples)) - 1
            with mpmath.workdps(60):
                exact = float(mpmath.log10(mpmath.mpf(1 + extreme) / (1 + resamples)))
            assert math.isclose(statistic.log10_p, exact, rel_tol=1e-14), key


def test_the_joint_test_is_a_function_of_its_inputs_and_seed():
    d = np.random.default_rng(2).normal(-0.1, 1.0, (3, 25))
    assert statistics.joint_sign_flip_test(d) == statistics.joint_sign_flip_test(d.copy())
    assert statistics.joint_sign_flip_test(d, batch=7) == statistics.joint_sign_flip_test(d)


def test_a_main_block_of_one_universe_is_its_own():
    pipeline = parse_pipeline(multiverse_text(), Path("mv.toml"))
    trials = study_trials(pipeline, etas_for(pipeline))
    assert {t.universe for t in trials} == {u.id for u in pipeline.multiverse.universes}
    assert all(t.block == MAIN and t.trial_id.endswith(f"@{t.universe}") for t in trials)


def test_the_shipped_multiverse_is_the_paper_study_in_53_universes():
    pipeline = load_pipeline(SMOKE.parent / "multiverse.toml")
    paper = load_pipeline(SMOKE.parent / "paper.toml")
    assert len(pipeline.multiverse.universes) == 53
    base = universe_pipeline(pipeline, pipeline.multiverse.base)
    suffix = f"@{pipeline.multiverse.base.id}"
    etas = {(None, "best_response", 3): 0.316, (None, "best_response", 10): 1.0}
    in_base = {(pipeline.multiverse.base.id, *key[1:]): eta for key, eta in etas.items()}

    def without_universe(trials):
        return [
            msgspec.structs.replace(
                t, trial_id=t.trial_id.removesuffix(suffix), run_id="-", universe=None
            )
            for t in trials
        ]

    def of_paper(trials):
        return [msgspec.structs.replace(t, run_id="-") for t in trials if t.block != "lambda_sweep"]

    assert without_universe(eta_cv_trials(base)) == of_paper(eta_cv_trials(paper))
    assert without_universe(study_trials(base, in_base)) == of_paper(study_trials(paper, etas))


ASCENT = """
[gradient_ascent]
steps = 30
learning_rate = 0.1

[multiverse.cross]
robot = ["map", "gradient_ascent"]
ascent_steps = [30, 300]

[multiverse.alone]
learning_rate = [0.01]
"""


def test_the_gradient_ascent_settings_are_axes_of_that_robot_alone(tmp_path: Path):
    pipeline = load_pipeline(multiverse(tmp_path, ASCENT))
    ids = [u.id for u in pipeline.multiverse.universes]
    base = "sigma=0.75,centers=per_draw,stays=yes,steps=4,lambda=1,robot=map,start=uniform"
    ascent = base.replace("robot=map", "robot=gradient_ascent")
    # the map universes of the cross are one (the base); learning_rate alone varies a setting
    # the base's robot lacks, so it adds nothing
    assert ids == [base, f"{ascent},ga_steps=30,ga_rate=0.1", f"{ascent},ga_steps=300,ga_rate=0.1"]
    deep = pipeline.multiverse.universes[2]
    study = universe_pipeline(pipeline, deep)
    assert (study.gradient_ascent.steps, study.gradient_ascent.learning_rate) == (300, 0.1)
    assert study.main.robots == ("gradient_ascent",)
    assert cv_universe(pipeline, deep) == pipeline.multiverse.base
    trials = study_trials(pipeline, etas_for(pipeline))
    settings = {(t.universe, t.gradient_ascent) for t in trials if t.robot == "gradient_ascent"}
    assert {(u, (a.steps, a.learning_rate)) for u, a in settings} == {
        (ids[1], (30, 0.1)),
        (ids[2], (300, 0.1)),
    }


@pytest.mark.parametrize(
    ("tables", "message"),
    [
        (
            '[multiverse.cross]\nrobot = ["map", "gradient_ascent"]\n',
            "gradient_ascent is missing (robot gradient_ascent needs its settings)",
        ),
        (
            ASCENT.replace("ascent_steps = [30, 300]", "ascent_steps = [0]"),
            "multiverse.cross.ascent_steps must be a non-empty list of integers in [1, 100000]",
        ),
        (
            ASCENT.replace("learning_rate = [0.01]", "learning_rate = [1000.0]"),
            "multiverse.alone.learning_rate must be a non-empty list of numbers in [1e-12, 100]",
        ),
    ],
)
def test_a_bad_gradient_ascent_axis_is_one_line(tmp_path: Path, tables: str, message: str):
    with pytest.raises(UserError, match=re.escape(message)):
        load_pipeline(multiverse(tmp_path, tables))


def test_the_regret_reading_is_an_axis_that_plays_no_trial_of_its_own(tmp_path: Path):
    tables = ASCENT.replace("ascent_steps = [30, 300]", 'regret = ["true", "estimate"]')
    pipeline = load_pipeline(multiverse(tmp_path, tables))
    ids = [u.id for u in pipeline.multiverse.universes]
    base = "sigma=0.75,centers=per_draw,stays=yes,steps=4,lambda=1,robot=map,start=uniform"
    ascent = base.replace("robot=map", "robot=gradient_ascent") + ",ga_steps=30,ga_rate=0.1"
    assert ids == [base, f"{base},regret=estimate", ascent, f"{ascent},regret=estimate"]
    # the two readings share their trials: the counts are those of the two played universes
    played = load_pipeline(multiverse(tmp_path, ASCENT.replace("ascent_steps = [30, 300]", "")))
    assert trial_counts(pipeline) == trial_counts(played)
    planned = {t.universe for t in study_trials(pipeline, etas_for(pipeline))}
    assert planned == {base, ascent}


def test_a_universe_judged_by_regret_under_the_estimate_reads_it_as_regret(tmp_path: Path):
    from cirl_study.analysis.multiverse.results import judged_rows
    from cirl_study.measure_registry import MEASURES
    from cirl_study.record import TrialRow

    logged = {"regret": 0.25, "kl": 1.0, "reward_l2": 2.0, "regret_under_estimate": 0.75}
    measures = tuple(logged.get(name) for name in MEASURES)
    row = TrialRow(
        trial_id="t", run_id="r", universe="u", block="main", subject="s", human="expert",
        robot="map", num_features=3, rationality=1.0, eta=None, seed=1, measures=measures,
        converged=True, draw="d",
    )  # fmt: skip
    pipeline = load_pipeline(
        multiverse(tmp_path, '[multiverse.alone]\nregret = ["estimate"]\n', name="r")
    )
    plain, estimate = pipeline.multiverse.universes
    assert judged_rows([row], plain) == [row]
    (judged,) = judged_rows([row], estimate)
    assert judged.universe == estimate.id and judged.measure("regret") == 0.75
    assert judged.measure("kl") == 1.0 and judged.trial_id == "t"
    old = msgspec.structs.replace(
        row, measures=tuple({**logged, "regret_under_estimate": None}.get(n) for n in MEASURES)
    )
    with pytest.raises(UserError, match="judges regret under the estimate, which trial t does"):
        judged_rows([old], estimate)
