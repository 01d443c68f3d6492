"""The robot (docs/design.md §2) against the enumerated log-likelihood of ``path_enumeration``.

The ``map`` robot's estimate must be the MAP of the MaxEnt log-likelihood on the box
:math:`[-1, 1]^K`; the model itself is tested in ``test_core_maxent``.
"""

import itertools

import map_reference
import numpy as np
import path_enumeration as bf
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from cirl_study.core.apprenticeship import Apprenticeship
from cirl_study.core.estimate import Estimate
from cirl_study.core.humans import expert_paths
from cirl_study.core.maxent import MaxEnt, Phase
from cirl_study.core.players import ROBOTS, register_robot
from cirl_study.core.robot import _certified, _Objective, box_step, map_estimate
from cirl_study.record import MAP

KKT_TOL = 1e-6 + 1e-9  # feature-count units, |dL/dtheta_k| / lambda: the fit's 1e-6 + rounding


def _fit(demos, features, width, height, start, horizon, rationality, **options):
    """Fit a batch of demonstration paths ``(B, T + 1)`` that share one feature matrix."""
    demos = np.atleast_2d(demos)
    batch_features = np.broadcast_to(features, (len(demos), *features.shape))
    model = MaxEnt(Phase(bf.move_table(width, height), start, horizon), batch_features, rationality)
    return map_estimate(model, demos, **options)


def _projected_slope(theta_hat, demo_counts, counts, rationality):
    """Box-projected gradient of L at theta_hat, divided by lambda (feature-count units).

    For a maximiser of a concave L over [-1, 1]^K (the KKT conditions): dL/dtheta_k = 0 inside,
    >= 0 at +1, <= 0 at -1; components that point out of the box at a bound are zeroed.
    """
    slope = demo_counts - bf.expected_features(counts, theta_hat, rationality)
    outward = ((theta_hat >= 1.0) & (slope > 0)) | ((theta_hat <= -1.0) & (slope < 0))
    return np.where(outward, 0.0, slope)


def _check_map(fit, b, demo, counts, rationality, rng, *, converged=True):
    """theta_hat in the box, KKT, reported LL exact, LL >= random box points and neighbours.

    By concavity, L(x) <= L(theta_hat) + grad L . (x - theta_hat) <= L(theta_hat) + gap for every
    x in the box, where gap = 2 lambda ||projected slope||_1: the certificate the fit must meet.
    ``converged``: the fit must also have converged its estimate (``converged``).
    """
    theta_hat = fit.theta_hat[b]
    assert fit.converged[b] or not converged
    assert np.all((theta_hat >= -1.0) & (theta_hat <= 1.0))
    slope = _projected_slope(theta_hat, demo, counts, rationality)
    assert np.abs(slope).max() <= KKT_TOL
    best = bf.log_likelihood(demo, counts, theta_hat, rationality)
    assert fit.log_likelihood[b] == pytest.approx(best, rel=1e-10, abs=1e-10 * rationality)
    gap = 2.0 * rationality * np.abs(slope).sum() + 1e-10 * max(1.0, abs(best))
    for point in rng.uniform(-1, 1, size=(10, len(theta_hat))):
        assert best >= bf.log_likelihood(demo, counts, point, rationality) - gap
    for direction in rng.normal(size=(6, len(theta_hat))):
        near = np.clip(theta_hat + 1e-3 * direction, -1, 1)
        assert best >= bf.log_likelihood(demo, counts, near, rationality) - gap


@pytest.mark.parametrize("rationality", [1e-4, 1.0, 1e3])
def test_fit_is_the_box_map_for_random_and_expert_demos(rationality):
    width, height, start, horizon = 4, 4, 5, 5
    rng, features, paths, counts = bf.random_game(width, height, start, horizon, 3, seed=4)
    thetas = rng.uniform(-1, 1, size=(3, 3))
    chosen = [*rng.integers(len(paths), size=3), *(bf.expert(counts, th)[0] for th in thetas)]
    fit = _fit(paths[chosen], features, width, height, start, horizon, rationality)
    assert fit.theta_hat.shape == (6, 3)
    # At large lambda a random path's MAP can lie where the likelihood is flat to rounding
    # (test_map_reference checks those estimates against the high-precision MAP).
    for b, index in enumerate(chosen):
        _check_map(fit, b, counts[index], counts, rationality, rng, converged=rationality < 100)


