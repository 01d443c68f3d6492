"""The humans (docs/design.md §3) against exhaustive enumeration of every path."""

import numpy as np
import path_enumeration as bf
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy import stats

from cirl_study.core.apprenticeship import Apprenticeship
from cirl_study.core.humans import (
    best_response_paths,
    best_response_target,
    expert_paths,
    literal_paths,
)
from cirl_study.core.maxent import MaxEnt, Phase
from cirl_study.core.path_search import NearestPaths, nearest_paths
from cirl_study.core.players import HUMANS, Human, register_human
from cirl_study.record import BEST_RESPONSE, EXPERT, LITERAL

PAPER = {"width": 10, "height": 10, "start": bf.cell(10, 5, 5), "horizon": 9}


SEEDS = np.arange(3)
"""Seeds of a batch of three trials."""


def _batch(features, size):
    return np.ascontiguousarray(np.broadcast_to(features, (size, *features.shape)))


def _model(features, width, height, start, horizon, rationality=1.0):
    """The learning-phase model of a batch ``(B, S, K)`` (or one trial's ``(S, K)``) of features."""
    features = np.asarray(features)
    if features.ndim == 2:
        features = features[None]
    return MaxEnt(Phase(bf.move_table(width, height), start, horizon), features, rationality)


def _assert_paths(paths, width, height, start, horizon):
    paths = np.asarray(paths)
    assert paths.shape[1] == horizon + 1
    for row in paths:
        assert bf.is_path(width, height, row, start, horizon), row


def _tol(value):
    return 1e-9 * max(1.0, abs(value))


# ---- expert ---------------------------------------------------------------------------------


@given(instance=bf.instances(max_side=4, max_horizon=5, max_features=4))
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_expert_is_the_argmax_over_all_paths(instance):
    theta = np.array(instance.theta)
    model = _model(
        instance.features,
        instance.width,
        instance.height,
        instance.start,
        instance.horizon,
        instance.rationality,
    )
    paths = expert_paths(model, theta[None])
    _assert_paths(paths, instance.width, instance.height, instance.start, instance.horizon)
    _, best = bf.expert(instance.counts, theta)
    got = bf.path_rewards(bf.feature_counts(paths, instance.features), theta)[0]
    assert got == pytest.approx(best, rel=1e-12, abs=1e-12)


@given(
    width=st.integers(1, 4),
    height=st.integers(2, 4),
    horizon=st.integers(1, 5),
    data=st.data(),
)
@settings(max_examples=30, deadline=None)
def test_expert_breaks_exact_ties_by_the_first_path_in_action_order(width, height, horizon, data):
    # Integer cell rewards (features = identity): sums are exact and ties are real. Lowest action
    # index at every step picks the lexicographically first optimal action sequence.
    cells = width * height
    rewards = np.array(data.draw(st.lists(st.integers(0, 2), min_size=cells, max_size=cells)))
    start = data.draw(st.integers(0, cells - 1))
    paths = bf.enumerate_paths(width, height, start, horizon)
    best, _ = bf.expert(bf.feature_counts(paths, np.eye(cells)), rewards)
    model = _model(np.eye(cells), width, height, start, horizon)
    got = expert_paths(model, rewards[None].astype(float))
    np.testing.assert_array_equal(got[0], paths[best])


def test_expert_at_the_paper_size():
    rng = np.random.default_rng(20)
    for k in (3, 10):
        features = bf.rbf_features(10, 10, rng.uniform(0, 9, size=(k, 2)), 2.0)
        counts = bf.feature_counts_fast(**PAPER, features=features)
        thetas = rng.uniform(-1, 1, size=(3, k))
        model = _model(_batch(features, 3), 10, 10, PAPER["start"], PAPER["horizon"])
        paths = expert_paths(model, thetas)
        _assert_paths(paths, 10, 10, PAPER["start"], PAPER["horizon"])
        got = bf.feature_counts(paths, features)
        for b in range(3):
            _, best = bf.expert_fast(counts, thetas[b])
            assert got[b] @ thetas[b] == pytest.approx(best, rel=1e-12, abs=1e-12)


def test_the_expert_ignores_the_robot_s_rationality():
    rng = np.random.default_rng(4)
    features = bf.rbf_features(5, 4, rng.uniform(0, 4, size=(3, 2)), 1.5)
    thetas = rng.uniform(-1, 1, size=(4, 3))
    paths = [
        expert_paths(_model(_batch(features, 4), 5, 4, 7, 5, rationality), thetas)
        for rationality in (1e-4, 1.0, 1e3)
    ]
    np.testing.assert_array_equal(paths[0], paths[1])
    np.testing.assert_array_equal(paths[0], paths[2])


# ---- best response --------------------------------------------------------------------------


