"""The MaxEnt trajectory model (docs/design.md §2) against the enumeration in ``path_enumeration``.

The model of a phase (:class:`~cirl_study.core.maxent.MaxEnt` of a
:class:`~cirl_study.core.maxent.Phase`) gives the log-partition, the log-likelihood of a
demonstration and the first two moments of the feature counts; every one is compared with
the same quantity summed over every enumerated path.
"""

import math

import mpmath
import numpy as np
import path_enumeration as bf
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cirl_study.core.maxent import _EXP_TABLE, MaxEnt, Moments, Phase, _split_exp, _split_log


def _model(features, width, height, start, horizon, rationality, batch=1):
    """The model of ``batch`` trials that share one ``(S, K)`` feature matrix."""
    batch_features = np.broadcast_to(features, (batch, *features.shape))
    return MaxEnt(Phase(bf.move_table(width, height), start, horizon), batch_features, rationality)


# ---- log-likelihood and moments -------------------------------------------------------------


@pytest.mark.parametrize("rationality", [1e-4, 1.0, 1e3])
def test_log_likelihood_equals_enumeration(rationality):
    width, height, start, horizon = 4, 4, 5, 5
    rng, features, paths, counts = bf.random_game(width, height, start, horizon, 3, seed=1)
    thetas = rng.uniform(-1, 1, size=(4, 3))
    demos = counts[rng.integers(len(paths), size=4)]
    model = _model(features, width, height, start, horizon, rationality, batch=4)
    got = model.log_likelihood(thetas, demos)
    log_z = model.log_partition(thetas)
    for b in range(4):
        want = bf.log_likelihood(demos[b], counts, thetas[b], rationality)
        assert got[b] == pytest.approx(want, rel=1e-12, abs=1e-11 * max(1.0, rationality))
        assert log_z[b] == pytest.approx(
            bf.log_partition(counts, thetas[b], rationality),
            rel=1e-12,
            abs=1e-11 * max(1.0, rationality),
        )


@pytest.mark.parametrize("rationality", [1e-4, 1.0, 1e3])
def test_trajectory_moments_equal_enumeration(rationality):
    width, height, start, horizon = 3, 5, 7, 5
    rng, features, _, counts = bf.random_game(width, height, start, horizon, 4, seed=2)
    thetas = rng.uniform(-1, 1, size=(3, 4))
    moments = _model(features, width, height, start, horizon, rationality, batch=3).moments(thetas)
    assert isinstance(moments, Moments)
    assert moments.log_partition.shape == (3,)
    assert moments.mean.shape == (3, 4)
    assert moments.covariance.shape == (3, 4, 4)
    for b in range(3):
        assert moments.log_partition[b] == pytest.approx(
            bf.log_partition(counts, thetas[b], rationality), rel=1e-12
        )
        np.testing.assert_allclose(
            moments.mean[b],
            bf.expected_features(counts, thetas[b], rationality),
            rtol=1e-10,
            atol=1e-13,
        )
        np.testing.assert_allclose(
            moments.covariance[b],
            bf.feature_covariance(counts, thetas[b], rationality),
            rtol=1e-8,
            atol=1e-12,
        )


def test_log_partition_and_log_likelihood_agree_with_the_moments():
    # The three entry points compute log Z by the same recursion: they agree to the last bit.
    width, height, start, horizon, rationality = 4, 3, 5, 4, 2.5
    rng, features, paths, counts = bf.random_game(width, height, start, horizon, 3, seed=6)
    thetas = rng.uniform(-1, 1, size=(5, 3))
    demos = counts[rng.integers(len(paths), size=5)]
    model = _model(features, width, height, start, horizon, rationality, batch=5)
    log_z = model.log_partition(thetas)
    np.testing.assert_array_equal(log_z, model.moments(thetas).log_partition)
    np.testing.assert_array_equal(
        model.log_likelihood(thetas, demos),
        rationality * np.einsum("bk,bk->b", thetas, demos) - log_z,
    )


