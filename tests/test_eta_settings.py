"""eta as a setting of a universe (cirl_study.study.spec.AXES ``eta``, ``eta_measure``,
``eta_grid``; cirl_study.study.eta_cv): the levels and ids, what each universe plays, the
choice on another measure and over another grid checked by hand, a fixed eta against the
cross-validated one it equals, and a run of them end to end (resume, validate, report)."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import msgspec
import pytest
from typer.testing import CliRunner

from cirl_study.cli import app
from cirl_study.errors import UserError
from cirl_study.logs.format import log_files
from cirl_study.logs.validate import validate_run
from cirl_study.measure_registry import MEASURES
from cirl_study.record import Demonstration, TrialRecord, TrialRow, TrialSpec, encode
from cirl_study.study.engines import LocalEngine
from cirl_study.study.eta_cv import choose_etas, study_etas
from cirl_study.study.multiverse import cv_universe, played_universes
from cirl_study.study.pipeline_file import load_pipeline, logged_pipeline, parse_pipeline
from cirl_study.study.plan import eta_cv_trials, study_trial_ids, study_trials, trial_counts
from cirl_study.study.runner import run_pipeline

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_logs_helpers import run_records  # noqa: E402
from test_multiverse import multiverse, multiverse_text  # noqa: E402

BASE = "sigma=0.75,centers=per_draw,stays=yes,steps=4,lambda=1,robot=map,start=uniform"
"""The id of the smoke multiverse's own universe (tests/test_multiverse.py)."""

ETA_LEVELS = """eta = [{3 = 1.0, 10 = 0.1}, {3 = 10}]
eta_measure = ["kl"]
eta_grid = [[1.0, 0.1]]
"""
"""A fixed eta at both levels, one at 3 features alone, eta chosen on KL, and over a grid of
two of the file's three etas (0.1, 1, 10)."""

ETAS = "[multiverse.alone]\n" + ETA_LEVELS


def parsed(tables: str):
    return parse_pipeline(multiverse_text(tables), Path("mv.toml"))


# ---- levels and ids --------------------------------------------------------------------------


def test_each_eta_setting_is_spelled_in_the_id_and_the_defaults_in_none():
    pipeline = parsed(ETAS)
    assert [u.id for u in pipeline.multiverse.universes] == [
        BASE,
        f"{BASE},eta=k3:1+k10:0.1",
        f"{BASE},eta=k3:10",
        f"{BASE},eta_cv=kl",
        f"{BASE},eta_grid=0.1+1",
    ]
    fixed, partly = pipeline.multiverse.universes[1:3]
    assert fixed.eta == ((3, 1.0), (10, 0.1)) and (fixed.fixed_eta(3), fixed.fixed_eta(10)) == (
        1.0,
        0.1,
    )
    assert (partly.fixed_eta(3), partly.fixed_eta(10)) == (10.0, None)
    assert pipeline.multiverse.universes[-1].eta_grid == (0.1, 1.0)
    # the defaults are the file's own universe: no new universe, no new id
    defaults = parsed('[multiverse.alone]\neta_measure = ["regret"]\nsigma = [0.75]\n')
    assert [u.id for u in defaults.multiverse.universes] == [BASE]
    # a measure or grid of a universe whose every eta is fixed is no setting of it, and "cv"
    # names the default among fixed levels
    crossed = parsed(
        '[multiverse.cross]\neta = ["cv", {3 = 1, 10 = 0.1}]\neta_measure = ["regret", "kl"]\n'
    )
    assert [u.id for u in crossed.multiverse.universes] == [
        BASE,
        f"{BASE},eta_cv=kl",
        f"{BASE},eta=k3:1+k10:0.1",
    ]


