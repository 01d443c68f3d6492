"""Soft and hard planning (docs/design.md §2 and §4) against brute-force path enumeration."""

import numpy as np
import path_enumeration as bf
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cirl_study.core.planning import (
    follow_policy,
    future_feature_counts,
    optimal_plan,
    reachable_cells,
    rollout,
    shared_policy_values,
    soft_value_iteration,
    state_visitation,
)

RATIONALITIES = (1e-4, 1.0, 1e3)
GRIDS = ((4, 4), (3, 5))


def _random_game(width, height, num_features, seed):
    """Random RBF features and a few reward vectors theta in the box."""
    rng = np.random.default_rng(seed)
    centers = rng.uniform([0, 0], [width - 1, height - 1], size=(num_features, 2))
    features = bf.rbf_features(width, height, centers, rng.uniform(0.8, 2.5))
    thetas = rng.uniform(-1, 1, size=(3, num_features))
    return features, thetas


def _path_log_prob(log_policy, b, path, table):
    """``sum_t log pi_t(a_t | s_t)`` of one path under batch member ``b``."""
    total = 0.0
    for t, (here, there) in enumerate(zip(path[:-1], path[1:], strict=True)):
        action = int(np.flatnonzero(table[here] == there)[0])
        total += log_policy[t, b, here, action]
    return total


def _tolerance(rationality):
    """Absolute tolerance for log-probabilities whose terms are of size ``lambda * T``."""
    return 1e-10 * max(1.0, rationality)


@pytest.mark.parametrize("width, height", GRIDS)
@pytest.mark.parametrize("rationality", RATIONALITIES)
def test_log_partition_equals_enumeration_from_every_start(width, height, rationality):
    features, thetas = _random_game(width, height, 3, seed=width * 10 + height)
    table = bf.move_table(width, height)
    horizon = 5 if rationality == 1.0 else 4
    plan = soft_value_iteration(thetas @ features.T, table, horizon, rationality)
    assert plan.values.shape == (horizon + 1, len(thetas), width * height)
    np.testing.assert_array_equal(plan.values[horizon], 0.0)
    for s in range(width * height):
        counts = bf.feature_counts(bf.enumerate_paths(width, height, s, horizon), features)
        for b, theta in enumerate(thetas):
            want = bf.log_partition(counts, theta, rationality)
            got = plan.values[0][b, s]
            assert got == pytest.approx(want, rel=1e-12, abs=_tolerance(rationality))


@pytest.mark.parametrize("width, height", GRIDS)
@pytest.mark.parametrize("rationality", RATIONALITIES)
@pytest.mark.parametrize("horizon", [1, 3, 5])
def test_path_probabilities_equal_enumeration(width, height, rationality, horizon):
    features, thetas = _random_game(width, height, 4, seed=horizon)
    table = bf.move_table(width, height)
    start = bf.cell(width, 1, 2)
    plan = soft_value_iteration(thetas @ features.T, table, horizon, rationality)
    paths = bf.enumerate_paths(width, height, start, horizon)
    counts = bf.feature_counts(paths, features)
    for b, theta in enumerate(thetas):
        want = bf.path_log_probs(counts, theta, rationality)
        got = np.array([_path_log_prob(plan.log_policy, b, p, table) for p in paths])
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=_tolerance(rationality))
        np.testing.assert_allclose(np.exp(got), np.exp(want), rtol=1e-9, atol=1e-14)
    # unavailable moves carry no probability, available ones all of it
    np.testing.assert_array_equal(
        np.isneginf(plan.log_policy), np.broadcast_to(table < 0, plan.log_policy.shape)
    )
    np.testing.assert_allclose(plan.policy.sum(axis=-1), 1.0, rtol=1e-12)


def test_zero_reward_gives_the_uniform_path_distribution():
    table = bf.move_table(3, 4)
    plan = soft_value_iteration(np.zeros((1, 12)), table, 5, 1.0)
    for s in range(12):
        assert plan.values[0][0, s] == pytest.approx(np.log(bf.count_paths(3, 4, s, 5)), rel=1e-14)


def test_soft_values_survive_extreme_rationality():
    features, thetas = _random_game(4, 4, 3, seed=3)
    for rationality in (1e-8, 1e5):
        plan = soft_value_iteration(thetas @ features.T, bf.move_table(4, 4), 5, rationality)
        assert np.isfinite(plan.values).all()
        assert np.isfinite(plan.policy).all()


