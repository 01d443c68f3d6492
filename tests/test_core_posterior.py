"""The ``posterior_mean`` robot (docs/design.md §2) against quadrature of the enumerated likelihood.

The references share no code with the package: every path of a tiny game is enumerated with
``path_enumeration``, its log-likelihood ``lambda theta . phi(tau_demo) - log Z(theta)`` is
summed over those paths here, and ``E[theta | tau_demo]`` under the uniform prior on the box is
integrated by scipy's adaptive quadrature (K = 1) or by a composite Gauss-Legendre tensor grid
(K = 2, 3), whose own error each test bounds by comparing two resolutions.

Tolerances. The robot reports a Monte-Carlo standard error ``se_k`` per coordinate; with an
honest, asymptotically normal error, ``|theta_hat_k - E[theta_k]| > 4 se_k`` has probability
6e-5 per coordinate (the seeds are fixed, so each test is deterministic). A converged trial
has ``se_k <= 0.01``, so the same check also bounds the error absolutely by 0.04 + the
reference's error (at most 1e-6, checked). That the reported ``se`` is honest, not just small,
is tested on 20 seeds.
"""

import math

import numpy as np
import path_enumeration as bf
import pytest
from scipy import integrate

from cirl_study.core.apprenticeship import Apprenticeship
from cirl_study.core.estimate import Estimate
from cirl_study.core.maxent import MaxEnt, Phase
from cirl_study.core.players import ROBOTS
from cirl_study.core.posterior import posterior_mean_estimate

# The tiny game: a 3 x 3 grid, 3 steps from the center (81 paths), RBF width 1.
WIDTH, HEIGHT, START, HORIZON, SIGMA = 3, 3, 4, 3, 1.0
CENTERS = ((0.2, 1.8), (2.0, 0.4), (1.6, 1.9))
THETA = (0.7, -0.4, 0.5)  # the expert's reward (its first K components)
REFERENCE_TOL = 1e-6  # bound on a reference's own error, checked by refining it
SIGMAS = 4.0  # allowed error in reported standard errors


def _game(k, theta=THETA, centers=CENTERS):
    """Features (S, K), every path's counts (P, K), and the expert's path and its counts."""
    features = bf.rbf_features(WIDTH, HEIGHT, centers[:k], SIGMA)
    paths = np.array(bf.enumerate_paths(WIDTH, HEIGHT, START, HORIZON))
    counts = bf.feature_counts(paths, features)
    best, _ = bf.expert(counts, theta[:k])
    return features, counts, paths[best], counts[best]


def _model(features, rationality):
    features = np.asarray(features)
    batch = features if features.ndim == 3 else features[None]
    return MaxEnt(Phase(bf.move_table(WIDTH, HEIGHT), START, HORIZON), batch, rationality)


def _log_likelihood(points, demo, counts, rationality):
    """``(M,)`` exact log-likelihood at ``points`` (M, K), summing over the enumerated paths."""
    scores = rationality * points @ counts.T
    top = scores.max(axis=1)
    log_z = top + np.log(np.exp(scores - top[:, None]).sum(axis=1))
    return rationality * points @ demo - log_z


def _quadrature_mean(demo, counts, rationality):
    """K = 1: ``E[theta]`` by adaptive quadrature (the likelihood bends at theta = 0)."""
    top = bf.log_likelihood(demo, counts, [1.0], rationality)
    top = max(top, bf.log_likelihood(demo, counts, [-1.0], rationality))

    def density(t):
        return math.exp(bf.log_likelihood(demo, counts, [t], rationality) - top)

    # The density is at most 1; its first moment nearly cancels at small lambda, hence epsabs.
    options = {"points": [0.0], "limit": 500, "epsabs": 1e-12, "epsrel": 1e-11}
    mass, mass_error = integrate.quad(density, -1.0, 1.0, **options)
    first, first_error = integrate.quad(lambda t: t * density(t), -1.0, 1.0, **options)
    assert mass_error <= 1e-9 * mass and first_error <= 1e-9 * mass
    return np.array([first / mass])