def test_an_interior_map_matches_the_moments():
    # Inside the box the MAP solves E_theta[phi] = phi(tau_demo) (the gradient vanishes).
    width, height, start, horizon, rationality = 3, 4, 4, 4, 5.0
    rng, features, paths, counts = bf.random_game(width, height, start, horizon, 2, seed=8)
    chosen = rng.permutation(len(paths))[:60]
    fit = _fit(paths[chosen], features, width, height, start, horizon, rationality)
    interior = np.flatnonzero(np.abs(fit.theta_hat).max(axis=1) < 1.0)
    assert len(interior) >= 5 and fit.converged.all()
    for b in interior:
        expected = bf.expected_features(counts, fit.theta_hat[b], rationality)
        np.testing.assert_allclose(expected, counts[chosen[b]], atol=1e-8)


def test_the_map_robot_is_registered_and_a_name_is_taken_once():
    width, height, start, horizon, rationality = 4, 4, 5, 4, 1.0
    _, features, paths, counts = bf.random_game(width, height, start, horizon, 3, seed=7)
    model = MaxEnt(Phase(bf.move_table(width, height), start, horizon), features[None], rationality)
    registered = ROBOTS[MAP].estimate(Apprenticeship(model, model), paths[:1], np.array([3]))
    np.testing.assert_array_equal(registered.theta_hat, map_estimate(model, paths[:1]).theta_hat)
    assert registered.theta_hat_se is None and registered.effective_sample_size is None
    robot = ROBOTS[MAP]
    with pytest.raises(ValueError):
        register_robot(MAP, robot)
    assert ROBOTS[MAP] is robot


def test_estimate_fields_and_the_iteration_cap():
    width, height, start, horizon, rationality = 4, 4, 5, 4, 1.0
    rng, features, paths, counts = bf.random_game(width, height, start, horizon, 3, seed=7)
    demos = paths[rng.integers(len(paths), size=4)]
    fit = _fit(demos, features, width, height, start, horizon, rationality)
    assert isinstance(fit, Estimate)
    assert fit.theta_hat.shape == (4, 3) and fit.log_likelihood.shape == (4,)
    assert fit.iterations.shape == (4,) and fit.iterations.dtype == np.int64
    assert fit.converged.shape == (4,) and fit.converged.dtype == np.bool_
    assert fit.converged.all() and (fit.iterations >= 1).all()
    # No iteration: the prior mean, not converged, with its log-likelihood -log(#paths).
    stopped = _fit(demos, features, width, height, start, horizon, rationality, max_iterations=0)
    np.testing.assert_array_equal(stopped.theta_hat, 0.0)
    np.testing.assert_array_equal(stopped.iterations, 0)
    assert not stopped.converged.any()
    np.testing.assert_allclose(stopped.log_likelihood, -np.log(len(paths)), rtol=1e-14)
    # A loose tolerance stops no later than the default one.
    loose = _fit(demos, features, width, height, start, horizon, rationality, tolerance=1e-2)
    assert loose.converged.all() and (loose.iterations <= fit.iterations).all()


def test_fit_of_a_batch_equals_fits_one_at_a_time():
    width, height, start, horizon, rationality = 4, 4, 9, 4, 1.0
    rng, features, paths, counts = bf.random_game(width, height, start, horizon, 3, seed=5)
    demos = paths[rng.integers(len(paths), size=5)]
    together = _fit(demos, features, width, height, start, horizon, rationality)
    for b in range(5):
        alone = _fit(demos[b], features, width, height, start, horizon, rationality)
        np.testing.assert_allclose(alone.theta_hat[0], together.theta_hat[b], atol=1e-9)