@pytest.mark.parametrize("rationality", RATIONALITIES)
def test_state_visitation_equals_enumerated_occupancy(rationality):
    width, height, horizon = 4, 4, 4
    features, thetas = _random_game(width, height, 3, seed=11)
    table = bf.move_table(width, height)
    plan = soft_value_iteration(thetas @ features.T, table, horizon, rationality)
    start = bf.cell(width, 2, 1)
    point = np.zeros((len(thetas), width * height))
    point[:, start] = 1.0
    got = state_visitation(plan.policy, table, point)
    paths = np.array(bf.enumerate_paths(width, height, start, horizon))
    counts = bf.feature_counts(paths, features)
    for b, theta in enumerate(thetas):
        want = bf.occupancy(paths, bf.path_log_probs(counts, theta, rationality), width * height)
        np.testing.assert_allclose(got[:, b], want, rtol=1e-9, atol=1e-13)
    np.testing.assert_allclose(got.sum(axis=-1), 1.0, rtol=1e-12)


def test_state_visitation_from_a_uniform_start_is_the_mean_of_point_starts():
    width, height, horizon = 3, 3, 3
    features, thetas = _random_game(width, height, 2, seed=5)
    table = bf.move_table(width, height)
    plan = soft_value_iteration(thetas[:1] @ features.T, table, horizon, 1.0)
    uniform = np.full((1, 9), 1 / 9)
    got = state_visitation(plan.policy, table, uniform)[:, 0]
    want = np.zeros_like(got)
    for s in range(9):
        paths = np.array(bf.enumerate_paths(width, height, s, horizon))
        logp = bf.path_log_probs(bf.feature_counts(paths, features), thetas[0], 1.0)
        want += bf.occupancy(paths, logp, 9) / 9
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-14)


@pytest.mark.parametrize("rationality", RATIONALITIES)
def test_expected_future_counts_equal_enumeration(rationality):
    width, height, horizon = 3, 5, 4
    features, thetas = _random_game(width, height, 3, seed=2)
    table = bf.move_table(width, height)
    plan = soft_value_iteration(thetas @ features.T, table, horizon, rationality)
    batch_features = np.broadcast_to(features, (len(thetas), *features.shape))
    future = future_feature_counts(plan.policy, table, batch_features)
    assert future.shape == (horizon + 1, len(thetas), width * height, 3)
    np.testing.assert_array_equal(future[horizon], 0.0)
    for s in range(width * height):
        counts = bf.feature_counts(bf.enumerate_paths(width, height, s, horizon), features)
        for b, theta in enumerate(thetas):
            want = bf.expected_features(counts, theta, rationality)
            np.testing.assert_allclose(future[0][b, s], want, rtol=1e-10, atol=1e-13)


@pytest.mark.parametrize("width, height", GRIDS)
@pytest.mark.parametrize("horizon", [1, 2, 5])
def test_optimal_plan_equals_enumeration(width, height, horizon):
    features, thetas = _random_game(width, height, 5, seed=horizon + width)
    table = bf.move_table(width, height)
    plan = optimal_plan(thetas @ features.T, table, horizon)
    assert plan.actions.shape == (horizon, len(thetas), width * height)
    for b, theta in enumerate(thetas):
        best = bf.optimal_values(width, height, features, theta, horizon)
        np.testing.assert_allclose(plan.values[0][b], best, rtol=1e-13, atol=1e-13)
        for s in range(width * height):
            achieved = bf.policy_value(width, height, features, theta, plan.actions[:, b], s)
            assert achieved == pytest.approx(best[s], rel=1e-13, abs=1e-13)
        np.testing.assert_array_equal(
            plan.actions[:, b], bf.greedy_actions(width, height, features, theta, horizon)
        )


@given(
    width=st.integers(1, 4),
    height=st.integers(2, 4),
    horizon=st.integers(1, 4),
    data=st.data(),
)
@settings(max_examples=30, deadline=None)
def test_optimal_plan_breaks_exact_ties_by_the_lowest_action(width, height, horizon, data):
    # Small integer rewards: every sum is exact, so ties are real and must go to the lowest index.
    cells = width * height
    rewards = np.array(data.draw(st.lists(st.integers(0, 2), min_size=cells, max_size=cells)))
    plan = optimal_plan(rewards[None].astype(float), bf.move_table(width, height), horizon)
    want = bf.greedy_actions(width, height, np.eye(cells), rewards, horizon)
    np.testing.assert_array_equal(plan.actions[:, 0], want)


def test_optimal_plan_of_a_constant_reward_always_stays():
    plan = optimal_plan(np.ones((2, 12)), bf.move_table(4, 3), 3)
    np.testing.assert_array_equal(plan.actions, 0)


@given(width=st.integers(1, 3), height=st.integers(2, 3), horizon=st.integers(1, 3), data=st.data())
@settings(max_examples=30, deadline=None)
def test_shared_policy_values_equal_the_enumerated_tie_sharing_policy(width, height, horizon, data):
    """Rewards in {0, 1} tie often: the value of the policy that shares ties is the average
    over every path the tie tree allows, weighted by its probability, found by enumeration."""
    cells = width * height
    table = bf.move_table(width, height)
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    planned = rng.integers(0, 2, size=(2, cells)).astype(float)
    true = rng.normal(size=(2, cells))
    got = shared_policy_values(true, planned, table, horizon)
    for b in range(2):
        for s in range(cells):
            want = bf.shared_policy_value(table, true[b], planned[b], s, horizon, ())
            assert got[b, s] == pytest.approx(want, rel=1e-12, abs=1e-12)