def _grid_mean(demo, counts, rationality, panels, order=6):
    """``E[theta]`` by a composite Gauss-Legendre tensor rule with ``panels`` per axis."""
    k = len(demo)
    x, w = np.polynomial.legendre.leggauss(order)
    edges = np.linspace(-1.0, 1.0, panels + 1)
    half = np.diff(edges)[:, None] / 2
    nodes = ((edges[:-1, None] + edges[1:, None]) / 2 + half * x).ravel()
    weights = (half * w).ravel()
    rest = np.stack(np.meshgrid(*[nodes] * (k - 1), indexing="ij"), -1).reshape(-1, k - 1)
    rest_weights = np.prod(
        np.stack(np.meshgrid(*[weights] * (k - 1), indexing="ij"), -1).reshape(-1, k - 1), axis=1
    )
    shift = None
    mass, first = 0.0, np.zeros(k)
    for node, weight in zip(nodes, weights, strict=True):  # one slab of the grid at a time
        points = np.concatenate([np.full((len(rest), 1), node), rest], axis=1)
        log_density = _log_likelihood(points, demo, counts, rationality)
        shift = log_density.max() if shift is None else shift
        density = weight * rest_weights * np.exp(log_density - shift)
        mass += density.sum()
        first += density @ points
    return first / mass


