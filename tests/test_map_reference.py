"""The high-precision MAP reference (``map_reference``) checked on its own, without ``cirl_study``.

Each check is independent of the reference's internals: a double-precision L-BFGS-B fit where
double suffices (small lambda), the KKT conditions recomputed path by path in mpmath with exact
feature counts, comparisons of ``L`` with random box points and with the max-margin LP limit,
the exact bound ``0 <= max_tau theta_hat . Delta_tau - v* <= log(P') / lambda``, interior
moment-matching instances whose MAP is known, and determinism.
"""

from __future__ import annotations

import functools
import math

import map_reference as mr
import mpmath
import numpy as np
import path_enumeration as bf
import pytest
from scipy.optimize import minimize

# (seed, K, horizon, start) of 4x4 games; demonstrations "expert" (reward-maximising path of a
# random theta) and "random" (a uniformly drawn path).
GAMES = {
    "a": (1, 2, 4, 5),
    "b": (2, 3, 4, 6),
    "c": (3, 4, 4, 9),
    "d": (5, 3, 5, 5),
}
WIDTH = HEIGHT = 4
LARGE = (1e2, 1e3, 1e4)
INSTANCES = [("a", "expert"), ("b", "random"), ("c", "expert"), ("d", "expert")]


@functools.cache
def _game(game: str):
    """``(features, paths, counts, demo index by kind)`` of a seeded 4x4 game."""
    seed, k, horizon, start = GAMES[game]
    rng, features, paths, counts = bf.random_game(WIDTH, HEIGHT, start, horizon, k, seed)
    theta = rng.uniform(-1, 1, size=k)
    demos = {"expert": bf.expert_fast(counts, theta)[0], "random": int(rng.integers(len(paths)))}
    return features, paths, counts, demos


def _args(game: str):
    _, k, horizon, start = GAMES[game]
    features = _game(game)[0]
    return features, WIDTH, HEIGHT, start, horizon


@functools.cache
def _reference(game: str, kind: str, rationality: float) -> mr.ReferenceResult:
    features, paths, counts, demos = _game(game)
    return mr.reference_map_details(*_args(game), counts[demos[kind]], rationality)


@functools.cache
def _limit(game: str, kind: str) -> mr.MaxMarginLimit:
    features, paths, counts, demos = _game(game)
    return mr.max_margin_limit(*_args(game), counts[demos[kind]])


# ---- independent evaluation, path by path ---------------------------------------------------


def _exact_deltas(features, paths, demo_states, dps: int = 50):
    """Per-path ``Delta_tau = phi(tau) - phi_d`` in mpmath, each count an exact sum of doubles.

    Exact sums make every reordering of the demonstration's cells give ``Delta = 0`` exactly.
    """
    with mpmath.workdps(dps):
        mp_features = [[mpmath.mpf(float(v)) for v in row] for row in features]
        k = len(mp_features[0])

        def exact(path):
            return [mpmath.fsum(mp_features[int(s)][i] for s in path[1:]) for i in range(k)]

        demo = exact(demo_states)
        return [[c - d for c, d in zip(exact(p), demo, strict=True)] for p in paths]


@functools.cache
def _exact_counts(game: str, kind: str):
    features, paths, counts, demos = _game(game)
    return _exact_deltas(features, paths, paths[demos[kind]])


def _moments_mp(deltas, theta, rationality):
    """``(grad L, -Hess L)`` at ``theta``: ``-lambda E[Delta]`` and ``lambda^2 Cov[Delta]``."""
    lam = mpmath.mpf(rationality)
    th = [mpmath.mpf(float(t)) for t in theta]
    scores = [lam * mpmath.fdot(th, d) for d in deltas]
    top = max(scores)
    w = [mpmath.exp(s - top) for s in scores]
    total = mpmath.fsum(w)
    w = [x / total for x in w]
    k = len(th)
    mean = [mpmath.fsum(wi * d[i] for wi, d in zip(w, deltas, strict=True)) for i in range(k)]
    grad = [-lam * m for m in mean]
    cov = mpmath.matrix(k, k)
    for a in range(k):
        for b in range(k):
            cov[a, b] = lam**2 * mpmath.fsum(
                wi * (d[a] - mean[a]) * (d[b] - mean[b]) for wi, d in zip(w, deltas, strict=True)
            )
    return grad, cov


