"""The per-trial measures (docs/design.md §4) against enumeration over every start and path."""

import numpy as np
import path_enumeration as bf
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cirl_study.core.maxent import MaxEnt, Phase
from cirl_study.core.measures import regret, reward_l2, trajectory_kl

_unit = st.floats(-1.0, 1.0, allow_subnormal=False)


def _game(width, height, num_features, seed):
    rng = np.random.default_rng(seed)
    centers = rng.uniform([0, 0], [width - 1, height - 1], size=(num_features, 2))
    return rng, bf.rbf_features(width, height, centers, rng.uniform(0.8, 2.5))


def _deployment(features, width, height, horizon, rationality=1.0, start=None):
    """The deployment-phase model of a batch ``(B, S, K)`` (or one trial's ``(S, K)``)."""
    features = np.asarray(features)
    if features.ndim == 2:
        features = features[None]
    return MaxEnt(Phase(bf.move_table(width, height), start, horizon), features, rationality)


def _regret(theta, theta_hat, features, width, height, horizon, rationality=1.0):
    """Regret of a batch of one trial (regret ignores the rationality)."""
    model = _deployment(features, width, height, horizon, rationality)
    return regret(model, np.atleast_2d(theta), np.atleast_2d(theta_hat))[0]


def _kl(theta, theta_hat, features, width, height, horizon, rationality):
    model = _deployment(features, width, height, horizon, rationality)
    return trajectory_kl(model, np.atleast_2d(theta), np.atleast_2d(theta_hat))[0]


def _l2(theta, theta_hat, features):
    return reward_l2(features[None], np.atleast_2d(theta), np.atleast_2d(theta_hat))[0]


def _theta_hat(instance, data):
    """A second reward vector: the truth, a random one, its negation or a box vertex."""
    kind = data.draw(st.sampled_from(["same", "random", "negated", "vertex"]))
    k = len(instance.theta)
    if kind == "same":
        return np.array(instance.theta)
    if kind == "negated":
        return -np.array(instance.theta)
    if kind == "vertex":
        return np.array(data.draw(st.lists(st.sampled_from([-1.0, 1.0]), min_size=k, max_size=k)))
    return np.array(data.draw(st.lists(_unit, min_size=k, max_size=k)))


small = bf.instances(max_side=3, max_horizon=3, max_features=3)


# ---- regret ---------------------------------------------------------------------------------


@given(instance=small, data=st.data())
@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_regret_equals_enumeration_and_is_non_negative(instance, data):
    theta, theta_hat = np.array(instance.theta), _theta_hat(instance, data)
    w, h, T = instance.width, instance.height, instance.horizon
    got = _regret(theta, theta_hat, instance.features, w, h, T)
    want = bf.regret(w, h, instance.features, theta, theta_hat, T)
    assert got == pytest.approx(want, abs=1e-12)
    assert got >= -1e-12


@given(instance=small)
@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_regret_is_zero_for_the_true_reward(instance):
    theta = np.array(instance.theta)
    got = _regret(
        theta, theta, instance.features, instance.width, instance.height, instance.horizon
    )
    assert abs(got) <= 1e-12


@pytest.mark.parametrize("width, height, horizon", [(4, 4, 5), (3, 5, 4), (5, 5, 3)])
def test_regret_on_fixed_grids(width, height, horizon):
    rng, features = _game(width, height, 4, seed=width * height + horizon)
    for _ in range(3):
        theta, theta_hat = rng.uniform(-1, 1, size=(2, 4))
        want = bf.regret(width, height, features, theta, theta_hat, horizon)
        got = _regret(theta, theta_hat, features, width, height, horizon)
        assert got == pytest.approx(want, rel=1e-12, abs=1e-12)
    assert bf.regret(width, height, features, theta, -theta, horizon) > 1e-3  # it can fail


def test_regret_is_a_batched_function():
    rng, features = _game(4, 3, 3, seed=9)
    thetas, theta_hats = rng.uniform(-1, 1, size=(2, 5, 3))
    batch = regret(_deployment(np.broadcast_to(features, (5, 12, 3)), 4, 3, 4), thetas, theta_hats)
    assert batch.shape == (5,)
    for b in range(5):
        assert batch[b] == pytest.approx(_regret(thetas[b], theta_hats[b], features, 4, 3, 4))