def _reference(demo, counts, rationality, panels):
    """The reference mean, and a check that refining it moves it by less than REFERENCE_TOL."""
    if len(demo) == 1:
        return _quadrature_mean(demo, counts, rationality)
    coarse = _grid_mean(demo, counts, rationality, panels)
    fine = _grid_mean(demo, counts, rationality, panels + panels // 2)
    assert np.abs(fine - coarse).max() <= REFERENCE_TOL
    return fine


def _check_against(estimate, reference, b=0, target=0.01):
    assert estimate.converged[b]
    se = estimate.theta_hat_se[b]
    assert np.all(se <= target) and np.all(se >= 0)
    error = np.abs(estimate.theta_hat[b] - reference)
    assert np.all(error <= SIGMAS * se + REFERENCE_TOL), (error, se)


@pytest.mark.parametrize("rationality", [1e-3, 1.0, 100.0, 1000.0])
def test_one_feature_matches_adaptive_quadrature(rationality):
    features, counts, path, demo = _game(1)
    reference = _reference(demo, counts, rationality, 0)
    estimate = posterior_mean_estimate(_model(features, rationality), path[None], np.array([11]))
    _check_against(estimate, reference)


@pytest.mark.parametrize("rationality", [0.1, 10.0, 100.0])
def test_two_features_match_a_tensor_grid(rationality):
    features, counts, path, demo = _game(2)
    reference = _reference(demo, counts, rationality, 40)
    estimate = posterior_mean_estimate(_model(features, rationality), path[None], np.array([12]))
    _check_against(estimate, reference)


@pytest.mark.parametrize("rationality", [1.0, 10.0])
def test_three_features_match_a_fine_grid(rationality):
    features, counts, path, demo = _game(3)
    reference = _reference(demo, counts, rationality, 8)
    estimate = posterior_mean_estimate(_model(features, rationality), path[None], np.array([13]))
    _check_against(estimate, reference)


@pytest.mark.parametrize("rationality", [1e-4, 1e-2])
def test_small_rationality_gives_the_prior_mean(rationality):
    # log Z(theta) = log P + lambda theta . phibar + O(lambda^2) (phibar: the mean counts of all
    # P paths), so the posterior is the uniform prior tilted by exp(lambda theta .
    # (phi_demo - phibar)): E[theta] = lambda / 3 (phi_demo - phibar) + O(lambda^3) (the
    # second-order terms vanish by the prior's symmetry). Here |lambda (phi_demo - phibar)|
    # <= 0.02, so the remainder is below 1e-5; the estimate tends to the prior mean 0.
    features, counts, path, demo = _game(3)
    first_order = rationality / 3.0 * (demo - counts.mean(axis=0))
    estimate = posterior_mean_estimate(_model(features, rationality), path[None], np.array([14]))
    assert estimate.converged[0]
    error = np.abs(estimate.theta_hat[0] - first_order)
    assert np.all(error <= SIGMAS * estimate.theta_hat_se[0] + 1e-5)
    assert np.abs(estimate.theta_hat[0]).max() <= rationality  # -> 0 with lambda


def test_reported_standard_errors_are_honest():
    # 20 independent runs (seeds) of one trial, with a loose target so that their spread is
    # visible: the spread of the estimates around the exact mean, and their spread around
    # their own average, must both match the reported standard errors within a factor 1.5.
    rationality, runs = 10.0, 20
    features, counts, path, demo = _game(2)
    reference = _reference(demo, counts, rationality, 40)
    model = _model(np.broadcast_to(features, (runs, *features.shape)), rationality)
    estimate = posterior_mean_estimate(
        model, np.repeat(path[None], runs, axis=0), np.arange(runs) + 100, target_se=0.03
    )
    assert estimate.converged.all()
    z = (estimate.theta_hat - reference) / estimate.theta_hat_se
    assert 1 / 1.5 <= np.sqrt(np.mean(z**2)) <= 1.5
    spread = estimate.theta_hat.std(axis=0, ddof=1)
    reported = np.sqrt(np.mean(estimate.theta_hat_se**2, axis=0))
    assert 1 / 1.5 <= np.sqrt(np.mean(spread**2) / np.mean(reported**2)) <= 1.5


def _mixed_batch(rationality):
    """Four different trials (features, reward, demonstration) of the tiny game."""
    rng = np.random.default_rng(3)
    features, paths = [], []
    for _ in range(4):
        centers = rng.uniform(0, 2, size=(3, 2))
        theta = rng.uniform(-1, 1, size=3)
        phi, _, path, _ = _game(3, tuple(theta), tuple(map(tuple, centers)))
        features.append(phi)
        paths.append(path)
    return _model(np.stack(features), rationality), np.stack(paths)


def test_same_seed_same_estimate_and_batch_independence():
    model, paths = _mixed_batch(10.0)
    seeds = np.array([5, 6, 7, 8])
    together = posterior_mean_estimate(model, paths, seeds)
    again = posterior_mean_estimate(model, paths, seeds, chunk=3)
    for field in ("theta_hat", "theta_hat_se", "effective_sample_size", "iterations"):
        np.testing.assert_array_equal(getattr(together, field), getattr(again, field))
    backwards = posterior_mean_estimate(model.take([3, 2, 1, 0]), paths[::-1], seeds[::-1])
    np.testing.assert_array_equal(backwards.theta_hat[::-1], together.theta_hat)
    for b in range(4):
        alone = posterior_mean_estimate(model.take([b]), paths[[b]], seeds[[b]])
        np.testing.assert_array_equal(alone.theta_hat[0], together.theta_hat[b])
        np.testing.assert_array_equal(alone.theta_hat_se[0], together.theta_hat_se[b])
    other = posterior_mean_estimate(model.take([0]), paths[[0]], np.array([99]))
    assert not np.array_equal(other.theta_hat[0], together.theta_hat[0])
    assert np.all(np.abs(other.theta_hat[0] - together.theta_hat[0]) <= 0.1)


def test_estimate_fields_and_counts_or_paths():
    rationality = 1.0
    model, paths = _mixed_batch(rationality)
    seeds = np.arange(4)
    estimate = posterior_mean_estimate(model, paths, seeds)
    assert isinstance(estimate, Estimate)
    assert estimate.theta_hat.shape == (4, 3) and estimate.theta_hat_se.shape == (4, 3)
    assert estimate.effective_sample_size.shape == (4,) and estimate.log_likelihood.shape == (4,)
    assert estimate.iterations.dtype == np.int64 and estimate.converged.dtype == np.bool_
    assert estimate.converged.all() and (estimate.iterations >= 256).all()
    assert np.all(estimate.effective_sample_size <= estimate.iterations)
    assert np.all(np.abs(estimate.theta_hat) <= 1.0)
    for b in range(4):
        counts = bf.feature_counts(
            bf.enumerate_paths(WIDTH, HEIGHT, START, HORIZON), model.features[b]
        )
        demo = bf.feature_counts(paths[[b]], model.features[b])[0]
        expected = bf.log_likelihood(demo, counts, estimate.theta_hat[b], rationality)
        assert estimate.log_likelihood[b] == pytest.approx(expected, abs=1e-10)
    with pytest.raises(ValueError):
        posterior_mean_estimate(model, paths[:, :-1], seeds)
    with pytest.raises(ValueError):
        posterior_mean_estimate(model, paths, seeds[:3])


def test_the_sample_cap_is_honoured_and_reported():
    features, counts, path, demo = _game(2)
    model = _model(features, 100.0)
    capped = posterior_mean_estimate(
        model, path[None], np.array([1]), target_se=1e-4, max_samples=1000
    )
    assert not capped.converged[0] and capped.iterations[0] == 1000
    assert capped.theta_hat_se[0].max() > 1e-4
    reference = _reference(demo, counts, 100.0, 40)
    error = np.abs(capped.theta_hat[0] - reference)
    assert np.all(error <= SIGMAS * capped.theta_hat_se[0] + REFERENCE_TOL)


def test_the_posterior_mean_robot_is_registered():
    features, counts, path, demo = _game(2)
    model = _model(features, 1.0)
    robot = ROBOTS["posterior_mean"]
    registered = robot.estimate(Apprenticeship(model, model), path[None], np.array([21]))
    direct = posterior_mean_estimate(model, path[None], np.array([21]))
    np.testing.assert_array_equal(registered.theta_hat, direct.theta_hat)
    assert registered.theta_hat_se is not None and registered.effective_sample_size is not None