@pytest.mark.parametrize("rationality", [1e-4, 1.0, 1e3])
def test_log_likelihood_at_equals_enumeration(rationality):
    width, height, start, horizon = 4, 4, 5, 5
    rng, features, paths, counts = bf.random_game(width, height, start, horizon, 3, seed=8)
    thetas = rng.uniform(-1, 1, size=(2, 6, 3))
    demos = counts[rng.integers(len(paths), size=2)]
    got = _model(features, width, height, start, horizon, rationality, 2).log_likelihood_at(
        thetas, demos
    )
    for b in range(2):
        for n in range(6):
            want = bf.log_likelihood(demos[b], counts, thetas[b, n], rationality)
            assert got[b, n] == pytest.approx(want, rel=1e-12, abs=1e-11 * max(1.0, rationality))


@pytest.mark.parametrize("rationality", [1e-4, 1.0, 10.0, 30.0, 100.0, 1e3, 1e5])
def test_log_likelihood_at_equals_the_one_at_a_time_recursion(rationality):
    # log_likelihood_at scores points in linear space with a binary exponent per cell, at
    # every lambda; it matches the log-space soft value iteration of log_partition to the
    # rounding of the terms that one sums, about T * lambda * max|theta . phi|.
    width, height, start, horizon, k = 10, 10, 55, 9, 10
    rng = np.random.default_rng(9)
    centres = rng.uniform(0, 9, size=(k, 2))
    features = bf.rbf_features(width, height, centres, 1.5)
    thetas = rng.uniform(-1, 1, size=(64, k))
    demo = features[rng.integers(width * height, size=horizon)].sum(axis=0)
    model = _model(features, width, height, start, horizon, rationality, batch=64)
    one_at_a_time = model.log_likelihood(thetas, np.broadcast_to(demo, (64, k)))
    batched = model.take([0]).log_likelihood_at(thetas[None], demo[None])[0]
    scale = 1.0 + horizon * rationality * np.abs(thetas @ features.T).max(axis=1)
    np.testing.assert_array_less(np.abs(batched - one_at_a_time), 1e-12 * scale)
    # Each point is scored on its own: the same bits alone as among the others, in the
    # SIMD lanes' loop or its remainder.
    for n in (0, 17, 63):
        alone = model.take([0]).log_likelihood_at(thetas[None, [n]], demo[None])[0, 0]
        assert alone == batched[n]
    np.testing.assert_array_equal(
        model.take([0]).log_likelihood_at(thetas[None, 5:], demo[None])[0], batched[5:]
    )


@pytest.mark.parametrize("rationality", [1e-4, 1.0, 1e3, 1e5])
def test_log_likelihood_at_equals_high_precision_enumeration(rationality):
    # Every path's weight summed in 50 digits, at the float64 points: the error is the
    # rounding of lambda * theta . phi(s) (relative 2^-53, each of the T terms of a path)
    # and of the sums, so within a few T ulp of lambda * max|theta . phi(s)|.
    width, height, start, horizon = 4, 4, 5, 5
    rng, features, paths, counts = bf.random_game(width, height, start, horizon, 3, seed=12)
    thetas = rng.uniform(-1, 1, size=(1, 9, 3))
    demo = counts[rng.integers(len(paths), size=1)]
    got = _model(features, width, height, start, horizon, rationality, 1).log_likelihood_at(
        thetas, demo
    )[0]
    with mpmath.workdps(50):
        for n, theta in enumerate(thetas[0]):
            scores = [
                rationality
                * mpmath.fsum(mpmath.mpf(c) * t for c, t in zip(row, theta, strict=True))
                for row in counts
            ]
            top = max(scores)
            log_z = top + mpmath.log(mpmath.fsum(mpmath.exp(s - top) for s in scores))
            want = (
                rationality
                * mpmath.fsum(mpmath.mpf(c) * t for c, t in zip(demo[0], theta, strict=True))
                - log_z
            )
            scale = 1.0 + rationality * np.abs(features @ theta).max()
            assert abs(float(got[n] - want)) <= 8 * horizon * 2.0**-52 * scale