@given(instance=bf.instances(max_horizon=4), data=st.data())
@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_fit_is_the_box_map_on_random_instances(instance, data):
    path = data.draw(st.integers(0, len(instance.paths) - 1))
    demo = instance.counts[path]
    fit = _fit(
        instance.paths[path],
        instance.features,
        instance.width,
        instance.height,
        instance.start,
        instance.horizon,
        instance.rationality,
    )
    rng = np.random.default_rng(path)
    # The MAP is unique, and can be converged in double precision, where the count
    # differences span R^K with room to spare (nearly equal centers leave a direction the
    # likelihood barely sees) and the likelihood is not flat to rounding (lambda < 100 here;
    # larger ones: test_map_reference).
    singular = np.linalg.svd(instance.counts - demo, compute_uv=False)
    spans = len(singular) == len(demo) and singular[-1] > 1e-6 * singular[0]
    converged = spans and instance.rationality <= 10
    _check_map(fit, 0, demo, instance.counts, instance.rationality, rng, converged=converged)


def test_fit_at_large_lambda_with_nearly_collinear_features():
    # Found by hypothesis (test_fit_is_the_box_map_on_random_instances): two wide RBFs 0.375
    # apart on a 4 x 3 grid, lambda = 487; the fit on the gradient of L once stopped here with a
    # KKT residual of 1.009e-6, off the MAP.
    instance = bf.Instance(
        4, 3, 10, 2, ((0.0, 0.0), (0.0, 0.375), (3.0, 2.0)), 3.0, (0.0,) * 3, 486.9675251658631
    )
    demo = instance.counts[14]
    fit = _fit(instance.paths[14], instance.features, 4, 3, 10, 2, instance.rationality)
    _check_map(fit, 0, demo, instance.counts, instance.rationality, np.random.default_rng(14))


def test_fit_reaches_a_vertex_optimum_with_strongly_correlated_features():
    # Found by hypothesis: three wide RBFs on a 4 x 1 strip, the demo stays at the left end.
    # The MAP is the vertex (1, -1, -1) with L = -2.0328...; an ill-conditioned Hessian must not
    # stop the fit short of it.
    instance = bf.Instance(4, 1, 0, 3, ((0.0, 0.0), (1.0, 0.0), (2.0, 0.0)), 3.0, (0.0,) * 3, 1.0)
    demo = instance.counts[0]
    fit = _fit(instance.paths[0], instance.features, 4, 1, 0, 3, 1.0)
    assert bf.log_likelihood(demo, instance.counts, [1, -1, -1], 1.0) == pytest.approx(
        -2.032806875483893, rel=1e-12
    )
    _check_map(fit, 0, demo, instance.counts, 1.0, np.random.default_rng(0))
    np.testing.assert_allclose(fit.theta_hat[0], [1, -1, -1], atol=1e-9)


# Paper-size cases (10 x 10, 9 steps from [5, 5], K = 10, sigma = 2) on which the fit once
# stopped far from the optimum (at lambda = 1 and at lambda = 1e-4), and ordinary ones.
_HARD_CASES = {
    "hard-lambda-1": (
        1.0,
        [
            [3.5137622746704267, 8.057718256893502],
            [2.0839835538189098, 3.9991691659073476],
            [1.2966570506573003, 7.28717346799125],
            [3.439456883980899, 3.2123301564383246],
            [2.3116841926264304, 7.5228648796769475],
            [3.9289413367411035, 0.4477057402685478],
            [7.23375259663003, 2.2815337022262963],
            [1.6382474887797254, 2.1032126178160198],
            [4.892287980686045, 8.665849095198642],
            [2.5581659886872297, 4.107556951888878],
        ],
        [
            0.7805844889964382,
            0.18914955300915026,
            -0.4280510983465322,
            0.15076150861672,
            0.4702146646167096,
            0.9041323223910613,
            -0.9997639703921233,
            -0.5563911227452076,
            -0.10233119692172843,
            0.46541027488633735,
        ],
    ),
    # MAP: the vertex (-1, ..., -1, 1, -1) with L = -14.46102...
    "hard-lambda-1e-4": (
        1e-4,
        [
            [4.714740660354562, 4.733206129110601],
            [5.3706734547284904, 6.621959203783918],
            [7.428577747650295, 6.045462598349954],
            [7.600148743905268, 3.287948742844898],
            [4.7115485683314295, 5.61317712355057],
            [3.848933342083941, 1.1951404441564244],
            [4.879347463577173, 5.69139221713066],
            [7.439945512942663, 1.9684044776540832],
            [4.468864360621387, 6.325512797221924],
            [3.4859258185207493, 2.760211482025067],
        ],
        [
            -0.26812449676974937,
            -0.011950397109362187,
            -0.6078600673110326,
            0.09001404122143253,
            0.9128705222916118,
            -0.6720179168347393,
            -0.41512193924003604,
            0.17222189080333616,
            -0.11378262577059606,
            -0.4504443028947487,
        ],
    ),
}


