"""The demonstration's count class (``MaxEnt.demonstration_classes``) against brute force.

The references share no code with the package: every path of a small successor table is
listed by a depth-first walk, the class is the paths whose cells carry the demonstration's
multiset of feature rows, and a path outside it leaves at the first step where its prefix is
no class path's prefix; the exits are those prefixes grouped by step, cell and the multiset of
rows before the last cell, their number the multiplicity. Large classes are counted by a
memoised recursion over (cell, rows still to take) in exact integers.
"""

import dataclasses
import functools
import math
import time

import mpmath
import numpy as np
import path_enumeration as bf
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cirl_study.core.maxent import DemonstrationClass, MaxEnt, Phase, _demonstration_classes
from cirl_study.core.robot import map_estimate

# ---- references -----------------------------------------------------------------------------


def _paths(table, start, horizon, needed=None):
    """Every path of ``horizon`` moves from ``start`` on the successor ``table`` (and, given
    ``needed``, in a cell it marks at every step), depth first in action order."""
    found = []

    def walk(path):
        if needed is not None and not needed[len(path) - 1, path[-1]]:
            return
        if len(path) == horizon + 1:
            found.append(tuple(path))
            return
        for nxt in table[path[-1]]:
            if nxt >= 0:
                walk([*path, int(nxt)])

    walk([start])
    return found


def _rows(features, cells):
    """The multiset of the feature rows of ``cells``, as a sorted tuple."""
    return tuple(sorted(tuple(features[c].tolist()) for c in cells))


@dataclasses.dataclass
class _Brute:
    members: int
    exits: dict  # (step, cell, rows before the cell) -> (multiplicity, shift)
    paths: int


def _brute_class(table, start, horizon, features, demo, needed=None):
    """The class and its exits by listing every path."""
    paths = _paths(table, start, horizon, needed)
    key = _rows(features, demo[1:])
    members = [p for p in paths if _rows(features, p[1:]) == key]
    prefixes = {p[:t] for p in members for t in range(1, horizon + 2)}
    demo_counts = [math.fsum(features[c, i] for c in demo[1:]) for i in range(features.shape[1])]
    grouped = {}
    for p in paths:
        if p in prefixes:
            continue
        t = next(t for t in range(1, horizon + 1) if p[: t + 1] not in prefixes)
        group = grouped.setdefault((t, p[t], _rows(features, p[1:t])), set())
        group.add(p[: t + 1])
    exits = {}
    for (t, cell, rows), group in grouped.items():
        prefix = next(iter(group))
        shift = [
            math.fsum([*(features[c, i] for c in prefix[1:]), -demo_counts[i]])
            for i in range(features.shape[1])
        ]
        exits[(t, cell, rows)] = (len(group), np.array(shift))
    return _Brute(len(members), exits, len(paths))


def _exact_class_size(table, start, demo, features):
    """The number of class paths in exact integers, by recursion over (cell, rows to take)."""
    rows = [tuple(r) for r in features.tolist()]
    need = {}
    for c in demo[1:]:
        need[rows[c]] = need.get(rows[c], 0) + 1
    kinds = sorted(need)

    @functools.cache
    def completions(cell, left):
        if not any(left):
            return 1
        total = 0
        for nxt in table[cell]:
            if nxt >= 0 and rows[nxt] in need:
                j = kinds.index(rows[nxt])
                if left[j]:
                    total += completions(int(nxt), (*left[:j], left[j] - 1, *left[j + 1 :]))
        return total

    return completions(start, tuple(need[k] for k in kinds))


def _completions(table, horizon, needed=None):
    """``[t][s]``: the number of ways to make the moves after step ``t`` from ``s`` (exact)."""
    cells = len(table)
    ways = [[0] * cells for _ in range(horizon + 1)]
    ways[horizon] = [1] * cells
    for t in range(horizon - 1, -1, -1):
        for s in range(cells):
            ways[t][s] = sum(
                ways[t + 1][int(n)]
                for n in table[s]
                if n >= 0 and (needed is None or needed[t + 1, n])
            )
    return ways


def _through_exits(classes, ways):
    """The number of paths through trial 0's exits: multiplicity times completions."""
    return sum(
        int(m) * ways[int(t)][int(c)]
        for t, c, m in zip(classes.step, classes.cell, _multiplicities(classes), strict=True)
    )