@pytest.mark.parametrize("rationality", [1e-4, 1.0, 1e3])
def test_best_response_target_equals_enumeration(rationality):
    width, height, start, horizon = 4, 4, 5, 5
    rng = np.random.default_rng(3)
    features = bf.rbf_features(width, height, rng.uniform(0, 3, size=(3, 2)), 1.5)
    counts = bf.feature_counts(bf.enumerate_paths(width, height, start, horizon), features)
    thetas = rng.uniform(-1, 1, size=(3, 3))
    etas = np.array([0.05, 0.5, 5.0])
    model = _model(_batch(features, 3), width, height, start, horizon, rationality)
    got = best_response_target(model, thetas, etas)
    for b in range(3):
        want = bf.expected_features(counts, thetas[b], rationality) + thetas[b] / (2 * etas[b])
        np.testing.assert_allclose(got[b], want, rtol=1e-10, atol=1e-12)


@given(
    instance=bf.instances(max_side=4, max_horizon=5, max_features=4),
    log10_eta=st.floats(-2.0, 1.0),
)
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_best_response_is_the_argmax_over_all_paths(instance, log10_eta):
    theta, eta = np.array(instance.theta), 10.0**log10_eta
    model = _model(
        instance.features,
        instance.width,
        instance.height,
        instance.start,
        instance.horizon,
        instance.rationality,
    )
    paths = best_response_paths(model, theta[None], np.array([eta]))
    _assert_paths(paths, instance.width, instance.height, instance.start, instance.horizon)
    _, best = bf.best_response(instance.counts, theta, eta, instance.rationality)
    phi_theta = bf.expected_features(instance.counts, theta, instance.rationality)
    got_counts = bf.feature_counts(paths, instance.features)
    got = bf.best_response_objective(got_counts, theta, eta, phi_theta)[0]
    assert got == pytest.approx(best, abs=_tol(best))


@pytest.mark.parametrize(
    "num_features, eta, rationality",
    [(3, 0.1, 1.0), (3, 2.0, 1e-4), (10, 0.5, 1.0), (10, 0.05, 1e3)],
)
def test_best_response_at_the_paper_size(num_features, eta, rationality):
    rng = np.random.default_rng(num_features * 100 + int(eta * 100))
    features = bf.rbf_features(10, 10, rng.uniform(0, 9, size=(num_features, 2)), 2.0)
    counts = bf.feature_counts_fast(**PAPER, features=features)
    thetas = rng.uniform(-1, 1, size=(2, num_features))
    model = _model(_batch(features, 2), 10, 10, PAPER["start"], PAPER["horizon"], rationality)
    paths = best_response_paths(model, thetas, np.full(2, eta))
    _assert_paths(paths, 10, 10, PAPER["start"], PAPER["horizon"])
    got_counts = bf.feature_counts(paths, features)
    for b in range(2):
        _, best, phi_theta = bf.best_response_fast(counts, thetas[b], eta, rationality)
        got = bf.best_response_objective(got_counts[b : b + 1], thetas[b], eta, phi_theta)[0]
        assert got == pytest.approx(best, abs=_tol(best))


def test_best_response_differs_from_the_expert_and_a_wrong_target_is_caught():
    # The reference can tell the best response from nearby wrong answers on this instance.
    width, height, start, horizon, rationality, eta = 4, 4, 5, 5, 1.0, 0.2
    rng = np.random.default_rng(12)
    features = bf.rbf_features(width, height, rng.uniform(0, 3, size=(3, 2)), 1.5)
    counts = bf.feature_counts(bf.enumerate_paths(width, height, start, horizon), features)
    theta = rng.uniform(-1, 1, size=3)
    phi_theta = bf.expected_features(counts, theta, rationality)
    objective = bf.best_response_objective(counts, theta, eta, phi_theta)
    best = objective.max()
    expert, _ = bf.expert(counts, theta)
    assert objective[expert] < best - 1e-3
    nearest_mean = int(np.argmin(((counts - phi_theta) ** 2).sum(axis=1)))  # theta / (2 eta) lost
    assert objective[nearest_mean] < best - 1e-3


# ---- the exact nearest-path search on arbitrary targets -------------------------------------


@given(
    instance=bf.instances(max_side=4, max_horizon=5, max_features=4),
    data=st.data(),
)
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_nearest_paths_is_the_argmin_over_all_paths(instance, data):
    k = len(instance.theta)
    kind = data.draw(st.sampled_from(["random", "far", "on a path"]))
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    if kind == "on a path":
        target = instance.counts[rng.integers(len(instance.counts))]
    else:
        scale = instance.horizon * (1.0 if kind == "random" else 50.0)
        target = rng.uniform(-scale, scale, size=k)
    direction = rng.normal(size=(1, k)) if data.draw(st.booleans()) else None
    found = nearest_paths(
        instance.features[None],
        target[None],
        Phase(bf.move_table(instance.width, instance.height), instance.start, instance.horizon),
        direction=direction,
    )
    assert isinstance(found, NearestPaths)
    assert found.actions.shape == (1, instance.horizon)
    assert found.values.shape == found.visited.shape == (1,)
    assert found.visited[0] >= 1
    squared = ((instance.counts - target) ** 2).sum(axis=1)
    best = squared.min()
    states = [instance.start]
    for a in found.actions[0]:
        states.append(bf.move(instance.width, instance.height, states[-1], bf.ACTIONS[a]))
    assert bf.is_path(instance.width, instance.height, states, instance.start, instance.horizon)
    got = ((bf.feature_counts([states], instance.features)[0] - target) ** 2).sum()
    assert got == pytest.approx(best, abs=_tol(best))
    assert found.values[0] == pytest.approx(best, abs=_tol(best))


