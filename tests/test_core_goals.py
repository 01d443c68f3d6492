"""Episodes that end at a goal (docs/design.md §1-4) against brute-force enumeration.

Every quantity of a goal phase (its paths, log Z, the moments of the counts, the likelihood,
the expert's and the best response's paths, the measures) is computed here from the list of
every path that reaches a goal within the moves (``path_enumeration.episode_paths``), on small
tile games whose one-hot features tie often, at rationalities from 1e-4 to 1e4.
"""

from __future__ import annotations

import math

import numpy as np
import path_enumeration as bf
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import minimize

from cirl_study.core.humans import best_response_paths, expert_paths
from cirl_study.core.maxent import MaxEnt, Phase
from cirl_study.core.measures import regret, trajectory_kl
from cirl_study.core.robot import map_estimate
from cirl_study.features import TileFeatures, feature_matrix

RATIONALITIES = (1e-4, 1e-2, 1.0, 10.0, 1e2, 1e4)

LAYOUT = ("ab.g", ".bb.", "a..a")
"""A 4 x 3 tile game: its goal ``g`` in the top right corner."""

TILES = TileFeatures(
    layout=LAYOUT,
    names=("a", "b", "step"),
    legend=(("a", "a"), ("b", "b"), (".", None), ("g", None)),
    step="step",
)
WIDTH, HEIGHT = 4, 3
GOAL = 2 * WIDTH + 3
START = 0
PHI = feature_matrix(WIDTH, HEIGHT, TILES)


def _table(stays: bool) -> np.ndarray:
    table = bf.move_table(WIDTH, HEIGHT)
    if not stays:
        table = table.copy()
        table[:, 0] = -1
    return table


def _phase(horizon: int, stays: bool, start: int | None = START) -> Phase:
    return Phase(_table(stays), start, horizon, (GOAL,))


def _strip(path: np.ndarray, phase: Phase) -> tuple[int, ...]:
    return tuple(int(c) for c in path[: phase.path_ends(path[None])[0] + 1])


def test_the_tile_matrix_is_the_hand_written_one() -> None:
    a, b, step = (1.0, 0.0, 1.0), (0.0, 1.0, 1.0), (0.0, 0.0, 1.0)
    rows = {
        (0, 2): a, (1, 2): b, (2, 2): step, (3, 2): step,
        (0, 1): step, (1, 1): b, (2, 1): b, (3, 1): step,
        (0, 0): a, (1, 0): step, (2, 0): step, (3, 0): a,
    }  # fmt: skip
    want = np.array([rows[x, y] for y in range(HEIGHT) for x in range(WIDTH)])
    np.testing.assert_array_equal(PHI, want)


@pytest.mark.parametrize("stays", [False, True])
@pytest.mark.parametrize("horizon", [3, 5, 6])
def test_the_live_cells_are_those_of_the_enumerated_episodes(horizon: int, stays: bool) -> None:
    phase = _phase(horizon, stays)
    paths = bf.episode_paths(_table(stays), START, horizon, (GOAL,))
    want = np.zeros_like(phase.reachable)
    for path in paths:
        padded = list(path) + [phase.sink] * (horizon + 1 - len(path))
        for t, cell in enumerate(padded):
            want[t, cell] = True
    np.testing.assert_array_equal(phase.reachable, want)