@pytest.mark.parametrize(("horizon", "rationality"), [(40, 1e-4), (40, 1.0), (40, 50.0), (19, 1e3)])
def test_log_likelihood_at_renormalises_long_phases(horizon, rationality):
    # Masses grow by up to 2A = 10 a step, so phases longer than 18 steps are brought back
    # to [1, 2) on the way; the soft value iteration of log_partition is the reference.
    width, height, start, k = 3, 3, 4, 3
    rng = np.random.default_rng(horizon)
    features = rng.uniform(0, 1, size=(width * height, k))
    thetas = rng.uniform(-1, 1, size=(20, k))
    demo = features[rng.integers(width * height, size=horizon)].sum(axis=0)
    model = _model(features, width, height, start, horizon, rationality, batch=20)
    want = model.log_likelihood(thetas, np.broadcast_to(demo, (20, k)))
    got = model.take([0]).log_likelihood_at(thetas[None], demo[None])[0]
    scale = 1.0 + horizon * rationality * np.abs(thetas @ features.T).max(axis=1)
    np.testing.assert_array_less(np.abs(got - want), 1e-12 * scale)


def test_the_exponential_table_is_correctly_rounded():
    assert len(_EXP_TABLE) == int(32 * math.log(2.0)) + 1
    with mpmath.workdps(50):
        for j, value in enumerate(_EXP_TABLE):
            assert value == float(mpmath.exp(mpmath.mpf(j) / 32)), j


def test_split_log_is_within_two_ulp_of_high_precision():
    rng = np.random.default_rng(4)
    cases = [
        (m, float(e))
        for m, e in zip(rng.uniform(1.0, 2.0**61, 300), rng.integers(-5000, 5000, 300), strict=True)
    ]
    cases += [(m, 0.0) for m in rng.uniform(1.0, 2.0, 300)]
    cases += [(1.0, 0.0), (2.0, 0.0), (math.sqrt(2.0), 0.0), (1.0 + 2.0**-52, 0.0), (1.0, -3.0)]
    with mpmath.workdps(40):
        for m, e in cases:
            want = mpmath.log(mpmath.mpf(m)) + e * mpmath.log(2)
            got = _split_log(m, e)
            assert abs(float(got - want)) <= 2 * 2.0**-52 * max(abs(float(want)), 1e-300), (m, e)
    assert _split_log(1.0, 0.0) == 0.0


def test_split_exp_is_within_two_ulp_of_high_precision():
    rng = np.random.default_rng(3)
    xs = [*rng.uniform(-745.0, 709.0, 400), *rng.uniform(-1e5, 1e5, 100)]
    xs += [0.0, 1e-300, -1e-300, math.log(2.0), -math.log(2.0), 1.0 / 32.0, -40.0]
    with mpmath.workdps(40):
        for x in xs:
            m, e = _split_exp(x)
            assert e == math.floor(e)
            assert 1.0 <= m < 2.0 * (1.0 + 2.0**-40)
            exact = mpmath.exp(mpmath.mpf(x)) / mpmath.mpf(2) ** int(e)
            assert abs(float((m - exact) / exact)) <= 2 * 2.0**-52, x


@pytest.mark.parametrize("rationality", [1e-2, 1.0, 20.0, 1e3])
def test_gradient_and_hessian_equal_finite_differences(rationality):
    width, height, start, horizon = 4, 4, 6, 4
    rng, features, paths, counts = bf.random_game(width, height, start, horizon, 3, seed=3)
    theta = rng.uniform(-0.8, 0.8, size=3)
    demo = counts[rng.integers(len(paths))]
    moments = _model(features, width, height, start, horizon, rationality).moments(theta[None])
    gradient = rationality * (demo - moments.mean[0])  # docs/design.md §2
    hessian = -(rationality**2) * moments.covariance[0]
    step = 1e-5 / max(1.0, rationality)
    for k in range(3):
        e = np.zeros(3)
        e[k] = step
        up = bf.log_likelihood(demo, counts, theta + e, rationality)
        down = bf.log_likelihood(demo, counts, theta - e, rationality)
        scale = rationality * max(1.0, np.abs(demo).max())
        assert gradient[k] == pytest.approx((up - down) / (2 * step), abs=1e-6 * scale)
        slope_up = rationality * (demo - bf.expected_features(counts, theta + e, rationality))
        slope_down = rationality * (demo - bf.expected_features(counts, theta - e, rationality))
        np.testing.assert_allclose(
            hessian[k], (slope_up - slope_down) / (2 * step), atol=1e-5 * rationality * scale
        )