def test_adding_eta_levels_changes_no_existing_universe_or_trial(tmp_path: Path):
    from test_multiverse import etas_for

    small = load_pipeline(multiverse(tmp_path, "[multiverse.alone]\nsigma = [1.5]\n", "a"))
    large = load_pipeline(multiverse(tmp_path, "[multiverse.alone]\nsigma = [1.5]\n" + ETA_LEVELS))

    def by_id(pipeline):
        trials = eta_cv_trials(pipeline) + study_trials(pipeline, etas_for(pipeline))
        return {t.trial_id: msgspec.structs.replace(t, run_id="-") for t in trials}

    mine, theirs = by_id(small), by_id(large)
    assert set(mine) < set(theirs)
    assert all(theirs[trial_id] == trial for trial_id, trial in mine.items())


@pytest.mark.parametrize(
    ("tables", "message"),
    [
        ("[multiverse.alone]\neta = [{4 = 1.0}]\n",
         'multiverse.alone.eta must be a non-empty list of "cv" or tables of feature levels '
         "(3, 10) and their eta, numbers in [1e-06, 1e+06]"),
        ('[multiverse.alone]\neta = ["CV"]\n', "multiverse.alone.eta must be a non-empty"),
        ("[multiverse.alone]\neta = [{3 = 0.0}]\n", "multiverse.alone.eta must be a non-empty"),
        ("[multiverse.alone]\neta = [{3 = 1e7}]\n", "multiverse.alone.eta must be a non-empty"),
        ("[multiverse.alone]\neta = [1.0]\n", "multiverse.alone.eta must be a non-empty"),
        ("[multiverse.alone]\neta = [{3 = true}]\n", "multiverse.alone.eta must be a non-empty"),
        ("[multiverse.alone]\neta = [{3 = 1.0}, {3 = 1}]\n",
         "multiverse.alone.eta must not repeat a level"),
        ("[[multiverse.universes]]\neta = {}\n", "multiverse.universes[0].eta must be one of"),
        ('[multiverse.alone]\neta_measure = ["loss"]\n',
         "multiverse.alone.eta_measure must be a non-empty list of regret, kl, reward_l2"),
        ("[multiverse.alone]\neta_grid = [[0.1, 0.1]]\n",
         "multiverse.alone.eta_grid must be a non-empty list of lists of distinct numbers"),
        ("[multiverse.alone]\neta_grid = [[]]\n", "multiverse.alone.eta_grid must be a non-empty"),
        ("[multiverse.alone]\neta_grid = [[1.0, 0.1], [0.1, 1.0]]\n",
         "multiverse.alone.eta_grid must not repeat a level"),
    ],
)  # fmt: skip
def test_a_bad_eta_level_is_one_line_naming_the_key(tables: str, message: str):
    with pytest.raises(UserError) as error:
        parsed(tables)
    assert str(error.value).startswith(f"mv.toml: {message}")
    assert "\n" not in str(error.value)


# ---- what each universe plays ------------------------------------------------------------


def test_a_fixed_eta_plays_no_cross_validation_and_a_measure_shares_the_bases():
    pipeline = parsed(ETAS)
    base, fixed, partly, on_kl, grid = pipeline.multiverse.universes
    assert cv_universe(pipeline, fixed) is None
    assert cv_universe(pipeline, partly) == cv_universe(pipeline, on_kl) == base
    assert cv_universe(pipeline, grid) == grid
    cv = eta_cv_trials(pipeline)
    assert {t.universe for t in cv} == {base.id, grid.id}
    assert {t.eta for t in cv if t.universe == grid.id} == {0.1, 1.0}
    assert len(cv) == trial_counts(pipeline)["eta_cv"] == 2 * 3 * (3 + 2)
    etas = study_etas(pipeline, [_row(t, regret=1.0, kl=1.0) for t in cv])
    trials = study_trials(pipeline, {key: choice.eta for key, choice in etas.items()})
    assert len(trials) == trial_counts(pipeline)["main"] == 5 * 16
    played = {(t.universe, t.num_features) for t in trials if t.human == "best_response"}
    assert played == {(u.id, k) for u in played_universes(pipeline) for k in (3, 10)}
    for t in trials:
        if t.human == "best_response":
            assert t.eta == etas[t.universe, t.human, t.num_features].eta
    assert [etas[fixed.id, "best_response", k].eta for k in (3, 10)] == [1.0, 0.1]
    assert (
        etas[partly.id, "best_response", 3].fixed and etas[partly.id, "best_response", 3].eta == 10
    )
    assert not etas[partly.id, "best_response", 10].fixed
    ids = study_trial_ids(pipeline, {key: choice.eta for key, choice in etas.items()})
    assert ids == [(t.block, t.trial_id) for t in trials]