@pytest.mark.parametrize("rationality", [1e-4, 1.0, 1e3])
def test_regret_ignores_the_rationality_and_averages_the_fixed_starts(rationality):
    # A fixed deployment start gives that start's regret; uniform starts, their mean.
    rng, features = _game(4, 3, 3, seed=10)
    thetas, theta_hats = rng.uniform(-1, 1, size=(2, 4, 3))
    batch = np.broadcast_to(features, (4, 12, 3))
    uniform = regret(_deployment(batch, 4, 3, 3), thetas, theta_hats)
    np.testing.assert_array_equal(
        regret(_deployment(batch, 4, 3, 3, rationality), thetas, theta_hats), uniform
    )
    per_start = np.stack(
        [
            regret(_deployment(batch, 4, 3, 3, rationality, start=start), thetas, theta_hats)
            for start in range(12)
        ],
        axis=1,
    )
    np.testing.assert_allclose(per_start.mean(axis=1), uniform, rtol=1e-12, atol=1e-15)
    assert (per_start >= 0).all() and (per_start.max(axis=1) > per_start.min(axis=1)).any()


# ---- regret under the estimate ---------------------------------------------------------------


def _regret_under_estimate_by_enumeration(features, theta, theta_hat, width, height, horizon):
    """``mean_s V*_theta_hat(s) - V^{pi_theta}_theta_hat(s)``: the best value under
    ``theta_hat`` by a maximum over every path from each start, minus the value under
    ``theta_hat`` of the hard-max human for ``theta`` that shares ties, by its tie tree."""
    best = bf.optimal_values(width, height, features, theta_hat, horizon)
    table = bf.move_table(width, height)
    estimated, true = features @ theta_hat, features @ theta
    gaps = [
        best[s] - bf.shared_policy_value(table, estimated, true, s, horizon, ())
        for s in range(width * height)
    ]
    return float(np.mean(gaps))


@given(instance=small, data=st.data(), scale=st.sampled_from([1.0, 4.0, 30.0]))
@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_regret_under_the_estimate_equals_enumeration_and_is_non_negative(instance, data, scale):
    """The second reading is :func:`regret` with the roles swapped, also for an estimate
    outside the box (``scale``, as the ``gradient_ascent`` robot's may be)."""
    theta, theta_hat = np.array(instance.theta), scale * _theta_hat(instance, data)
    w, h, T = instance.width, instance.height, instance.horizon
    got = _regret(theta_hat, theta, instance.features, w, h, T)
    want = _regret_under_estimate_by_enumeration(instance.features, theta, theta_hat, w, h, T)
    assert got == pytest.approx(want, abs=1e-12 * scale)
    assert got >= -1e-12 * scale
    if np.array_equal(theta_hat, theta):
        assert got == 0.0


# ---- KL -------------------------------------------------------------------------------------


@pytest.mark.parametrize("rationality", [1e-4, 1.0, 1e3])
@pytest.mark.parametrize("width, height, horizon", [(4, 4, 4), (3, 5, 4)])
def test_kl_equals_enumeration_on_fixed_grids(width, height, horizon, rationality):
    rng, features = _game(width, height, 3, seed=horizon + width)
    for _ in range(2):
        theta, theta_hat = rng.uniform(-1, 1, size=(2, 3))
        want = bf.kl(width, height, features, theta, theta_hat, horizon, rationality)
        got = _kl(theta, theta_hat, features, width, height, horizon, rationality)
        assert got == pytest.approx(want, rel=1e-9, abs=1e-13)
        assert want > 0


@given(instance=small, data=st.data())
@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_kl_equals_enumeration_and_is_non_negative(instance, data):
    theta, theta_hat = np.array(instance.theta), _theta_hat(instance, data)
    w, h, T, lam = instance.width, instance.height, instance.horizon, instance.rationality
    got = _kl(theta, theta_hat, instance.features, w, h, T, lam)
    want = bf.kl(w, h, instance.features, theta, theta_hat, T, lam)
    assert got == pytest.approx(want, rel=1e-8, abs=1e-12)
    assert got >= 0.0


