"""The gridworld (docs/design.md §1) against the independent reference in ``path_enumeration``."""

import numpy as np
import path_enumeration as bf
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cirl_study.core.gridworld import (
    ACTION_STEPS,
    ACTIONS,
    Gridworld,
    action_between,
    paths_actions,
    paths_cells,
    rbf_features,
)

sides = st.integers(1, 7)


def test_action_order_and_steps_follow_the_contract():
    assert ACTIONS == bf.ACTIONS
    assert tuple(ACTION_STEPS) == tuple(bf.STEPS[name] for name in bf.ACTIONS)


def test_successors_of_a_3x2_grid_written_out_by_hand():
    # cells: 0=[0,0] 1=[1,0] 2=[2,0] / 3=[0,1] 4=[1,1] 5=[2,1]; columns stay, N, S, E, W
    expected = [
        [0, 3, -1, 1, -1],
        [1, 4, -1, 2, 0],
        [2, 5, -1, -1, 1],
        [3, -1, 0, 4, -1],
        [4, -1, 1, 5, 3],
        [5, -1, 2, -1, 4],
    ]
    np.testing.assert_array_equal(Gridworld(3, 2).successors, expected)
    np.testing.assert_array_equal(bf.move_table(3, 2), expected)


@given(width=sides, height=sides)
@settings(max_examples=40, deadline=None)
def test_successors_equal_reference(width, height):
    grid = Gridworld(width, height)
    assert grid.num_cells == width * height
    np.testing.assert_array_equal(grid.successors, bf.move_table(width, height))


@given(width=sides, height=sides, data=st.data())
@settings(max_examples=40, deadline=None)
def test_index_and_coords_round_trip(width, height, data):
    grid = Gridworld(width, height)
    x = data.draw(st.integers(0, width - 1))
    y = data.draw(st.integers(0, height - 1))
    assert grid.index(x, y) == bf.cell(width, x, y)
    assert grid.coords(bf.cell(width, x, y)) == (x, y)
    np.testing.assert_array_equal(grid.cell_coordinates()[grid.index(x, y)], [x, y])


@pytest.mark.parametrize("x, y", [(-1, 0), (0, -1), (4, 0), (0, 3)])
def test_index_outside_the_grid_is_refused(x, y):
    assert not Gridworld(4, 3).contains(x, y)
    with pytest.raises(ValueError):
        Gridworld(4, 3).index(x, y)


@given(width=sides, height=sides, x=st.integers(-3, 9), y=st.integers(-3, 9))
@settings(max_examples=80, deadline=None)
def test_contains_equals_the_reference_cells(width, height, x, y):
    grid = Gridworld(width, height)
    on_grid = {bf.xy(width, s) for s in range(width * height)}
    assert grid.contains(x, y) == ((x, y) in on_grid)
    if grid.contains(x, y):
        assert grid.index(x, y) == bf.cell(width, x, y)
    else:
        with pytest.raises(ValueError):
            grid.index(x, y)


@pytest.mark.parametrize("width, height", [(3, 3), (4, 2), (1, 3), (1, 1)])
def test_action_between_equals_the_reference_moves(width, height):
    # Every ordered pair of cells: the action is the reference's unique move between them, if any.
    for here in range(width * height):
        for there in range(width * height):
            moves = [a for a in bf.ACTIONS if bf.move(width, height, here, a) == there]
            assert len(moves) <= 1
            got = action_between(bf.xy(width, here), bf.xy(width, there))
            assert got == (moves[0] if moves else None), (here, there)


@given(
    cell=st.tuples(st.integers(-5, 5), st.integers(-5, 5)),
    step=st.tuples(st.integers(-2, 2), st.integers(-2, 2)),
)
@settings(max_examples=80, deadline=None)
def test_action_between_reads_the_step_whatever_the_grid(cell, step):
    # The relation knows no grid: any two cells one reference step apart (or equal) give its name.
    names = [name for name in bf.ACTIONS if bf.STEPS[name] == step]
    following = (cell[0] + step[0], cell[1] + step[1])
    assert action_between(cell, following) == (names[0] if names else None)
    assert action_between(list(cell), list(following)) == action_between(cell, following)


@given(
    width=sides,
    height=sides,
    centers=st.lists(st.tuples(st.floats(-2, 9), st.floats(-2, 9)), min_size=1, max_size=5),
    sigma=st.floats(0.2, 5.0),
)
@settings(max_examples=40, deadline=None)
def test_rbf_features_equal_reference(width, height, centers, sigma):
    got = rbf_features(Gridworld(width, height), centers, sigma)
    want = bf.rbf_features(width, height, centers, sigma)
    assert got.shape == (width * height, len(centers))
    # exp(-x) carries x times the relative error of x: compare exponents, away from underflow
    normal = want > 1e-290
    np.testing.assert_allclose(np.log(got[normal]), np.log(want[normal]), rtol=1e-14, atol=1e-14)
    assert np.all(got[~normal] < 1e-280)


