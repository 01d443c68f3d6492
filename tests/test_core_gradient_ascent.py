"""The ``gradient_ascent`` robot (docs/design.md §2) against plain numpy gradient ascent on the
exact likelihood of every enumerated path (``path_enumeration``).

The reference runs the contract's update :math:`\\theta \\leftarrow \\theta + \\alpha \\lambda
(\\phi(\\tau_{demo}) - E_\\theta[\\phi])` from :math:`\\theta = 0`, with :math:`E_\\theta[\\phi]`
summed over the enumerated paths (log-sum-exp, exactly rounded sums): no code shared with the
robot, which computes the same step from the off-demonstration moments.
"""

from __future__ import annotations

import numpy as np
import path_enumeration as bf
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cirl_study.core.apprenticeship import Apprenticeship
from cirl_study.core.gradient_ascent import gradient_ascent_estimate
from cirl_study.core.maxent import MaxEnt, Phase
from cirl_study.core.players import ROBOTS
from cirl_study.record import GRADIENT_ASCENT, GradientAscent

RELATIVE = 1e-9
"""How near the robot's estimate and log-likelihood must be to the reference's."""


def stable_rate(instance: bf.Instance, fraction: float) -> float:
    """``fraction`` of the largest step size at which ascent provably rises at every step.

    :math:`-L` is smooth with constant :math:`\\lambda^2 \\max \\mathrm{eig\\,Cov}[\\phi]
    \\le \\lambda^2 K T^2 / 4` (each count lies in ``[0, T]``), so ``alpha < 8 / (lambda^2 K
    T^2)`` keeps every step an ascent; past it the iteration may oscillate, and its orbit then
    amplifies rounding (it is not a comparison to 1e-9 of two ways to sum).
    """
    k = len(instance.theta)
    return fraction * 8.0 / (instance.rationality**2 * k * instance.horizon**2)


def reference(
    counts: np.ndarray, demo: np.ndarray, rationality: float, steps: int, learning_rate: float
) -> np.ndarray:
    """``theta_N`` of plain gradient ascent on the enumerated likelihood."""
    theta = np.zeros(counts.shape[1])
    for _ in range(steps):
        expected = bf.expected_features(counts, theta, rationality)
        theta = theta + learning_rate * rationality * (demo - expected)
    return theta


def fit(instance: bf.Instance, demo_rows: list[int], steps: int, learning_rate: float):
    """The robot's fit of the demonstrations ``instance.paths[demo_rows]``, in one batch."""
    demos = instance.paths[demo_rows]
    features = np.broadcast_to(instance.features, (len(demos), *instance.features.shape))
    phase = Phase(bf.move_table(instance.width, instance.height), instance.start, instance.horizon)
    model = MaxEnt(phase, features, instance.rationality)
    return gradient_ascent_estimate(model, demos, steps, learning_rate)


def check(instance: bf.Instance, demo_rows: list[int], steps: int, learning_rate: float):
    """The robot's estimates and log-likelihoods equal the reference's to :data:`RELATIVE`."""
    got = fit(instance, demo_rows, steps, learning_rate)
    for b, row in enumerate(demo_rows):
        demo = instance.counts[row]
        want = reference(instance.counts, demo, instance.rationality, steps, learning_rate)
        scale = max(1.0, float(np.abs(want).max()))
        np.testing.assert_allclose(got.theta_hat[b], want, rtol=RELATIVE, atol=RELATIVE * scale)
        likelihood = bf.log_likelihood(demo, instance.counts, want, instance.rationality)
        assert got.log_likelihood[b] == pytest.approx(
            likelihood, rel=RELATIVE, abs=RELATIVE * instance.rationality * scale
        )
    assert got.iterations.tolist() == [steps] * len(demo_rows)
    assert got.converged.all()
    return got


def square(theta: tuple[float, ...], rationality: float, horizon: int = 3) -> bf.Instance:
    """A 3x3 game from the centre with two RBFs in opposite corners."""
    return bf.Instance(
        width=3,
        height=3,
        start=4,
        horizon=horizon,
        centers=((0.0, 0.0), (2.0, 2.0)),
        sigma=1.0,
        theta=theta,
        rationality=rationality,
    )


@settings(max_examples=40, deadline=None)
@given(
    instance=bf.instances(max_side=3, max_horizon=4, log10_rationality=(-2.0, 1.0)),
    data=st.data(),
)
def test_the_estimate_is_that_of_gradient_ascent_on_the_enumerated_likelihood(instance, data):
    rows = data.draw(st.lists(st.integers(0, len(instance.paths) - 1), min_size=1, max_size=3))
    steps = data.draw(st.integers(1, 30))
    learning_rate = stable_rate(instance, data.draw(st.floats(0.01, 0.99)))
    check(instance, rows, steps, learning_rate)


def test_an_expert_estimate_leaves_the_box_and_grows_with_the_step_budget():
    instance = square((0.3, 0.8), rationality=1.0)
    expert, _ = bf.expert(instance.counts, instance.theta)
    short = check(instance, [expert], 30, 0.1)
    long = check(instance, [expert], 300, 0.1)
    assert np.abs(short.theta_hat).max() > 1.0
    assert np.linalg.norm(long.theta_hat) > np.linalg.norm(short.theta_hat)