def _log_lik_mp(deltas, theta, rationality):
    """``L(theta) = -log sum_tau exp(lambda theta . Delta_tau)``."""
    lam = mpmath.mpf(rationality)
    th = [mpmath.mpf(float(t)) for t in theta]
    scores = [lam * mpmath.fdot(th, d) for d in deltas]
    top = max(scores)
    return -(top + mpmath.log(mpmath.fsum(mpmath.exp(s - top) for s in scores)))


def _log_lik(counts, demo, theta, rationality):
    """Double precision ``L`` at many points: ``(n,)`` for ``theta`` ``(n, K)``."""
    scores = rationality * (np.atleast_2d(theta) @ (counts - demo).T)
    top = scores.max(axis=1)
    return -(top + np.log(np.exp(scores - top[:, None]).sum(axis=1)))


# ---- (a) small lambda: agreement with L-BFGS-B in double precision -----------------------------


@pytest.mark.parametrize("rationality", [1.0, 1e-2])
@pytest.mark.parametrize("game, kind", [("a", "expert"), ("b", "random"), ("c", "expert")])
def test_agrees_with_lbfgsb_at_small_lambda(game, kind, rationality):
    features, paths, counts, demos = _game(game)
    demo = counts[demos[kind]]

    def objective(theta):  # -L / lambda and its gradient E[phi] - phi_d
        value = -bf.log_likelihood_fast(demo, counts, theta, rationality) / rationality
        return value, bf.expected_features_fast(counts, theta, rationality) - demo

    k = len(demo)
    fit = minimize(
        objective,
        np.zeros(k),
        jac=True,
        method="L-BFGS-B",
        bounds=[(-1.0, 1.0)] * k,
        options={"ftol": 1e-16, "gtol": 1e-13, "maxiter": 20000, "maxcor": 20},
    )
    theta_hat = _reference(game, kind, rationality).theta
    assert np.abs(fit.x - theta_hat).max() <= 1e-6
    assert np.all(np.abs(theta_hat) <= 1.0)


# ---- (b) KKT, recomputed path by path in mpmath ------------------------------------------------


def _assert_kkt(deltas, theta_hat, rationality):
    """KKT of the box maximisation of L at ``theta_hat``, path by path in mpmath."""
    with mpmath.workdps(50):
        grad, neg_hess = _moments_mp(deltas, theta_hat, rationality)
        k = len(theta_hat)
        # A bound coordinate's slope of L must push outward (or vanish); the others are free.
        bound = [i for i in range(k) if abs(theta_hat[i]) == 1.0 and grad[i] * theta_hat[i] > 0]
        free = [i for i in range(k) if i not in bound]
        if not free:
            return
        # On the free coordinates the projected gradient vanishes, to within what rounding the
        # answer to double moves it: the Newton step there is below 1e-11.
        sub = mpmath.matrix([[neg_hess[i, j] for j in free] for i in free])
        n = len(free)
        scale = [1 / mpmath.sqrt(sub[a, a]) for a in range(n)]
        unit = mpmath.matrix(
            [[sub[a, b] * scale[a] * scale[b] for b in range(n)] for a in range(n)]
        )
        rhs = mpmath.matrix([grad[i] * scale[a] for a, i in enumerate(free)])
        step = mpmath.lu_solve(unit, rhs)
        assert max(abs(step[a] * scale[a]) for a in range(n)) <= 1e-11
        # and the projected gradient itself is within the Hessian times such a step
        slack = max(sum(abs(neg_hess[i, j]) for j in range(k)) for i in free)
        assert max(abs(grad[i]) for i in free) <= slack * mpmath.mpf("1e-11")


@pytest.mark.parametrize("rationality", [1e-2, 1.0, *LARGE])
@pytest.mark.parametrize("game, kind", INSTANCES)
def test_kkt_holds_at_the_reference(game, kind, rationality):
    _assert_kkt(_exact_counts(game, kind), _reference(game, kind, rationality).theta, rationality)