def test_finite_differences_notice_a_wrong_gradient():
    # The check above is sharp: a gradient off by lambda * phi(s_0) (start counted) fails it.
    width, height, start, horizon, rationality = 4, 4, 6, 4, 1.0
    rng, features, paths, counts = bf.random_game(width, height, start, horizon, 3, seed=3)
    theta = rng.uniform(-0.8, 0.8, size=3)
    demo = counts[rng.integers(len(paths))]
    right = rationality * (demo - bf.expected_features(counts, theta, rationality))
    wrong = right + rationality * features[start]
    step = 1e-5
    fd = np.array(
        [
            (
                bf.log_likelihood(demo, counts, theta + step * e, rationality)
                - bf.log_likelihood(demo, counts, theta - step * e, rationality)
            )
            / (2 * step)
            for e in np.eye(3)
        ]
    )
    np.testing.assert_allclose(right, fd, atol=1e-6)
    assert np.abs(wrong - fd).max() > 1e-3


# ---- the phase ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "width, height, start, horizon", [(4, 4, 5, 4), (3, 5, 0, 3), (1, 3, 1, 3), (1, 1, 0, 2)]
)
def test_phase_reaches_exactly_the_cells_of_enumerated_paths(width, height, start, horizon):
    phase = Phase(bf.move_table(width, height), start, horizon)
    assert phase.start_cell == start
    want = np.zeros((horizon + 1, width * height), dtype=bool)
    for path in bf.enumerate_paths(width, height, start, horizon):
        want[np.arange(horizon + 1), list(path)] = True
    np.testing.assert_array_equal(phase.reachable, want)


@pytest.mark.parametrize("width, height, horizon", [(4, 4, 3), (1, 3, 2), (2, 2, 0)])
def test_a_phase_that_starts_anywhere_reaches_every_cell_and_has_no_log_partition(
    width, height, horizon
):
    phase = Phase(bf.move_table(width, height), None, horizon)
    assert phase.start is None
    np.testing.assert_array_equal(phase.reachable, np.ones((horizon + 1, width * height), bool))
    with pytest.raises(ValueError):
        _ = phase.start_cell
    _, features, _, _ = bf.random_game(width, height, 0, horizon, 2, seed=0)
    model = MaxEnt(phase, features[None], 1.0)
    theta, demo = np.array([[0.5, -0.5]]), np.zeros((1, 2))
    with pytest.raises(ValueError):
        model.log_partition(theta)
    with pytest.raises(ValueError):
        model.log_likelihood(theta, demo)
    with pytest.raises(ValueError):
        model.moments(theta)


def test_phase_normalises_its_fields():
    table = bf.move_table(3, 2).astype(np.int32)
    phase = Phase(table, np.int64(4), np.int32(3))
    assert phase.successors.dtype == np.int64 and phase.successors.flags.c_contiguous
    np.testing.assert_array_equal(phase.successors, bf.move_table(3, 2))
    assert type(phase.start) is int and phase.start == 4
    assert type(phase.horizon) is int and phase.horizon == 3


# ---- the batch: take, path counts, cell rewards ---------------------------------------------


@pytest.mark.parametrize("rationality", [1e-4, 1.0, 1e3])
def test_take_gives_the_rows_of_the_full_model(rationality):
    # Each trial is computed alone: the model of some rows is bit-identical to those rows.
    width, height, start, horizon, batch = 4, 4, 6, 4, 6
    rng = np.random.default_rng(17)
    centers = rng.uniform(0, 3, size=(batch, 3, 2))
    features = np.array([bf.rbf_features(width, height, c, 1.3) for c in centers])
    thetas = rng.uniform(-1, 1, size=(batch, 3))
    model = MaxEnt(Phase(bf.move_table(width, height), start, horizon), features, rationality)
    full = model.moments(thetas)
    for rows in (np.array([4, 0, 2]), np.array([True, False, False, True, True, False])):
        part = model.take(rows)
        assert part.phase is model.phase and part.rationality == model.rationality
        assert part.batch == len(thetas[rows])
        np.testing.assert_array_equal(part.features, features[rows])
        got = part.moments(thetas[rows])
        np.testing.assert_array_equal(got.log_partition, full.log_partition[rows])
        np.testing.assert_array_equal(got.mean, full.mean[rows])
        np.testing.assert_array_equal(got.covariance, full.covariance[rows])
        np.testing.assert_array_equal(
            part.log_partition(thetas[rows]), model.log_partition(thetas)[rows]
        )