@pytest.mark.parametrize("rationality", [30.0, 1000.0, 1e4])
def test_the_estimate_at_large_lambda_is_the_reference(rationality):
    """An expert's class soon holds all but a sliver of the mass: the step shrinks to nothing
    without a rounding error's worth of drift, in the robot as in the reference; a middling
    demonstration's estimate settles inside."""
    instance = square((-0.6, 0.9), rationality=rationality, horizon=4)
    expert, _ = bf.expert(instance.counts, instance.theta)
    other = int(np.argsort(instance.counts @ np.array(instance.theta))[len(instance.paths) // 2])
    check(instance, [expert, other], 50, stable_rate(instance, 0.5))


def test_the_largest_settings_stay_finite():
    """lambda = 1e4 and alpha = 100 (a pipeline's largest): every step jumps by about 1e6, the
    model is all but the hard maximum, and nothing overflows. Past the stable step size the
    iterate depends on each step's rounding (the module docstring), so only its first step is
    compared with the reference; every step keeps the bound ``|theta_k| <= N alpha lambda T``,
    and a trial's estimate is the same in any batch."""
    instance = square((-0.6, 0.9), rationality=1e4, horizon=4)
    expert, _ = bf.expert(instance.counts, instance.theta)
    check(instance, [expert], 1, 100.0)
    steps = 200
    got = fit(instance, [expert, 0, expert], steps, 100.0)
    assert np.isfinite(got.theta_hat).all() and np.isfinite(got.log_likelihood).all()
    assert np.abs(got.theta_hat).max() <= steps * 100.0 * 1e4 * instance.horizon
    assert (got.log_likelihood <= 0).all()
    alone = fit(instance, [expert], steps, 100.0)
    assert got.theta_hat[0].tolist() == got.theta_hat[2].tolist() == alone.theta_hat[0].tolist()


@pytest.mark.parametrize("num_features", [3, 10])
def test_the_estimate_at_the_paper_size_is_the_reference(num_features):
    """The paper's game (10 x 10, 9 steps from the centre, sigma 1.5, lambda 1: 1.9 million
    paths) with 30 steps of alpha = 0.1, for an expert's demonstration and another path."""
    rng = np.random.default_rng(num_features)
    centers = rng.uniform(0.0, 9.0, size=(num_features, 2))
    theta = rng.uniform(-1.0, 1.0, num_features)
    start, horizon, steps, learning_rate = bf.cell(10, 5, 5), 9, 30, 0.1
    features = bf.rbf_features(10, 10, centers, 1.5)
    paths = bf.enumerate_paths_array(10, 10, start, horizon)
    counts = bf.feature_counts_fast(10, 10, start, horizon, features)
    rows = [int(np.argmax(counts @ theta)), int(rng.integers(len(paths)))]
    model = MaxEnt(Phase(bf.move_table(10, 10), start, horizon), features[None], 1.0)
    for row in rows:
        got = gradient_ascent_estimate(model, paths[[row]].astype(np.int64), steps, learning_rate)
        want = np.zeros(num_features)
        for _ in range(steps):
            want = want + learning_rate * (
                counts[row] - bf.expected_features_fast(counts, want, 1.0)
            )
        scale = max(1.0, float(np.abs(want).max()))
        np.testing.assert_allclose(got.theta_hat[0], want, rtol=RELATIVE, atol=RELATIVE * scale)
    assert np.abs(want).max() > 0.0


def test_a_demonstration_every_path_shares_leaves_theta_at_zero():
    """On a 1x2 grid without staying put each path alternates the two cells: one count class."""
    game = MaxEnt(Phase(np.array([[-1, 1], [0, -1]]), 0, 3), np.array([[[0.2], [0.9]]]), 1.0)
    got = gradient_ascent_estimate(game, np.array([[0, 1, 0, 1]]), 10, 0.5)
    assert got.theta_hat.tolist() == [[0.0]]
    assert got.log_likelihood.tolist() == [0.0]


def test_the_robot_reads_its_settings_from_the_game():
    instance = square((0.3, 0.8), rationality=1.0)
    expert, _ = bf.expert(instance.counts, instance.theta)
    phase = Phase(bf.move_table(3, 3), instance.start, instance.horizon)
    model = MaxEnt(phase, instance.features[None], 1.0)
    demos = instance.paths[[expert]]
    game = Apprenticeship(model, model, gradient_ascent=GradientAscent(steps=7, learning_rate=0.2))
    got = ROBOTS[GRADIENT_ASCENT].estimate(game, demos, np.array([0]))
    want = gradient_ascent_estimate(model, demos, 7, 0.2)
    assert got.theta_hat.tolist() == want.theta_hat.tolist()
    with pytest.raises(ValueError, match="no gradient_ascent settings"):
        ROBOTS[GRADIENT_ASCENT].estimate(Apprenticeship(model, model), demos, np.array([0]))