def test_certificate_reports_the_face_and_a_small_step():
    res = _reference("a", "expert", 1e4)
    cert = res.certificate
    assert cert.ok and cert.resolvable
    assert cert.newton_step <= 1e-12
    assert all(m > 0 for m in cert.multipliers)
    assert sorted(cert.bound + cert.free) == list(range(len(res.theta)))
    for i in cert.bound:
        assert abs(res.theta[i]) == 1.0
    assert res.log_likelihood <= 0


# ---- (c) large lambda: a maximiser, and the max-margin limit -----------------------------------


@pytest.mark.parametrize("game, kind", INSTANCES)
def test_large_lambda_maximises_and_approaches_the_max_margin_limit(game, kind):
    features, paths, counts, demos = _game(game)
    demo = counts[demos[kind]]
    limit = _limit(game, kind)
    deltas = _exact_counts(game, kind)
    # Paths with the demo's counts are left out of the margin (they weigh exp(0) everywhere).
    other = np.abs(counts - demo).max(axis=1) > 1e-12
    assert limit.num_excluded == len(paths) - int(other.sum()) >= 1
    assert limit.value <= 1e-12  # theta = 0 is in the box
    log_others = math.log(int(other.sum()))
    rng = np.random.default_rng(0)
    points = rng.uniform(-1, 1, size=(200, len(demo)))
    theta_lp = np.clip(limit.theta, -1, 1)
    gaps, distances = [], []
    for rationality in LARGE:
        theta_hat = _reference(game, kind, rationality).theta
        # L(theta_hat) >= L at random box points (double) and at the LP point (mpmath).
        best = _log_lik(counts, demo, theta_hat, rationality)[0]
        assert np.all(_log_lik(counts, demo, points, rationality) <= best + 1e-9 * rationality)
        with mpmath.workdps(50):
            at_hat = _log_lik_mp(deltas, theta_hat, rationality)
            assert _log_lik_mp(deltas, theta_lp, rationality) <= at_hat
        # The exact soft-max bound: 0 <= max_tau theta_hat . Delta_tau - v* <= log(P') / lambda.
        margin = float(((counts[other] - demo) @ theta_hat).max())
        gap = margin - limit.value
        assert -1e-9 <= gap <= log_others / rationality + 1e-9
        gaps.append(gap)
        distances.append(float(np.abs(theta_hat - limit.theta).max()))
    assert gaps[-1] <= gaps[0] + 1e-9
    if limit.unique:
        assert distances[-1] <= distances[0] + 1e-9
        assert distances[-1] <= 0.02


def test_max_margin_limit_knows_a_unique_and_a_degenerate_lp():
    # An expert demonstration that is the only optimal path of some theta: v* < 0, unique LP.
    limit = _limit("a", "expert")
    assert limit.value < 0
    assert limit.unique
    assert np.all(limit.theta_range[:, 1] - limit.theta_range[:, 0] <= 1e-6)
    # theta_range always holds the returned solution
    for lim in (limit, _limit("b", "random")):
        assert np.all(lim.theta_range[:, 0] - 1e-7 <= lim.theta)
        assert np.all(lim.theta <= lim.theta_range[:, 1] + 1e-7)


# ---- known answers: moment matching ----------------------------------------------------------


@pytest.mark.parametrize("rationality", [2.0, 50.0])
def test_recovers_theta_when_the_demo_counts_are_its_moments(rationality):
    # Demo counts E_theta[phi] (not a path's) make an interior theta the MAP: grad L = 0 there.
    features, paths, counts, _ = _game("b")
    theta = np.array([0.3, -0.45, 0.2]) / (1.0 if rationality < 10 else 10.0)
    demo = bf.expected_features(counts, theta, rationality)
    res = mr.reference_map_details(*_args("b"), demo, rationality)
    assert res.certificate.bound == ()
    assert np.abs(res.theta - theta).max() <= 1e-9


# ---- (d) determinism, precision and non-uniqueness ----------------------------------------------