def _row(spec: TrialSpec, **measures: float | None) -> TrialRow:
    """The row of a record of ``spec`` whose measures are ``measures`` (0 unless given)."""
    values = dict.fromkeys(MEASURES, 0.0) | measures
    fields = {name: getattr(spec, name) for name in TrialSpec.__struct_fields__}
    record = TrialRecord(
        **fields,
        theta_hat=spec.theta,
        demonstration=Demonstration(states=(spec.start,), actions=()),
        measures=values,
    )
    return TrialRow.of(record)


def test_each_universe_chooses_on_its_measure_over_its_grid_by_hand():
    pipeline = parsed(ETAS)
    base, fixed, partly, on_kl, grid = pipeline.multiverse.universes
    # per (K, eta): three draws' regret and KL. Lowest mean regret: eta 10 at both levels;
    # lowest KL: 0.1 at 3 features, 1 at 10; the grid (0.1, 1) without 10: by regret, 1 and
    # 0.1 (a tie of 2.0 against 2.0 goes to the smaller eta).
    regret = {(3, 0.1): [3, 3, 3], (3, 1.0): [2, 2, 2], (3, 10.0): [1, 0, 2],
              (10, 0.1): [2, 2, 2], (10, 1.0): [1, 2, 3], (10, 10.0): [0, 0, 0]}  # fmt: skip
    kl = {(3, 0.1): [0, 1, 2], (3, 1.0): [5, 5, 5], (3, 10.0): [4, 4, 4],
          (10, 0.1): [3, 3, 3], (10, 1.0): [1, 1, 1.5], (10, 10.0): [9, 9, 9]}  # fmt: skip
    rows, position = [], {}
    for t in eta_cv_trials(pipeline):
        key = (t.universe, t.num_features, t.eta)
        i = position[key] = position.get(key, -1) + 1
        rows.append(_row(t, regret=regret[key[1:]][i], kl=kl[key[1:]][i]))
    etas = study_etas(pipeline, rows[::-1])
    chosen = {(u, k): c.eta for (u, _, k), c in etas.items()}
    assert chosen == {
        (base.id, 3): 10.0, (base.id, 10): 10.0,
        (fixed.id, 3): 1.0, (fixed.id, 10): 0.1,
        (partly.id, 3): 10.0, (partly.id, 10): 10.0,
        (on_kl.id, 3): 0.1, (on_kl.id, 10): 1.0,
        (grid.id, 3): 1.0, (grid.id, 10): 0.1,
    }  # fmt: skip
    choice = etas[on_kl.id, "best_response", 10]
    assert choice.measure == "kl" and choice.subjects == 3
    assert choice.means == {0.1: 3.0, 1.0: 3.5 / 3, 10.0: 9.0}
    assert etas[partly.id, "best_response", 3].measure is None  # fixed
    assert etas[partly.id, "best_response", 10].measure == "regret"


def test_a_score_is_maximised_and_a_draw_it_leaves_undefined_is_left_out():
    pipeline = parsed('[multiverse.alone]\neta_measure = ["order_agreement"]\n')
    trials = [t for t in eta_cv_trials(pipeline) if t.num_features == 3]
    # per eta, three draws' order agreement (a score: higher is better); the first draw
    # has none at eta 1, so it is left out at every eta: 0.1 -> (0.5 + 0.5) / 2,
    # 1 -> (0.75 + 0.25) / 2, 10 -> (0.6 + 0.6) / 2 = 0.6, the highest (with it, 0.1 would be)
    agreement = {0.1: [1.0, 0.5, 0.5], 1.0: [None, 0.75, 0.25], 10.0: [0.0, 0.6, 0.6]}
    subjects = sorted({t.subject for t in trials})
    rows = [_row(t, order_agreement=agreement[t.eta][subjects.index(t.subject)]) for t in trials]
    (choice,) = choose_etas(rows, "order_agreement").values()
    assert choice.eta == 10.0 and choice.subjects == 2
    assert choice.means == {0.1: 0.5, 1.0: 0.5, 10.0: 0.6}
    undefined = [_row(t, order_agreement=None if t.eta == 1.0 else 0.5) for t in trials]
    with pytest.raises(ValueError, match="no draw has a value of order_agreement at every eta"):
        choose_etas(undefined, "order_agreement")
    with pytest.raises(ValueError, match="played on different draws"):
        choose_etas(
            [r for r in rows if (r.eta, r.subject) != (0.1, subjects[0])]
            + [msgspec.structs.replace(rows[0], subject="cv-k03-s0099")]
        )