def test_shared_policy_values_do_not_depend_on_the_order_of_the_actions():
    rng = np.random.default_rng(3)
    table = bf.move_table(4, 3)
    planned = rng.integers(0, 2, size=(3, 12)).astype(float)
    true = rng.normal(size=(3, 12))
    values = shared_policy_values(true, planned, table, 4)
    for order in ([4, 3, 2, 1, 0], [2, 0, 4, 1, 3]):
        np.testing.assert_allclose(
            shared_policy_values(true, planned, table[:, order], 4), values, rtol=1e-13
        )
    # The first of tied actions, which the rollouts follow, does depend on it.
    first = optimal_plan(planned, table, 4).actions
    assert not np.array_equal(optimal_plan(planned, table[:, [4, 3, 2, 1, 0]], 4).actions, first)


# ---- following actions and policies ----------------------------------------------------------


@pytest.mark.parametrize(
    "width, height, start, horizon", [(3, 3, 4, 4), (4, 2, 0, 4), (1, 3, 1, 3)]
)
def test_rollout_of_every_action_sequence_is_its_reference_path(width, height, start, horizon):
    paths = np.array(bf.enumerate_paths(width, height, start, horizon))
    table = bf.move_table(width, height)
    actions = np.array(
        [
            [int(np.flatnonzero(table[a] == b)[0]) for a, b in zip(p[:-1], p[1:], strict=True)]
            for p in paths
        ]
    )
    np.testing.assert_array_equal(rollout(table, start, actions), paths)


def test_rollout_refuses_an_action_sequence_that_leaves_the_grid():
    table = bf.move_table(3, 3)
    with pytest.raises(ValueError):
        rollout(table, bf.cell(3, 2, 2), np.array([[0, 3]]))  # stay, then E off the edge


@given(width=st.integers(1, 4), height=st.integers(2, 4), horizon=st.integers(1, 4), data=st.data())
@settings(max_examples=30, deadline=None)
def test_follow_policy_equals_the_reference_rollout(width, height, horizon, data):
    cells = width * height
    table = bf.move_table(width, height)
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    policy = (rng.random((horizon, 3, cells, 5)) * (table >= 0)).argmax(axis=-1)
    starts = rng.integers(cells, size=3)
    paths = follow_policy(table, starts, policy)
    assert paths.shape == (3, horizon + 1)
    rewards = rng.normal(size=cells)
    for b in range(3):
        want = [int(starts[b])]
        for t in range(horizon):
            want.append(bf.move(width, height, want[-1], bf.ACTIONS[policy[t, b, want[-1]]]))
        np.testing.assert_array_equal(paths[b], want)
        value = bf.policy_value(width, height, np.eye(cells), rewards, policy[:, b], want[0])
        assert rewards[paths[b, 1:]].sum() == pytest.approx(value, rel=1e-13, abs=1e-13)


@pytest.mark.parametrize(
    "width, height, start, horizon", [(4, 4, 5, 4), (3, 5, 0, 3), (1, 3, 1, 3), (1, 1, 0, 2)]
)
def test_reachable_cells_equal_the_cells_of_enumerated_paths(width, height, start, horizon):
    got = reachable_cells(bf.move_table(width, height), start, horizon)
    want = np.zeros((horizon + 1, width * height), dtype=bool)
    for path in bf.enumerate_paths(width, height, start, horizon):
        want[np.arange(horizon + 1), list(path)] = True
    np.testing.assert_array_equal(got, want)


# ---- the references can tell right from wrong ----------------------------------------------


def test_reference_log_partition_notices_a_counted_start_cell():
    features, thetas = _random_game(4, 4, 3, seed=1)
    start = 5
    paths = np.array(bf.enumerate_paths(4, 4, start, 3))
    right = bf.log_partition(bf.feature_counts(paths, features), thetas[0], 1.0)
    counted = bf.feature_counts(paths, features) + features[start]
    wrong = bf.log_partition(counted, thetas[0], 1.0)
    assert abs(right - wrong) == pytest.approx(abs(features[start] @ thetas[0]), rel=1e-12)
    assert abs(right - wrong) > 1e-3


def test_reference_policy_value_notices_a_suboptimal_policy():
    features, thetas = _random_game(4, 4, 3, seed=4)
    best = bf.optimal_values(4, 4, features, thetas[0], 3)
    stay = np.zeros((3, 16), dtype=np.int64)
    gaps = [best[s] - bf.policy_value(4, 4, features, thetas[0], stay, s) for s in range(16)]
    assert min(gaps) >= -1e-12
    assert max(gaps) > 1e-2