@pytest.mark.parametrize("case", [*_HARD_CASES, "seed-1", "seed-2"])
def test_fit_is_the_box_map_at_the_paper_size(case):
    width = height = 10
    start, horizon = bf.cell(10, 5, 5), 9
    if case in _HARD_CASES:
        rationality, centers, theta = _HARD_CASES[case]
    else:
        rng = np.random.default_rng(int(case[-1]))
        rationality, centers, theta = 1.0, rng.uniform(0, 9, size=(10, 2)), rng.uniform(-1, 1, 10)
    features = bf.rbf_features(width, height, centers, 2.0)
    counts = bf.feature_counts_fast(width, height, start, horizon, features)
    expert = bf.expert_fast(counts, theta)[0]
    demo = counts[expert]
    path = bf.enumerate_paths_array(width, height, start, horizon)[expert]
    fit = _fit(path, features, width, height, start, horizon, rationality)
    theta_hat = fit.theta_hat[0]
    slope = demo - bf.expected_features_fast(counts, theta_hat, rationality)
    outward = ((theta_hat >= 1.0) & (slope > 0)) | ((theta_hat <= -1.0) & (slope < 0))
    slope = np.where(outward, 0.0, slope)
    best = bf.log_likelihood_fast(demo, counts, theta_hat, rationality)
    assert fit.converged[0]
    assert np.abs(slope).max() <= KKT_TOL
    assert fit.log_likelihood[0] == pytest.approx(best, rel=1e-9)
    gap = 2.0 * rationality * np.abs(slope).sum() + 1e-9 * abs(best)
    for point in np.random.default_rng(0).uniform(-1, 1, size=(5, 10)):
        assert best >= bf.log_likelihood_fast(demo, counts, point, rationality) - gap


@pytest.mark.parametrize(("name", "case"), map_reference.reference_cases())
def test_fit_equals_the_high_precision_map(name, case):
    # The converged MAP of map_reference (mpmath, every path enumerated) at lambda from 1e-2 to
    # 1e4: the fit must certify its estimate and be within its tolerance, 1e-6, of it.
    fit = _fit(
        np.array(case["demo_states"]),
        case["features"],
        case["width"],
        case["height"],
        case["start"],
        case["horizon"],
        case["rationality"],
    )
    assert fit.converged[0], name
    np.testing.assert_allclose(fit.theta_hat[0], case["theta_hat"], rtol=0, atol=1e-6)


def _box_step_by_faces(curvature, gradient, theta, ridge):
    """The maximiser of ``g.d - d'(H + ridge I)d/2`` over ``theta + d`` in the box, and the
    model's value there, by trying every face (each coordinate at -1, free or at +1: 3^K)."""
    k = len(gradient)
    matrix = curvature + ridge * np.eye(k)
    best, best_value = None, -np.inf
    for face in itertools.product((-1, 0, 1), repeat=k):
        face = np.array(face)
        d = np.where(face != 0, face - theta, 0.0)
        free = face == 0
        if free.any():
            block = matrix[np.ix_(free, free)]
            if np.linalg.matrix_rank(block) < free.sum():
                continue  # its maxima lie on a smaller face
            rhs = gradient[free] - matrix[np.ix_(free, ~free)] @ d[~free]
            d[free] = np.linalg.solve(block, rhs)
            if np.any(np.abs(theta + d) > 1 + 1e-12):
                continue
        value = gradient @ d - d @ matrix @ d / 2
        if value > best_value:
            best, best_value = d, value
    return best, best_value