# ---- runs ----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def eta_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The smoke multiverse with :data:`ETAS` and a universe whose fixed etas are those its
    own cross-validation chooses in the base (1 at 3 features and 0.1 at 10, as
    ``tests/test_multiverse.py`` finds them), played to the end."""
    directory = tmp_path_factory.mktemp("eta")
    pipeline = load_pipeline(multiverse(directory, ETAS))
    run = directory / "run"
    run_pipeline(pipeline, run, LocalEngine(2))
    return run


def test_a_fixed_eta_equal_to_the_choice_plays_the_bases_numbers(eta_run: Path):
    records = run_records(eta_run)
    base = [r for r in records if r.universe == BASE and r.block == "main"]
    chosen = {r.num_features: r.eta for r in base if r.human == "best_response"}
    assert chosen == {3: 1.0, 10: 0.1}  # so the universe eta=k3:1+k10:0.1 fixes them
    fixed = [r for r in records if r.universe == f"{BASE},eta=k3:1+k10:0.1"]
    assert len(fixed) == len(base) == 16 and all(r.block == "main" for r in fixed)

    def numbers(r: TrialRecord):
        return (r.subject, r.human, r.eta, r.seed, r.theta, r.theta_hat, r.measures)

    assert sorted(map(numbers, fixed)) == sorted(map(numbers, base))


def test_a_run_of_eta_settings_resumes_validates_and_reports(eta_run: Path, tmp_path: Path):
    run = tmp_path / "run"
    shutil.copytree(eta_run, run)
    files = log_files(run)
    for victim in (files[0], files[-1]):
        victim.unlink()
    pipeline = load_pipeline(eta_run.parent / "mv.toml")
    assert run_pipeline(pipeline, run, LocalEngine(1)).played > 0
    payloads = {r.trial_id: encode(r) for r in run_records(run)}
    assert payloads == {r.trial_id: encode(r) for r in run_records(eta_run)}
    assert validate_run(run, logged_pipeline).ok
    result = CliRunner().invoke(app, ["analyze", str(run), "--out", str(tmp_path / "r")])
    assert result.exit_code == 0, result.output
    results = json.loads((tmp_path / "r" / "results.json").read_text())
    universes = {u["id"]: u for u in results["universes"]}
    assert results["axes"]["eta"] == [None, "k3:1+k10:0.1", "k3:10"]
    assert results["axes"]["eta_measure"] == [None, "kl"]
    assert "eta" not in universes[BASE]["settings"]  # a default is no setting of the universe
    assert universes[f"{BASE},eta=k3:10"]["settings"]["eta"] == "k3:10"
    assert universes[f"{BASE},eta=k3:10"]["eta"] == [
        {"num_features": 3, "eta": 10.0, "mean": None},  # fixed: no cross-validated mean
        universes[BASE]["eta"][1],
    ]
    text = (tmp_path / "r" / "report.md").read_text()
    assert "| eta | cv, k3:1+k10:0.1, k3:10 |" in text
    assert "| cv (3 universes) |" in text
    header = (tmp_path / "r" / "universes.csv").read_text().splitlines()[0].split(",")
    assert header[header.index("learning_rate") + 1 : header.index("regret")] == [
        "eta", "eta_measure", "eta_grid",
    ]  # fmt: skip