def _multiplicities(classes, b=0):
    """Trial ``b``'s exit multiplicities as integers (the counts are exact here)."""
    part = slice(classes.offsets[b], classes.offsets[b + 1])
    counts = np.exp(classes.log_multiplicity[part])
    np.testing.assert_allclose(counts, np.rint(counts), rtol=1e-13)
    return np.rint(counts).astype(np.int64)


def _check_against_brute(classes, brute, b=0, features=None):
    """Members, and the exits (step, cell, shift, multiplicity) one to one with the reference."""
    assert classes.members[b] == brute.members
    part = slice(classes.offsets[b], classes.offsets[b + 1])
    mine = sorted(
        (int(t), int(c), tuple(s), int(m))
        for t, c, s, m in zip(
            classes.step[part],
            classes.cell[part],
            classes.shift[part].tolist(),
            _multiplicities(classes, b),
            strict=True,
        )
    )
    theirs = sorted(
        (t, c, tuple(shift.tolist()), m) for (t, c, _), (m, shift) in brute.exits.items()
    )
    assert len(mine) == len(theirs)
    for (t, c, s, m), (t2, c2, s2, m2) in zip(mine, theirs, strict=True):
        assert (t, c, m) == (t2, c2, m2)
        np.testing.assert_allclose(s, s2, rtol=0, atol=1e-12)


def _tile_features(rng, cells, kinds, k, *, zero=False):
    """``(S, K)`` rows drawn from ``kinds`` random rows (the first all zeros if ``zero``)."""
    pool = rng.uniform(0, 1, size=(kinds, k))
    if zero:
        pool[0] = 0.0
    return pool[rng.integers(kinds, size=cells)]


# ---- against brute force --------------------------------------------------------------------


@st.composite
def _games(draw):
    width = draw(st.integers(1, 4))
    height = draw(st.integers(1 if width > 1 else 2, 3))
    horizon = draw(st.integers(0, 5 if width * height <= 6 else 4))
    start = draw(st.integers(0, width * height - 1))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    k = draw(st.integers(1, 3))
    if draw(st.booleans()):
        features = _tile_features(
            rng, width * height, draw(st.integers(1, 3)), k, zero=draw(st.booleans())
        )
    else:
        centers = rng.uniform([0, 0], [width - 1, height - 1], size=(k, 2))
        features = bf.rbf_features(width, height, centers, rng.uniform(0.5, 2.0))
    table = bf.move_table(width, height)
    paths = _paths(table, start, horizon)
    # A drawn path, or the first one: staying put throughout.
    demo = paths[draw(st.integers(0, len(paths) - 1))] if draw(st.booleans()) else paths[0]
    return width, height, start, horizon, features, table, np.array(demo)


@given(game=_games())
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_the_class_and_its_exits_equal_brute_force(game):
    # Every path is in the class or leaves it at exactly one exit: the exits' multiplicities
    # times their completions, plus the members, are all the paths.
    width, height, start, horizon, features, table, demo = game
    model = MaxEnt(Phase(table, start, horizon), features[None], 1.0)
    classes = model.demonstration_classes(demo[None])
    brute = _brute_class(table, start, horizon, features, demo)
    _check_against_brute(classes, brute)
    assert classes.members.dtype == np.float64
    through_exits = _through_exits(classes, _completions(table, horizon))
    assert through_exits + int(classes.members[0]) == brute.paths


def _reference_moments(paths, features, demo, theta, rationality):
    """``(log R, E_q[Delta], Cov_q[Delta])`` over the paths outside the class, in 50 digits."""
    key = _rows(features, demo[1:])
    k = features.shape[1]
    with mpmath.workdps(50):
        phi = [[mpmath.mpf(float(x)) for x in row] for row in features]
        demo_counts = [mpmath.fsum(phi[c][i] for c in demo[1:]) for i in range(k)]
        deltas = [
            [mpmath.fsum(phi[c][i] for c in p[1:]) - demo_counts[i] for i in range(k)]
            for p in paths
            if _rows(features, p[1:]) != key
        ]
        scores = [
            rationality
            * mpmath.fsum(mpmath.mpf(float(t)) * d for t, d in zip(theta, row, strict=True))
            for row in deltas
        ]
        top = max(scores)
        weights = [mpmath.exp(s - top) for s in scores]
        total = mpmath.fsum(weights)
        q = [w / total for w in weights]
        mean = [
            mpmath.fsum(qi * row[i] for qi, row in zip(q, deltas, strict=True)) for i in range(k)
        ]
        covariance = [
            [
                mpmath.fsum(
                    qi * (row[i] - mean[i]) * (row[j] - mean[j])
                    for qi, row in zip(q, deltas, strict=True)
                )
                for j in range(k)
            ]
            for i in range(k)
        ]
        return (
            float(top + mpmath.log(total)),
            np.array([float(x) for x in mean]),
            np.array([[float(x) for x in row] for row in covariance]),
        )


