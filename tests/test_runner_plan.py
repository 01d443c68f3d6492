"""Identity and seeds: ids unique and disjoint, streams from identity only, eta choice."""

from __future__ import annotations

import hashlib
import struct
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cirl_study.record import Demonstration, Measures, TrialRecord, TrialRow, TrialSpec
from cirl_study.study.eta_cv import choose_etas
from cirl_study.study.multiverse import played_universes
from cirl_study.study.pipeline_file import load_pipeline
from cirl_study.study.plan import (
    draw_reward,
    eta_cv_trial_ids,
    eta_cv_trials,
    study_trial_ids,
    study_trials,
    subject_id,
    trial_counts,
    trial_id,
    trial_seed,
)
from cirl_study.study.spec import Pipeline

SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"
ETAS = {(None, "best_response", 3): 0.1, (None, "best_response", 10): 10.0}


@pytest.fixture(scope="module")
def smoke() -> Pipeline:
    return load_pipeline(SMOKE)


def all_trials(pipeline: Pipeline) -> list[Any]:
    return eta_cv_trials(pipeline) + study_trials(pipeline, ETAS)


def test_ids_are_unique_and_counts_match(smoke: Pipeline) -> None:
    trials = all_trials(smoke)
    assert len({t.trial_id for t in trials}) == len(trials) == sum(trial_counts(smoke).values())
    assert len({t.seed for t in trials}) == len(trials)
    by_block = {b: sum(t.block == b for t in trials) for b in trial_counts(smoke)}
    assert by_block == trial_counts(smoke)


@pytest.mark.parametrize("name", ["smoke", "robots", "multiverse-small", "teaching-small"])
def test_the_audits_ids_are_the_plans(name: str) -> None:
    pipeline = load_pipeline(SMOKE.parent / f"{name}.toml")
    cv_trials = eta_cv_trials(pipeline)
    assert eta_cv_trial_ids(pipeline) == [t.trial_id for t in cv_trials]
    universes = (
        [None] if pipeline.multiverse is None else [u.id for u in played_universes(pipeline)]
    )
    keys = [
        (universe, human, k)
        for universe in universes
        for human in pipeline.humans_with_eta
        for k in pipeline.game.feature_levels
    ]
    etas = {key: 0.1 * (position + 1) for position, key in enumerate(keys)}
    trials = study_trials(pipeline, etas)
    assert study_trial_ids(pipeline, etas) == [(t.block, t.trial_id) for t in trials]


def test_subjects_unique_across_levels_and_cv_disjoint_from_test(smoke: Pipeline) -> None:
    cv = eta_cv_trials(smoke)
    test = study_trials(smoke, ETAS)
    cv_subjects = {t.subject for t in cv}
    test_subjects = {t.subject for t in test}
    assert not cv_subjects & test_subjects
    assert len(cv_subjects) == 2 * smoke.eta_cv.subjects
    assert len(test_subjects) == 2 * smoke.main.subjects
    # a subject id names one feature level, and its draws are distinct from every other's
    levels = {}
    thetas = {}
    for t in cv + test:
        assert levels.setdefault(t.subject, t.num_features) == t.num_features
        thetas.setdefault(t.subject, t.theta)
    assert len(set(thetas.values())) == len(thetas)
    assert "cv-k03-s0001" in cv_subjects and "main-k10-s0004" in test_subjects


def test_one_subject_is_one_reward_draw_for_every_trial(smoke: Pipeline) -> None:
    draws: dict[str, tuple[Any, Any]] = {}
    for t in all_trials(smoke):
        draw = (t.theta, t.features, t.grid, t.start)
        assert draws.setdefault(t.subject, draw) == draw
    sweep_subjects = {t.subject for t in study_trials(smoke, ETAS) if t.block == "lambda_sweep"}
    main_subjects = {t.subject for t in study_trials(smoke, ETAS) if t.block == "main"}
    assert sweep_subjects <= main_subjects


def test_draws_lie_in_their_ranges(smoke: Pipeline) -> None:
    game = smoke.game
    for t in all_trials(smoke):
        centers = np.asarray(t.features.centers)
        assert centers.shape == (t.num_features, 2)
        assert np.all(centers >= 0) and np.all(centers[:, 0] <= game.width - 1)
        assert np.all(centers[:, 1] <= game.height - 1)
        assert np.all(np.abs(t.theta) <= 1) and len(t.theta) == t.num_features
        assert t.start == game.start and t.features.sigma == game.sigma
        assert (t.grid.width, t.grid.height) == (game.width, game.height)
        assert (t.learning_steps, t.deployment_steps) == (
            game.learning_steps,
            game.deployment_steps,
        )
        assert (t.robot,) == smoke.main.robots == ("map",)


def test_humans_and_etas(smoke: Pipeline) -> None:
    for t in eta_cv_trials(smoke):
        assert t.human == "best_response" and t.eta in smoke.eta_cv.etas
    for t in study_trials(smoke, ETAS):
        assert t.eta == ETAS.get((None, t.human, t.num_features))
        assert t.rationality in (smoke.main.rationality, *smoke.lambda_sweep.rationalities)