@given(instance=small)
@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_kl_is_zero_for_the_true_reward(instance):
    theta = np.array(instance.theta)
    w, h, T, lam = instance.width, instance.height, instance.horizon, instance.rationality
    assert abs(_kl(theta, theta, instance.features, w, h, T, lam)) <= 1e-12


def test_kl_is_not_symmetric_and_the_reference_sees_it():
    # Swapping the arguments changes the value: a KL computed the wrong way round fails the tests.
    rng, features = _game(3, 3, 2, seed=1)
    theta, theta_hat = np.array([1.0, -0.2]), np.array([-0.3, 0.9])
    forward = bf.kl(3, 3, features, theta, theta_hat, 3, 2.0)
    backward = bf.kl(3, 3, features, theta_hat, theta, 3, 2.0)
    assert abs(forward - backward) > 1e-3
    assert _kl(theta, theta_hat, features, 3, 3, 3, 2.0) == pytest.approx(forward, rel=1e-10)


def test_kl_averages_over_the_uniform_starts_or_takes_the_fixed_one():
    # Uniform starts give the mean over every cell; a fixed start, that cell's KL.
    rng, features = _game(3, 4, 2, seed=12)
    thetas, theta_hats = rng.uniform(-1, 1, size=(2, 3, 2))
    batch = np.broadcast_to(features, (3, 12, 2))
    everywhere = trajectory_kl(_deployment(batch, 3, 4, 3, 2.0), thetas, theta_hats)
    per_start = np.stack(
        [
            trajectory_kl(_deployment(batch, 3, 4, 3, 2.0, start=start), thetas, theta_hats)
            for start in range(12)
        ],
        axis=1,
    )
    np.testing.assert_allclose(per_start.mean(axis=1), everywhere, rtol=1e-12, atol=1e-15)
    for b in range(3):
        want = bf.kl(3, 4, features, thetas[b], theta_hats[b], 3, 2.0)
        assert everywhere[b] == pytest.approx(want, rel=1e-9, abs=1e-13)


# ---- reward L2 ------------------------------------------------------------------------------


@given(instance=small, data=st.data())
@settings(max_examples=40, deadline=None)
def test_reward_l2_equals_exact_arithmetic(instance, data):
    theta, theta_hat = np.array(instance.theta), _theta_hat(instance, data)
    got = _l2(theta, theta_hat, instance.features)
    want = bf.reward_l2(instance.features, theta, theta_hat)
    assert got == pytest.approx(want, rel=1e-12, abs=1e-15)
    assert _l2(theta_hat, theta, instance.features) == pytest.approx(got)
    assert _l2(theta, theta, instance.features) == 0.0


def test_reward_l2_by_hand():
    features = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
    # Phi (theta - theta_hat) = (1, -2, -1) for theta - theta_hat = (1, -2): norm sqrt(6)
    got = _l2(np.array([0.5, -1.0]), np.array([-0.5, 1.0]), features)
    assert got == pytest.approx(np.sqrt(6.0), rel=1e-15)
    assert bf.reward_l2(features, [0.5, -1.0], [-0.5, 1.0]) == pytest.approx(np.sqrt(6), rel=1e-15)


@pytest.mark.parametrize(
    "width, height, centers, sigma, theta, theta_hat, rationality",
    [
        # found by hypothesis: the true KL is ~1e-18; summing p (log p - log q) in floating point
        # gives about -9e-17 here and -3e-169 in the second case
        (1, 3, [(0.0, 0.0)], 3.0, [5.960464477539063e-08], [-5.960464477539063e-08], 1.0),
        (1, 2, [(0.0, 0.0)] * 3, 1.0, [0.0, 0.0, -1.0], [0.0, 0.0, -0.5], 1e3),
    ],
)
def test_kl_is_never_negative_even_when_it_rounds_to_nothing(
    width, height, centers, sigma, theta, theta_hat, rationality
):
    features = bf.rbf_features(width, height, centers, sigma)
    got = _kl(np.array(theta), np.array(theta_hat), features, width, height, 1, rationality)
    assert got >= 0.0
    assert got == pytest.approx(0.0, abs=1e-15)