def test_reference_is_deterministic_and_independent_of_the_precision():
    features, paths, counts, demos = _game("b")
    args = (*_args("b"), counts[demos["expert"]], 1e3)
    first = mr.reference_map_details(*args)
    second = mr.reference_map_details(*args)
    assert first.theta.tobytes() == second.theta.tobytes()
    assert first.iterations == second.iterations
    finer = mr.reference_map(*args, dps=90, tol=1e-20)
    assert np.abs(finer - first.theta).max() <= 1e-12


def test_raises_when_the_map_is_not_unique():
    # Two identical features: L depends on theta_0 + theta_1 only, and with demo counts that
    # put the optimum of that sum inside (-2, 2) the MAP is a segment.
    width, height, start, horizon = 3, 4, 4, 4
    features = bf.rbf_features(width, height, [(0.5, 1.2), (0.5, 1.2), (1.7, 2.1)], 1.1)
    counts = bf.feature_counts(bf.enumerate_paths_array(width, height, start, horizon), features)
    demo = bf.expected_features(counts, [0.2, 0.2, 0.1], 1.0)
    with pytest.raises(mr.MapNotDetermined, match="not determined"):
        mr.reference_map(features, width, height, start, horizon, demo, 1.0)


def test_warns_of_a_map_that_double_precision_inputs_do_not_determine():
    # A random demonstration at lambda = 1e4 whose LP limit is not unique: the MAP is unique
    # and converged, but one direction of L is so flat (curvature ~1e-10) that perturbing the
    # demo counts by two ulps moves the MAP by ~1e-3. No double-precision robot can be held
    # to 1e-6 there; the certificate's input_sensitivity says so.
    width, height, start, horizon = 4, 4, 5, 4
    rng = np.random.default_rng(12)
    centers = rng.uniform([0, 0], [width - 1, height - 1], size=(3, 2))
    features = bf.rbf_features(width, height, centers, float(rng.uniform(0.8, 2.0)))
    paths = bf.enumerate_paths_array(width, height, start, horizon)
    counts = bf.feature_counts(paths, features)
    rng.uniform(-1, 1, size=3)
    demo = counts[int(rng.integers(len(paths)))]
    args = (features, width, height, start, horizon)
    res = mr.reference_map_details(*args, demo, 1e4)
    assert res.certificate.ok
    assert res.certificate.input_sensitivity > 1e-6
    assert not mr.max_margin_limit(*args, demo).unique
    nudged = demo + 2 * np.spacing(demo)
    assert np.abs(mr.reference_map(*args, nudged, 1e4) - res.theta).max() > 1e-5


# ---- the shared cases ---------------------------------------------------------------------------


def test_reference_cases_are_certified_well_posed_and_cached():
    cases = mr.reference_cases()
    assert 6 <= len(cases) <= 10
    assert len({name for name, _ in cases}) == len(cases)
    lams = {case["rationality"] for _, case in cases}
    assert {1e2, 1e3, 1e4, 1.0, 1e-2} <= lams
    for name, case in cases:
        assert case["width"] * case["height"] == case["features"].shape[0]
        k = case["features"].shape[1]
        assert 2 <= k <= 4 and case["horizon"] in (4, 5)
        states = case["demo_states"]
        assert bf.is_path(case["width"], case["height"], states, case["start"], case["horizon"])
        np.testing.assert_array_equal(
            case["demo_counts"], bf.feature_counts([states], case["features"])[0]
        )
        theta_hat = case["theta_hat"]
        assert theta_hat is mr.reference_theta(name)  # computed once
        assert theta_hat.shape == (k,) and np.all(np.abs(theta_hat) <= 1.0)
        res = mr.reference_case_details(name)
        assert res.theta.tobytes() == theta_hat.tobytes()
        # well posed for a double-precision robot held to 1e-6
        assert res.certificate.input_sensitivity <= 1e-9
        paths = bf.enumerate_paths_array(
            case["width"], case["height"], case["start"], case["horizon"]
        )
        deltas = _exact_deltas(case["features"], paths, states)
        _assert_kkt(deltas, theta_hat, case["rationality"])
    with pytest.raises(KeyError):
        cases[0][1]["no such key"]