def test_nearest_paths_needs_a_move_and_a_start():
    features, target = np.ones((1, 4, 2)), np.zeros((1, 2))
    with pytest.raises(ValueError):
        nearest_paths(features, target, Phase(bf.move_table(2, 2), 0, 0))
    with pytest.raises(ValueError):
        nearest_paths(features, target, Phase(bf.move_table(2, 2), None, 2))


# ---- the registry ---------------------------------------------------------------------------


def test_the_paper_s_humans_are_registered_by_name():
    assert not HUMANS[EXPERT].takes_eta
    assert HUMANS[BEST_RESPONSE].takes_eta
    width, height, start, horizon, rationality = 4, 4, 5, 4, 1.0
    rng = np.random.default_rng(9)
    features = bf.rbf_features(width, height, rng.uniform(0, 3, size=(3, 2)), 1.5)
    model = _model(_batch(features, 3), width, height, start, horizon, rationality)
    thetas, etas = rng.uniform(-1, 1, size=(3, 3)), np.array([0.1, 1.0, 10.0])
    np.testing.assert_array_equal(
        HUMANS[EXPERT].demonstrate(Apprenticeship(model, model), thetas, None, SEEDS),
        expert_paths(model, thetas),
    )
    np.testing.assert_array_equal(
        HUMANS[BEST_RESPONSE].demonstrate(Apprenticeship(model, model), thetas, etas, SEEDS),
        best_response_paths(model, thetas, etas),
    )


def test_a_human_name_is_registered_once():
    expert = HUMANS[EXPERT]
    with pytest.raises(ValueError):
        register_human(EXPERT, Human(lambda game, theta, eta, seeds: None, takes_eta=False))
    assert HUMANS[EXPERT] is expert


# ---- the literal demonstrator ----------------------------------------------------------------


@pytest.mark.parametrize("rationality", [0.5, 2.0, 20.0])
def test_literal_paths_are_drawn_from_the_maxent_distribution(rationality):
    # Every path from s_0, with its exact probability by enumeration, against 20,000 draws
    # (one per seed): a chi-square test of the counts (the draws are fixed by their seeds).
    width, height, start, horizon = 3, 3, 4, 3
    rng = np.random.default_rng(5)
    features = bf.rbf_features(width, height, rng.uniform(0, 2, size=(2, 2)), 1.0)
    theta = rng.uniform(-1, 1, size=2)
    draws = 20_000
    model = _model(_batch(features, draws), width, height, start, horizon, rationality)
    paths = literal_paths(model, np.tile(theta, (draws, 1)), np.arange(draws))
    every = bf.enumerate_paths(width, height, start, horizon)
    probability = np.exp(bf.path_log_probs(bf.feature_counts(every, features), theta, rationality))
    index = {path: i for i, path in enumerate(every)}
    counts = np.bincount([index[tuple(p)] for p in paths], minlength=len(every))
    assert counts.sum() == draws  # every draw is a path of the phase
    expected = probability * draws
    pooled = expected >= 5  # the chi-square approximation; the rest pooled into one cell
    observed = np.append(counts[pooled], counts[~pooled].sum())
    wanted = np.append(expected[pooled], expected[~pooled].sum())
    keep = wanted > 0
    _, p = stats.chisquare(observed[keep], wanted[keep] * observed.sum() / wanted[keep].sum())
    assert p > 1e-3


def test_a_literal_path_depends_on_its_seed_alone():
    width, height, start, horizon = 4, 4, 5, 4
    features = bf.rbf_features(width, height, [[0.0, 0.0], [3.0, 3.0]], 1.5)
    thetas = np.array([[0.5, -0.5], [0.2, 0.9], [-0.7, 0.1]])
    model = _model(_batch(features, 3), width, height, start, horizon)
    together = literal_paths(model, thetas, np.array([11, 12, 13]))
    for b, seed in enumerate((11, 12, 13)):
        alone = _model(_batch(features, 1), width, height, start, horizon)
        np.testing.assert_array_equal(
            literal_paths(alone, thetas[b : b + 1], np.array([seed])), together[b : b + 1]
        )
    np.testing.assert_array_equal(
        HUMANS[LITERAL].demonstrate(Apprenticeship(model, model), thetas, None, SEEDS),
        literal_paths(model, thetas, SEEDS),
    )
    assert not HUMANS[LITERAL].takes_eta