@pytest.mark.parametrize("rationality", RATIONALITIES)
@pytest.mark.parametrize("stays", [False, True])
def test_log_partition_and_moments_equal_enumeration(rationality: float, stays: bool) -> None:
    horizon = 6
    phase = _phase(horizon, stays)
    counts = bf.episode_counts(bf.episode_paths(_table(stays), START, horizon, (GOAL,)), PHI)
    rng = np.random.default_rng(11)
    theta = rng.uniform(-1, 1, size=(4, 3))
    model = MaxEnt(phase, np.broadcast_to(PHI, (4, *PHI.shape)), rationality)
    got = model.moments(theta)
    for b in range(4):
        scores = rationality * counts @ theta[b]
        log_z = bf.logsumexp(scores)
        p = np.exp(scores - log_z)
        mean = p @ counts
        cov = (counts - mean).T @ ((counts - mean) * p[:, None])
        assert got.log_partition[b] == pytest.approx(log_z, rel=1e-12, abs=1e-12)
        np.testing.assert_allclose(got.mean[b], mean, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(got.covariance[b], cov, rtol=1e-7, atol=1e-9)
        one = model.take(np.array([b]))
        log_likelihood = one.log_likelihood_at(theta[b][None, None], counts[:1])[0, 0]
        assert log_likelihood == pytest.approx(scores[0] - log_z, rel=1e-10, abs=1e-10)


@given(seed=st.integers(0, 2**32 - 1), horizon=st.integers(5, 8), stays=st.booleans())
@settings(max_examples=25, deadline=None)
def test_the_expert_and_best_response_are_the_enumerated_optima(seed, horizon, stays) -> None:
    phase = _phase(horizon, stays)
    paths = bf.episode_paths(_table(stays), START, horizon, (GOAL,))
    counts = bf.episode_counts(paths, PHI)
    rng = np.random.default_rng(seed)
    theta = rng.uniform(-1, 1, size=(3, 3))
    eta = rng.uniform(0.1, 3.0, size=3)
    model = MaxEnt(phase, np.broadcast_to(PHI, (3, *PHI.shape)), 1.0)
    shown = expert_paths(model, theta)
    taught = best_response_paths(model, theta, eta)
    target = model.moments(theta, covariance=False).mean + theta / (2 * eta[:, None])
    for b in range(3):
        expert = _strip(shown[b], phase)
        assert expert in paths
        reward = PHI[list(expert[1:])].sum(axis=0) @ theta[b]
        assert reward == pytest.approx((counts @ theta[b]).max(), abs=1e-12)
        response = _strip(taught[b], phase)
        assert response in paths
        distance = ((PHI[list(response[1:])].sum(axis=0) - target[b]) ** 2).sum()
        assert distance == pytest.approx(((counts - target[b]) ** 2).sum(axis=1).min(), abs=1e-9)


@pytest.mark.parametrize("rationality", [1e-4, 1e-2, 1.0, 1e2, 1e4])
def test_regret_and_kl_equal_enumeration_over_the_non_goal_starts(rationality: float) -> None:
    horizon = 5
    table = _table(True)
    phase = Phase(table, None, horizon, (GOAL,))
    rng = np.random.default_rng(5)
    theta = rng.integers(-1, 2, size=(3, 3)).astype(float)  # integer rewards: many ties
    theta_hat = rng.integers(-1, 2, size=(3, 3)).astype(float)
    model = MaxEnt(phase, np.broadcast_to(PHI, (3, *PHI.shape)), rationality)
    got_regret = regret(model, theta, theta_hat)
    got_kl = trajectory_kl(model, theta, theta_hat)
    starts = [s for s in range(WIDTH * HEIGHT) if s != GOAL]
    np.testing.assert_array_equal(np.flatnonzero(phase.starts), starts)
    for b in range(3):
        true, planned = PHI @ theta[b], PHI @ theta_hat[b]
        gaps, divergences = [], []
        for s in starts:
            best = bf.best_episode_value(table, true, s, horizon, (GOAL,))
            gaps.append(best - bf.shared_policy_value(table, true, planned, s, horizon, (GOAL,)))
            counts = bf.episode_counts(bf.episode_paths(table, s, horizon, (GOAL,)), PHI)
            logp = bf.path_log_probs(counts, theta[b], rationality)
            logq = bf.path_log_probs(counts, theta_hat[b], rationality)
            divergences.append(math.fsum(np.exp(logp) * (logp - logq)))
        assert got_regret[b] == pytest.approx(math.fsum(gaps) / len(gaps), abs=1e-12)
        assert got_kl[b] == pytest.approx(math.fsum(divergences) / len(starts), rel=1e-8, abs=1e-10)


@pytest.mark.parametrize("rationality", [1e-4, 1e-1, 1.0, 10.0, 1e2, 1e4])
def test_the_map_estimate_of_a_goal_demonstration_maximises_the_enumerated_likelihood(
    rationality: float,
) -> None:
    """The MAP in the box. A certified fit (``converged``) satisfies the optimality conditions
    of the enumerated log-likelihood (each coordinate free with zero slope, or at a bound
    pushed outward); every fit reports the enumerated likelihood at its estimate, and none is
    beaten by a bounded quasi-Newton search of the enumerated likelihood. (A demonstration on
    a face of the counts' hull has its supremum at the box's edge, flat to rounding at large
    lambda: such a fit is not certified, and the docs say so.) Seven moves: the goal is five
    away, so paths of five and seven moves both reach it and the step count varies."""
    horizon = 7
    phase = _phase(horizon, False)
    paths = bf.episode_paths(_table(False), START, horizon, (GOAL,))
    counts = bf.episode_counts(paths, PHI)
    demos = [paths[0], paths[len(paths) // 2], paths[-1]]
    padded = np.array([list(p) + [phase.sink] * (horizon + 1 - len(p)) for p in demos])
    model = MaxEnt(phase, np.broadcast_to(PHI, (3, *PHI.shape)), rationality)
    fit = map_estimate(model, padded)
    if rationality <= 10:
        assert fit.converged.all()
    for b, demo in enumerate(demos):
        theta = fit.theta_hat[b]
        demo_counts = PHI[list(demo[1:])].sum(axis=0)

        def log_likelihood(point, demo_counts=demo_counts):
            return rationality * point @ demo_counts - bf.logsumexp(rationality * counts @ point)

        assert fit.log_likelihood[b] == pytest.approx(log_likelihood(theta), abs=1e-9)
        rival = minimize(
            lambda point: -log_likelihood(point), np.zeros(3), method="L-BFGS-B",
            bounds=[(-1, 1)] * 3,
        )  # fmt: skip
        assert fit.log_likelihood[b] >= -rival.fun - 1e-9
        if not fit.converged[b]:
            continue
        scores = rationality * counts @ theta
        p = np.exp(scores - bf.logsumexp(scores))
        slope = demo_counts - p @ counts
        for k in range(3):
            if -1 < theta[k] < 1:
                assert abs(slope[k]) < 1e-6 * (1 + np.abs(counts).max())
            else:
                assert slope[k] * np.sign(theta[k]) >= -1e-6