@given(instance=bf.instances(max_side=4, max_horizon=4, max_features=4), data=st.data())
@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_path_counts_equal_the_reference_feature_counts(instance, data):
    # A batch of trials, each with its own features and path; the start cell is not counted.
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    batch = 3
    features = instance.features[None] * rng.uniform(0.5, 2.0, size=(batch, 1, 1))
    chosen = rng.integers(len(instance.paths), size=batch)
    paths = instance.paths[chosen]
    phase = Phase(bf.move_table(instance.width, instance.height), instance.start, instance.horizon)
    got = MaxEnt(phase, features, instance.rationality).path_counts(paths)
    assert got.shape == (batch, len(instance.theta))
    for b in range(batch):
        want = bf.feature_counts(paths[b : b + 1], features[b])[0]
        np.testing.assert_allclose(got[b], want, rtol=1e-14, atol=1e-300)


def test_cell_rewards_are_theta_dot_phi_of_every_cell():
    rng = np.random.default_rng(5)
    features = np.array([bf.rbf_features(3, 3, rng.uniform(0, 2, (2, 2)), 1.0) for _ in range(2)])
    thetas = rng.uniform(-1, 1, size=(2, 2))
    model = MaxEnt(Phase(bf.move_table(3, 3), 0, 2), features, 1.0)
    got = model.cell_rewards(thetas)
    assert got.shape == (2, 9)
    for b in range(2):
        np.testing.assert_allclose(got[b], bf.path_rewards(features[b], thetas[b]), rtol=1e-14)


@pytest.mark.parametrize("seed", range(6))
def test_off_demonstration_moments_equal_enumeration(seed):
    # log R, E_q[Delta] and Cov_q[Delta] over the paths whose counts differ from the
    # demonstration's, summed path by path; demonstrations include back-and-forth walks, whose
    # reorderings share their counts (the class has several members).
    width, height, horizon = 4, 3, 4
    rng = np.random.default_rng(seed)
    start = int(rng.integers(width * height))
    rng, features, paths, counts = bf.random_game(width, height, start, horizon, 3, seed=seed)
    if seed % 3 == 0:
        there = next(int(c) for c in bf.move_table(width, height)[start] if c >= 0 and c != start)
        demo = np.array([start, there, start, there, start])
    else:
        demo = paths[rng.integers(len(paths))]
    theta = rng.uniform(-1, 1, size=(1, 3))
    rationality = float(10 ** rng.uniform(-1, 3))
    model = MaxEnt(Phase(bf.move_table(width, height), start, horizon), features[None], rationality)
    classes = model.demonstration_classes(demo[None])
    off = model.off_demonstration(theta, classes)
    same = np.array([sorted(p[1:]) == sorted(demo[1:]) for p in paths.tolist()])
    assert classes.members[0] == same.sum()
    delta = counts[~same] - bf.feature_counts(demo[None], features)[0]
    scores = rationality * delta @ theta[0]
    top = scores.max()
    weights = np.exp(scores - top)
    q = weights / weights.sum()
    mean = q @ delta
    covariance = (delta - mean).T @ ((delta - mean) * q[:, None])
    assert off.log_mass[0] == pytest.approx(top + np.log(weights.sum()), rel=1e-12, abs=1e-12)
    np.testing.assert_allclose(off.mean[0], mean, rtol=0, atol=1e-12)
    np.testing.assert_allclose(off.covariance[0], covariance, rtol=0, atol=1e-12)
    without = model.off_demonstration(theta, classes, moments=1)
    np.testing.assert_array_equal(without.mean, off.mean)
    np.testing.assert_array_equal(without.covariance, 0.0)
    mass_only = model.off_demonstration(theta, classes, moments=0)
    np.testing.assert_array_equal(mass_only.log_mass, off.log_mass)
    np.testing.assert_array_equal(mass_only.mean, 0.0)