@pytest.mark.parametrize("rationality", [1e-4, 1e-2, 1.0, 1e2, 1e4])
@pytest.mark.parametrize("walk", ["back and forth", "stays", "drawn"])
@pytest.mark.parametrize("kind", ["tile", "rbf"])
def test_off_demonstration_equals_the_high_precision_sum(kind, walk, rationality):
    # log R, E_q[Delta] and Cov_q[Delta] against 50 digits path by path, on tiles of three
    # rows (one of them zero: many ties) and on RBF features, for a walk back and forth, one
    # that stays put and a drawn path. The exits' log weights are of size lambda T max|r| and
    # rounded to eps of that, so the weights q_e sum to 1 only to about eps lambda T: the mean
    # is exact to that relative rounding, and the covariance relative to the variances down
    # to its square (the floor of the deviations mu_e - E_q[Delta]).
    width, height, start, horizon, k = 3, 3, 4, 5, 3
    rng = np.random.default_rng(["tile", "rbf"].index(kind))
    if kind == "tile":
        features = _tile_features(rng, width * height, 3, k, zero=True)
    else:
        features = bf.rbf_features(width, height, rng.uniform(0, 2, size=(k, 2)), 1.2)
    table = bf.move_table(width, height)
    paths = _paths(table, start, horizon)
    demo = {
        "back and forth": (4, 5, 4, 5, 4, 1),
        "stays": (4, 4, 7, 7, 4, 4),
        "drawn": paths[int(rng.integers(len(paths)))],
    }[walk]
    theta = rng.uniform(-1, 1, size=(1, k))
    model = MaxEnt(Phase(table, start, horizon), features[None], rationality)
    classes = model.demonstration_classes(np.array([demo]))
    off = model.off_demonstration(theta, classes)
    log_mass, mean, covariance = _reference_moments(paths, features, demo, theta[0], rationality)
    assert off.log_mass[0] == pytest.approx(log_mass, rel=1e-12, abs=1e-12)
    rounding = 8 * np.finfo(float).eps * (1 + rationality) * horizon * np.abs(features).max()
    size = max(1.0, np.abs(mean).max())
    np.testing.assert_allclose(off.mean[0], mean, rtol=0, atol=max(1e-12, rounding) * size)
    scale = np.sqrt(np.outer(np.diag(covariance), np.diag(covariance)))
    floor = (rounding * size) ** 2
    np.testing.assert_array_less(np.abs(off.covariance[0] - covariance), 1e-9 * scale + floor)


def test_the_exits_carry_their_multiplicities():
    # On tiles many prefixes leave through one exit; dropping its multiplicity (counting it
    # once) gives another R, not the brute-force one.
    width, height, start, horizon, k = 3, 3, 4, 5, 2
    features = _tile_features(np.random.default_rng(3), width * height, 2, k)
    table = bf.move_table(width, height)
    demo = np.array([4, 5, 4, 5, 4, 1])
    model = MaxEnt(Phase(table, start, horizon), features[None], 1.0)
    classes = model.demonstration_classes(demo[None])
    assert classes.log_multiplicity.max() > math.log(2)
    theta = np.array([[0.7, -0.4]])
    want, _, _ = _reference_moments(_paths(table, start, horizon), features, demo, theta[0], 1.0)
    assert model.off_demonstration(theta, classes).log_mass[0] == pytest.approx(want, rel=1e-12)
    dropped = dataclasses.replace(classes, log_multiplicity=np.zeros_like(classes.log_multiplicity))
    assert abs(model.off_demonstration(theta, dropped).log_mass[0] - want) > 0.1