def test_seed_is_the_documented_function_of_root_seed_and_id() -> None:
    ident = "main:main-k03-s0001:expert:lambda=1.0"
    words = struct.unpack(
        "<4I", hashlib.blake2b(f"trial:{ident}".encode(), digest_size=16).digest()
    )
    sequence = np.random.SeedSequence(entropy=7, spawn_key=words)
    assert trial_seed(7, ident) == int(sequence.generate_state(1, np.uint64)[0]) >> 11
    assert trial_seed(7, ident) < 2**53
    assert trial_seed(8, ident) != trial_seed(7, ident)


def test_trial_id_spells_out_the_identity() -> None:
    assert trial_id("main", "main-k03-s0001", "expert", 1, None, "map") == (
        "main:main-k03-s0001:expert:lambda=1.0:robot=map"
    )
    assert trial_id(
        "lambda_sweep", "main-k10-s0042", "best_response", 1e-3, 0.316, "posterior_mean"
    ) == ("lambda_sweep:main-k10-s0042:best_response:lambda=0.001:eta=0.316:robot=posterior_mean")


def by_id(trials: list[Any]) -> dict[str, Any]:
    return {t.trial_id: t for t in trials}


def test_nothing_depends_on_the_order_of_the_lists(smoke: Pipeline) -> None:
    shuffled = replace(
        smoke,
        game=replace(smoke.game, feature_levels=smoke.game.feature_levels[::-1]),
        eta_cv=replace(smoke.eta_cv, etas=smoke.eta_cv.etas[::-1]),
        lambda_sweep=replace(
            smoke.lambda_sweep, rationalities=smoke.lambda_sweep.rationalities[::-1]
        ),
    )
    assert [t.trial_id for t in all_trials(shuffled)] != [t.trial_id for t in all_trials(smoke)]
    assert by_id(all_trials(shuffled)) == by_id(all_trials(smoke))


def test_more_subjects_keep_the_first_draws(smoke: Pipeline) -> None:
    bigger = replace(smoke, main=replace(smoke.main, subjects=9))
    small, large = by_id(study_trials(smoke, ETAS)), by_id(study_trials(bigger, ETAS))
    assert small.items() <= large.items()
    second = subject_id("main", 3, 2)
    assert draw_reward(bigger, second, 3) == draw_reward(smoke, second, 3)


def test_another_root_seed_draws_anew(smoke: Pipeline) -> None:
    other = replace(smoke, seed=smoke.seed + 1)
    first = subject_id("main", 3, 1)
    assert draw_reward(other, first, 3)[1] != draw_reward(smoke, first, 3)[1]


def played(spec: TrialSpec, regret: float) -> TrialRecord:
    """A record of ``spec`` whose only meaningful outcome is its ``regret``."""
    fields = {name: getattr(spec, name) for name in TrialSpec.__struct_fields__}
    return TrialRecord(
        **fields,
        theta_hat=spec.theta,
        demonstration=Demonstration(states=(spec.start,), actions=()),
        measures=Measures(
            regret=regret, kl=0.0, reward_l2=0.0, regret_under_estimate=0.0, order_agreement=1.0
        ),
    )


def cv_records(
    trials: list[TrialSpec], regret: dict[tuple[int, float], list[float]]
) -> list[TrialRecord]:
    """Records whose regrets are taken, per (K, eta), from ``regret`` in subject order."""
    position: dict[tuple[int, float], int] = {}
    records = []
    for t in trials:
        key = (t.num_features, t.eta)
        i = position.get(key, 0)
        position[key] = i + 1
        records.append(played(t, regret[key][i]))
    return records


def test_choose_etas_lowest_mean_then_smaller_eta(smoke: Pipeline) -> None:
    trials = eta_cv_trials(smoke)  # 3 subjects at etas 0.1, 1, 10 per level
    regret = {
        (3, 0.1): [3.0, 3.0, 3.0],
        (3, 1.0): [1.0, 5.0, 0.0],  # mean 2: the lowest
        (3, 10.0): [2.0, 2.0, 2.1],
        (10, 0.1): [4.0, 4.0, 4.0],
        (10, 1.0): [1.0, 2.0, 3.0],  # mean 2: ties with 10.0 and is smaller
        (10, 10.0): [2.0, 2.0, 2.0],
    }
    records = cv_records(trials, regret)
    choices = choose_etas(rows(records))
    assert {key: c.eta for key, c in choices.items()} == {
        (None, "best_response", 3): 1.0,
        (None, "best_response", 10): 1.0,
    }
    choice = choices[None, "best_response", 3]
    assert choice.means == {0.1: 3.0, 1.0: 2.0, 10.0: 6.1 / 3}
    assert choice.subjects == 3
    # the same records read in another order choose the same; other blocks are ignored
    main = [played(t, 0.0) for t in study_trials(smoke, ETAS)]
    assert choose_etas(rows([*main, *records[::-1]])) == choices


def test_choose_etas_needs_every_draw_at_every_eta(smoke: Pipeline) -> None:
    trials = eta_cv_trials(smoke)
    records = cv_records(trials, {(t.num_features, t.eta): [1.0] * 3 for t in trials})
    del records[4]
    with pytest.raises(ValueError, match="played on different numbers of draws"):
        choose_etas(rows(records))


def rows(records: list[TrialRecord]) -> list[TrialRow]:
    return [TrialRow.of(record) for record in records]