@given(
    k=st.integers(1, 4),
    rank=st.integers(0, 4),
    ridge=st.sampled_from([0.0, 1e-8, 1e-2, 1.0]),
    seed=st.integers(0, 2**32 - 1),
)
@settings(max_examples=300, deadline=None)
def test_box_step_maximises_the_model_over_the_box(k, rank, ridge, seed):
    rng = np.random.default_rng(seed)
    rank = min(rank, k) if ridge > 0 else k  # without a ridge the model must be strictly concave
    factor = rng.normal(size=(k, rank)) * rng.choice([1e-3, 1.0, 1e3], size=rank)
    curvature = factor @ factor.T
    gradient = rng.normal(size=k) * rng.choice([1e-3, 1.0, 1e3])
    theta = np.where(rng.random(k) < 0.4, rng.choice([-1.0, 1.0], size=k), rng.uniform(-1, 1, k))
    matrix = curvature + ridge * np.eye(k)
    # Without a ridge the model must be strictly concave in double precision too: a factor
    # column scaled by 1e-3 beside one by 1e3 leaves H singular to rounding (condition
    # number 2.5e16 at k = rank = 4, seed 248), where the step is documented to be NaN
    # (test_a_box_step_on_a_singular_free_block_is_nan).
    assume(ridge > 0 or np.linalg.cond(matrix) < 1e12)
    step = box_step(curvature[None], gradient[None], theta[None], np.array([ridge]))[0]
    assert np.all(np.abs(theta + step) <= 1.0)
    value = gradient @ step - step @ matrix @ step / 2
    expected, best = _box_step_by_faces(curvature, gradient, theta, ridge)
    scale = np.abs(gradient).sum() * 2 + np.abs(matrix).sum() * 4
    assert value >= best - 1e-10 * scale
    # KKT of the model: r = g - M d vanishes on the free coordinates and points out of the box
    # (or is zero) on the bound ones.
    r = gradient - matrix @ step
    upper, lower = theta + step >= 1.0, theta + step <= -1.0
    assert np.all(np.abs(r[~upper & ~lower]) <= 1e-9 * scale)
    assert np.all(r[upper] >= -1e-9 * scale) and np.all(r[lower] <= 1e-9 * scale)
    if np.linalg.eigvalsh(matrix)[0] > 1e-6 * np.abs(matrix).max(initial=1e-300):
        np.testing.assert_allclose(step, expected, atol=1e-7)  # strictly concave: unique


def test_a_box_step_on_a_singular_free_block_is_nan():
    # The undamped step (no ridge) where the free block is singular: the data do not say.
    step = box_step(np.zeros((1, 2, 2)), np.zeros((1, 2)), np.zeros((1, 2)), np.zeros(1))
    assert np.isnan(step).all()


def test_converged_is_the_certificate_at_the_returned_point_and_the_likelihood_is_its_own():
    # Paper-size fits at lambda = 1000 (K = 10), some of which stop with no ascent left at the
    # objective's rounding, and fits cut short at three iterations: whatever stopped a fit,
    # ``converged`` is the certificate at the point returned and ``log_likelihood`` its own.
    width = height = 10
    start, horizon = bf.cell(10, 5, 5), 9
    rng = np.random.default_rng(110)
    rows = 24
    centers = rng.uniform(0, 9, size=(rows, 10, 2))
    theta = rng.uniform(-1, 1, size=(rows, 10))
    features = np.stack([bf.rbf_features(width, height, c, 1.0) for c in centers])
    phase = Phase(bf.move_table(width, height), start, horizon)
    for rationality, cap in ((1e3, 200), (1.0, 3)):
        model = MaxEnt(phase, features, rationality)
        demos = expert_paths(model, theta)
        fit = map_estimate(model, demos, max_iterations=cap)
        classes = model.demonstration_classes(demos)
        objective = _Objective.at(model, classes, fit.theta_hat)
        np.testing.assert_array_equal(
            fit.converged, _certified(fit.theta_hat, objective, tolerance=1e-6)
        )
        # L = -log(m + R) at theta_hat (log Z itself loses L to cancellation at large lambda).
        off = model.off_demonstration(fit.theta_hat, classes, moments=0)
        own = -np.logaddexp(np.log(classes.members), off.log_mass)
        np.testing.assert_allclose(fit.log_likelihood, own, rtol=1e-12)
        if rationality == 1.0:
            counts = model.path_counts(demos)
            np.testing.assert_allclose(own, model.log_likelihood(fit.theta_hat, counts), rtol=1e-9)
        assert (fit.iterations <= cap).all()
        if cap == 3:
            assert not fit.converged.all()  # the cap bit