@pytest.mark.parametrize("mask", ["goal", "knocked out"])
def test_moves_go_only_into_needed_cells(mask):
    # A goal task as fixed-length paths: entering the goal G leads to a zero-feature sink Z that
    # stays put. With "goal", a cell is needed at step t only if it is reachable then and can
    # still be in Z at step T; with "knocked out", a quarter of the reachable (step, cell) pairs
    # after the start are dropped, so that some class prefixes could go on through them. The
    # class and its exits are those of the paths that keep to the mask.
    width, height, horizon = 3, 3, 5
    goal, sink = 8, 9
    grid = bf.move_table(width, height)
    table = np.full((10, 5), -1, dtype=np.int64)
    table[:9] = grid
    table[goal] = [sink, -1, -1, -1, -1]
    table[sink] = [sink, -1, -1, -1, -1]
    rng = np.random.default_rng(5)
    features = np.vstack([_tile_features(rng, 9, 3, 2), np.zeros((1, 2))])
    start = 0
    reach = np.zeros((horizon + 1, 10), dtype=bool)
    reach[0, start] = True
    for t in range(horizon):
        for s in np.flatnonzero(reach[t]):
            for nxt in table[s]:
                if nxt >= 0:
                    reach[t + 1, nxt] = True
    if mask == "goal":
        finish = np.zeros((horizon + 1, 10), dtype=bool)
        finish[horizon, sink] = True
        for t in range(horizon - 1, -1, -1):
            for s in range(10):
                finish[t, s] = any(nxt >= 0 and finish[t + 1, nxt] for nxt in table[s])
        needed = reach & finish
    else:
        kept = rng.uniform(size=reach.shape) > 0.25
        kept[0] = True
        needed = reach & kept
    paths = _paths(table, start, horizon, needed)
    assert 0 < len(paths) < len(_paths(table, start, horizon))
    for demo in (paths[0], paths[len(paths) // 2], paths[-1]):
        got = _demonstration_classes(table, start, needed, np.array([demo]), features[None])
        classes = DemonstrationClass(*got)
        brute = _brute_class(table, start, horizon, features, demo, needed)
        _check_against_brute(classes, brute)
        assert needed[classes.step, classes.cell].all()
        through_exits = _through_exits(classes, _completions(table, horizon, needed))
        assert through_exits + int(classes.members[0]) == len(paths)


def test_codes_that_wrap_past_64_bits_still_tell_multisets_apart():
    # 67 kinds taken once each: the mixed-radix codes wrap (the radix of kinds 64.. is 2^64 =
    # 0), so the prefixes ..X Z and ..Y Z share a code at one step and cell; they are two nodes.
    chain = 65  # cells 0..64 in a row, each moving only to the next
    x, y, z = chain, chain + 1, chain + 2
    table = np.full((chain + 3, 3), -1, dtype=np.int64)
    for c in range(chain - 1):
        table[c, 0] = c + 1
    table[chain - 1, :2] = [x, y]
    table[x, :2] = [z, x]
    table[y, :2] = [z, y]
    table[z, :3] = [x, y, z]
    cells = table.shape[0]
    features = np.column_stack([np.arange(cells) / cells, (np.arange(cells) / cells) ** 2])
    horizon = chain - 1 + 3
    demo = np.array([*range(chain), x, z, y])
    model = MaxEnt(Phase(table, 0, horizon), features[None], 1.0)
    classes = model.demonstration_classes(demo[None])
    _check_against_brute(classes, _brute_class(table, 0, horizon, features, demo))
    assert classes.members[0] == 2  # ..X Z Y and ..Y Z X
    theta = np.array([[0.3, -0.8]])
    want, _, _ = _reference_moments(_paths(table, 0, horizon), features, demo, theta[0], 1.0)
    assert model.off_demonstration(theta, classes).log_mass[0] == pytest.approx(want, rel=1e-12)


# ---- large classes ---------------------------------------------------------------------------


def _tile_walk(width, height, horizon, kinds, seed):
    """One-hot tile features of ``kinds`` kinds and a random walk of ``horizon`` moves from 0."""
    rng = np.random.default_rng(seed)
    features = np.eye(kinds)[rng.integers(kinds, size=width * height)]
    table = bf.move_table(width, height)
    demo = [0]
    for _ in range(horizon):
        demo.append(int(rng.choice([c for c in table[demo[-1]] if c >= 0])))
    return table, features, np.array(demo)


def test_the_exact_count_agrees_with_brute_force_on_a_reduced_tile_case():
    # The recursion that checks the large classes below, itself checked by listing the paths.
    table, features, demo = _tile_walk(3, 3, 7, 3, seed=1)
    brute = _brute_class(table, 0, 7, features, demo)
    assert brute.members > 10
    assert _exact_class_size(table, 0, demo, features) == brute.members
    model = MaxEnt(Phase(table, 0, 7), features[None], 1.0)
    _check_against_brute(model.demonstration_classes(demo[None]), brute)


def test_a_class_of_more_than_a_trillion_paths_is_counted_at_once():
    # A 6 x 5 grid of five kinds of tiles and a 30-move walk: 5.8e14 class paths (below 2^53,
    # so counted exactly), about 1e5 nodes; the MAP fit runs on it.
    table, features, demo = _tile_walk(6, 5, 30, 5, seed=0)
    model = MaxEnt(Phase(table, 0, 30), features[None], 1.0)
    model.demonstration_classes(demo[None])  # compiled
    took = []
    for _ in range(3):
        begin = time.perf_counter()
        classes = model.demonstration_classes(demo[None])
        took.append(time.perf_counter() - begin)
    assert min(took) < 0.5
    assert classes.members[0] > 1e12
    assert classes.members[0] == _exact_class_size(table, 0, demo, features)
    ways = _completions(table, 30)
    through_exits = math.fsum(
        math.exp(m) * ways[int(t)][int(c)]
        for t, c, m in zip(classes.step, classes.cell, classes.log_multiplicity, strict=True)
    )
    total = ways[0][0]
    assert (through_exits + classes.members[0]) / total == pytest.approx(1.0, rel=1e-12)
    fit = map_estimate(model, demo[None])
    assert fit.converged[0] and np.isfinite(fit.log_likelihood[0])
    off = model.off_demonstration(fit.theta_hat, classes, moments=0)
    assert fit.log_likelihood[0] == pytest.approx(
        -np.logaddexp(np.log(classes.members[0]), off.log_mass[0]), rel=1e-12
    )


def test_a_class_beyond_2_to_the_53_is_counted_to_the_rounding_of_its_sums():
    # 1.3e21 paths: the count is a sum of non-negative counts, within (T (P - 1) + N) 2^-53.
    table, features, demo = _tile_walk(6, 5, 40, 5, seed=1)
    model = MaxEnt(Phase(table, 0, 40), features[None], 1.0)
    members = model.demonstration_classes(demo[None]).members[0]
    exact = _exact_class_size(table, 0, demo, features)
    assert exact > 2**53
    assert abs(members - exact) <= (40 * 4 + 30) * 2.0**-53 * exact


# ---- determinism -----------------------------------------------------------------------------


def test_a_trial_alone_and_in_a_batch_gives_the_same_bits():
    table, features, demo = _tile_walk(4, 4, 8, 3, seed=2)
    rng = np.random.default_rng(2)
    other = bf.rbf_features(4, 4, rng.uniform(0, 3, size=(3, 2)), 1.0)
    demos = np.array([demo, np.full_like(demo, demo[0]), demo])
    batch = MaxEnt(Phase(table, 0, 8), np.stack([features, other, features]), 1.0)
    together = batch.demonstration_classes(demos)
    for b in range(3):
        alone = batch.take(np.array([b])).demonstration_classes(demos[b : b + 1])
        picked = together.take(np.array([b]))
        for field in dataclasses.fields(alone):
            np.testing.assert_array_equal(getattr(alone, field.name), getattr(picked, field.name))
    again = batch.demonstration_classes(demos)
    for field in dataclasses.fields(together):
        np.testing.assert_array_equal(getattr(again, field.name), getattr(together, field.name))


def test_a_phase_without_moves_has_one_member_and_no_exits():
    model = MaxEnt(Phase(bf.move_table(3, 3), 4, 0), np.ones((2, 9, 2)), 1.0)
    classes = model.demonstration_classes(np.array([[4], [4]]))
    np.testing.assert_array_equal(classes.members, [1.0, 1.0])
    np.testing.assert_array_equal(classes.offsets, [0, 0, 0])
    assert classes.shift.shape == (0, 2) and classes.log_multiplicity.shape == (0,)