def test_rbf_features_batch_matches_one_at_a_time():
    rng = np.random.default_rng(7)
    grid = Gridworld(5, 4)
    centers = rng.uniform(0, 4, size=(3, 6, 2))
    got = rbf_features(grid, centers, 1.7)
    assert got.shape == (3, 20, 6)
    for b in range(3):
        np.testing.assert_allclose(got[b], bf.rbf_features(5, 4, centers[b], 1.7), rtol=1e-13)


def test_rbf_feature_is_one_at_its_center_and_decays():
    phi = rbf_features(Gridworld(5, 5), [[2.0, 3.0]], 1.0)[:, 0]
    assert phi[bf.cell(5, 2, 3)] == 1.0
    assert phi[bf.cell(5, 3, 3)] == pytest.approx(np.exp(-0.5), rel=1e-15)
    assert phi[bf.cell(5, 4, 4)] == pytest.approx(np.exp(-2.5), rel=1e-15)


@pytest.mark.parametrize(
    "width, height, start, horizon", [(3, 3, 4, 4), (4, 2, 0, 4), (1, 3, 1, 3)]
)
def test_every_path_round_trips_through_its_actions(width, height, start, horizon):
    grid = Gridworld(width, height)
    paths = bf.enumerate_paths(width, height, start, horizon)
    seen = set()
    for states in paths:
        (moves,) = paths_actions(grid, np.array([states], dtype=np.int64))
        actions = list(moves)
        assert len(actions) == horizon
        walked = [start]
        for name in actions:
            walked.append(bf.move(width, height, walked[-1], name))
        assert walked == list(states)
        cells = [bf.xy(width, s) for s in states]
        assert [action_between(a, b) for a, b in zip(cells[:-1], cells[1:], strict=True)] == actions
        seen.add(tuple(actions))
    assert len(seen) == len(paths) == bf.count_paths(width, height, start, horizon)


@pytest.mark.parametrize(
    "width, height, start, horizon", [(3, 3, 4, 4), (4, 2, 0, 4), (1, 3, 1, 3)]
)
def test_a_batch_of_paths_gives_each_paths_cells_and_actions(width, height, start, horizon):
    grid = Gridworld(width, height)
    paths = np.array(bf.enumerate_paths(width, height, start, horizon), dtype=np.int64)
    cells, actions = paths_cells(grid, paths), paths_actions(grid, paths)
    for states, path_cells, path_moves in zip(paths, cells, actions, strict=True):
        assert path_cells == tuple(bf.xy(width, s) for s in states)
        assert path_moves == tuple(
            action_between(a, b) for a, b in zip(path_cells[:-1], path_cells[1:], strict=True)
        )
    if width >= 3:  # the second path jumps two cells
        jump = np.array([[0, 0], [grid.index(0, 0), grid.index(2, 0)]], dtype=np.int64)
        with pytest.raises(ValueError, match="cells 0 and 2 are not one move apart"):
            paths_actions(grid, jump)


# ---- the reference itself -------------------------------------------------------------------


@pytest.mark.parametrize(
    "width, height, start, horizon", [(4, 4, 5, 5), (3, 5, 7, 4), (1, 1, 0, 3)]
)
def test_reference_enumerations_agree(width, height, start, horizon):
    listed = bf.enumerate_paths(width, height, start, horizon)
    stacked = bf.enumerate_paths_array(width, height, start, horizon)
    np.testing.assert_array_equal(stacked, np.array(listed))
    assert len(set(listed)) == len(listed) == bf.count_paths(width, height, start, horizon)
    assert all(bf.is_path(width, height, p, start, horizon) for p in listed)
    features = np.random.default_rng(0).random((width * height, 3))
    np.testing.assert_array_equal(
        bf.feature_counts_fast(width, height, start, horizon, features),
        bf.feature_counts(listed, features),
    )


def test_reference_path_count_at_the_paper_size():
    # 10 x 10, 9 steps from the center [5, 5]: fewer than 5^9 because of the border.
    assert bf.count_paths(10, 10, bf.cell(10, 5, 5), 9) == 1_910_313 < 5**9
    assert bf.count_paths(10, 10, bf.cell(10, 5, 5), 4) == 5**4


def test_reference_rejects_non_paths():
    assert not bf.is_path(3, 3, [0, 2], 0, 1)  # two cells apart
    assert not bf.is_path(3, 3, [0, 1], 1, 1)  # wrong start
    assert not bf.is_path(3, 3, [0, 1, 2], 0, 1)  # wrong length
    assert bf.is_path(3, 3, [0, 0, 1], 0, 2)