def test_demonstration_classes_take_rows():
    width, height, start, horizon = 3, 3, 4, 3
    _, features, paths, _ = bf.random_game(width, height, start, horizon, 2, seed=3)
    model = MaxEnt(
        Phase(bf.move_table(width, height), start, horizon),
        np.broadcast_to(features, (4, *features.shape)),
        2.0,
    )
    demos = paths[[0, 5, 9, 11]]
    classes = model.demonstration_classes(demos)
    rows = np.array([2, 0])
    picked = classes.take(rows)
    alone = model.take(rows).demonstration_classes(demos[rows])
    for field in ("members", "offsets", "step", "cell", "shift", "log_multiplicity"):
        np.testing.assert_array_equal(getattr(picked, field), getattr(alone, field))


def test_moments_without_covariance_keep_the_mean():
    width, height, start, horizon = 4, 3, 5, 4
    rng, features, _, _ = bf.random_game(width, height, start, horizon, 3, seed=4)
    model = MaxEnt(Phase(bf.move_table(width, height), start, horizon), features[None], 2.0)
    theta = rng.uniform(-1, 1, size=(1, 3))
    full, mean_only = model.moments(theta), model.moments(theta, covariance=False)
    np.testing.assert_array_equal(mean_only.mean, full.mean)
    np.testing.assert_array_equal(mean_only.log_partition, full.log_partition)
    np.testing.assert_array_equal(mean_only.covariance, 0.0)


@pytest.mark.parametrize("rationality", [10.0, 100.0, 1000.0])
@pytest.mark.parametrize("seed", range(4))
def test_off_demonstration_covariance_keeps_its_relative_accuracy(seed, rationality):
    # Where the mass outside the demonstration's class sits almost all on one path (large
    # lambda), its covariance is tiny beside the squared counts. Against a 50-digit sum path by
    # path, every entry is accurate relative to the variances, down to a floor set by the
    # rounding of the mean in double precision (eps |E_q Delta|)^2, not by the counts' size.
    width, height, start, horizon = 4, 3, 5, 4
    rng, features, paths, counts = bf.random_game(width, height, start, horizon, 3, seed=seed)
    demo = paths[rng.integers(len(paths))]
    theta = rng.uniform(-1, 1, size=(1, 3))
    model = _model(features, width, height, start, horizon, rationality)
    off = model.off_demonstration(theta, model.demonstration_classes(demo[None]))
    same = np.array([sorted(p[1:]) == sorted(demo[1:]) for p in paths.tolist()])
    delta = counts[~same] - bf.feature_counts(demo[None], features)[0]
    with mpmath.workdps(50):
        scores = [
            rationality * mpmath.fsum(mpmath.mpf(d) * t for d, t in zip(row, theta[0], strict=True))
            for row in delta
        ]
        top = max(scores)
        weights = [mpmath.exp(s - top) for s in scores]
        total = mpmath.fsum(weights)
        q = [w / total for w in weights]
        mean = [
            mpmath.fsum(qi * mpmath.mpf(row[i]) for qi, row in zip(q, delta, strict=True))
            for i in range(3)
        ]
        covariance = np.array(
            [
                [
                    float(
                        mpmath.fsum(
                            qi * (mpmath.mpf(row[i]) - mean[i]) * (mpmath.mpf(row[j]) - mean[j])
                            for qi, row in zip(q, delta, strict=True)
                        )
                    )
                    for j in range(3)
                ]
                for i in range(3)
            ]
        )
    scale = np.sqrt(np.outer(np.diag(covariance), np.diag(covariance)))
    floor = (8 * np.finfo(float).eps * np.abs(np.array(mean, dtype=float)).max()) ** 2
    np.testing.assert_array_less(np.abs(off.covariance[0] - covariance), 1e-9 * scale + floor)
