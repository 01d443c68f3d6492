"""The finite hypothesis space (:mod:`cirl_study.core.hypotheses`) against listing every path.

Every reference here lists the phase's paths one at a time, by a recursion over the moves
written out from the grid's coordinates (it reads none of the engine's successor tables or
class enumerations). Then it computes each path's feature counts and applies Bayes' rule one
path at a time in 40-digit arithmetic (an isolated :class:`mpmath.MPContext`):

* literal likelihood  ``log P_L(tau | h) = lambda theta_h . phi(tau) - log Z_h``, where
  ``Z_h = sum_tau exp(lambda theta_h . phi(tau))``;
* literal posterior   ``P_L(h | tau) = P_L(tau | h) / sum_g P_L(tau | g)`` (uniform prior);
* pedagogic normaliser ``N_h = sum_tau P_L(h | tau)^alpha`` (over paths, never classes);
* pragmatic posterior ``P_P(h | tau) ∝ P_L(h | tau)^alpha / N_h``;
* teaching weights    ``sum_{tau in m} P_L(theta | tau)^alpha / N_theta`` for each visit class ``m``
  (the paths that visit the same multiset of cells), over the demonstrator's space.

The engine groups paths by visit class and sums over the classes in float64. So the
comparisons below use relative tolerances of about ``1e-10`` (and ``1e-10`` absolute on
logarithms).
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from dataclasses import dataclass
from functools import cached_property

import mpmath
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray
from scipy.special import logsumexp

from cirl_study.core.gridworld import ACTIONS, UNAVAILABLE, Gridworld, rbf_features
from cirl_study.core.hypotheses import (
    BOX,
    SUM_FLOOR,
    HypothesisSpace,
    VisitClasses,
    draw_hypotheses,
    path_count,
)
from cirl_study.core.maxent import MaxEnt, Phase

Path = tuple[int, ...]
FloatArray = NDArray[np.float64]

STEPS: tuple[tuple[int, int], ...] = ((0, 0), (0, 1), (0, -1), (1, 0), (-1, 0))
"""``(dx, dy)`` of stay, N, S, E, W: the documented action order, written out here."""

DIGITS = 40
"""Working precision of the references (decimal digits)."""

RTOL = 1e-10
"""Relative tolerance of every comparison with a reference."""

LOG_ATOL = 1e-10
"""Absolute tolerance on logarithms (a relative error of ``1e-10`` in the value)."""


# ---- the independent listing ------------------------------------------------------------------


def list_paths(
    width: int, height: int, start: tuple[int, int], horizon: int, stay: bool
) -> list[Path]:
    """Every path of ``horizon`` moves from ``start = (x, y)``, in lexicographic order of moves.

    One recursion over the five moves in the order stay, N, S, E, W (stay left out unless
    ``stay``). A move that leaves the grid is not made. Cells are flat indices ``y * width + x``.
    """
    out: list[Path] = []
    path = [start[1] * width + start[0]]

    def extend(x: int, y: int, left: int) -> None:
        if left == 0:
            out.append(tuple(path))
            return
        for a, (dx, dy) in enumerate(STEPS):
            if a == 0 and not stay:
                continue
            nx, ny = x + dx, y + dy
            if 0 <= nx < width and 0 <= ny < height:
                path.append(ny * width + nx)
                extend(nx, ny, left - 1)
                path.pop()

    extend(start[0], start[1], horizon)
    return out


def visit_key(path: Path) -> Path:
    """The multiset of cells ``s_1..s_T`` a path visits, as a sorted tuple."""
    return tuple(sorted(path[1:]))


def phase_of(width: int, height: int, start: tuple[int, int], horizon: int, stay: bool) -> Phase:
    """The engine's phase: the grid's successor table, with the stay column removed if needed."""
    grid = Gridworld(width, height)
    successors = grid.successors.copy()
    if not stay:
        successors[:, ACTIONS.index("stay")] = UNAVAILABLE
    return Phase(successors, grid.index(*start), horizon)


# ---- the path-by-path reference ---------------------------------------------------------------


@dataclass(frozen=True)
class Reference:
    """Bayes' rule over listed ``paths`` for hypotheses ``thetas`` ``(H, K)``, in 40 digits.

    ``features`` is ``(S, K)`` (one trial's features); ``rationality`` is :math:`\\lambda`.
    """

    paths: list[Path]
    features: FloatArray
    thetas: FloatArray
    rationality: float

    @cached_property
    def ctx(self) -> mpmath.MPContext:
        ctx = mpmath.MPContext()
        ctx.dps = DIGITS
        return ctx

    @cached_property
    def counts(self) -> list[list[object]]:
        """``(P, K)`` feature counts, each an exact sum of the float64 features."""
        ctx = self.ctx
        k = self.features.shape[1]
        return [
            [ctx.fsum(ctx.mpf(float(self.features[s, j])) for s in path[1:]) for j in range(k)]
            for path in self.paths
        ]

    @cached_property
    def scores(self) -> list[list[object]]:
        """``(P, H)`` :math:`\\lambda \\theta_h^\\top \\phi(\\tau)`."""
        ctx = self.ctx
        lam = ctx.mpf(self.rationality)
        thetas = [[ctx.mpf(float(v)) for v in row] for row in self.thetas]
        return [
            [lam * ctx.fsum(t * c for t, c in zip(theta, counts, strict=True)) for theta in thetas]
            for counts in self.counts
        ]

    @cached_property
    def log_partition(self) -> list[object]:
        """``(H,)`` :math:`\\log Z_h`, summed over every listed path."""
        ctx = self.ctx
        return [
            ctx.log(ctx.fsum(ctx.exp(row[h]) for row in self.scores))
            for h in range(len(self.thetas))
        ]

    @cached_property
    def log_likelihood(self) -> list[list[object]]:
        """``(P, H)`` :math:`\\log P_L(\\tau \\mid \\theta_h)`."""
        return [
            [score - logz for score, logz in zip(row, self.log_partition, strict=True)]
            for row in self.scores
        ]

    @cached_property
    def log_literal(self) -> list[list[object]]:
        """``(P, H)`` :math:`\\log P_L(\\theta_h \\mid \\tau)`, Bayes' rule for each path."""
        ctx = self.ctx
        out = []
        for row in self.log_likelihood:
            evidence = ctx.log(ctx.fsum(ctx.exp(v) for v in row))
            out.append([v - evidence for v in row])
        return out

    def log_normaliser(self, alpha: float) -> list[object]:
        """``(H,)`` :math:`\\log N_h = \\log \\sum_\\tau P_L(\\theta_h \\mid \\tau)^\\alpha`."""
        ctx = self.ctx
        a = ctx.mpf(alpha)
        return [
            ctx.log(ctx.fsum(ctx.exp(a * row[h]) for row in self.log_literal))
            for h in range(len(self.thetas))
        ]

    def plain_normaliser(self, alpha: float) -> FloatArray:
        """``(H,)`` :math:`N_h` summed in float64, the way a plain sum sees it (may underflow)."""
        terms = np.array([[float(alpha * v) for v in row] for row in self.log_literal])
        return np.array([math.fsum(np.exp(column)) for column in terms.T])

    def log_pedagogic_paths(self, alpha: float) -> list[list[object]]:
        """``(P, H)`` :math:`\\log P_P(\\tau \\mid \\theta_h) = \\alpha \\log P_L(\\theta_h \\mid
        \\tau) - \\log N_h`."""
        normaliser = self.log_normaliser(alpha)
        return [
            [alpha * v - n for v, n in zip(row, normaliser, strict=True)]
            for row in self.log_literal
        ]

    def pedagogic_posterior(self, alpha: float) -> FloatArray:
        """``(P, H)`` :math:`P_P(\\theta_h \\mid \\tau)`, Bayes' rule for each path."""
        ctx = self.ctx
        out = []
        for row in self.log_pedagogic_paths(alpha):
            evidence = ctx.log(ctx.fsum(ctx.exp(v) for v in row))
            out.append([float(ctx.exp(v - evidence)) for v in row])
        return np.array(out)

    def teaching_log_weights(self, alpha: float, truth: int) -> dict[Path, float]:
        """``log sum_{tau in m} P_P(tau | theta_truth)`` for each visit class ``m``, by key."""
        ctx = self.ctx
        by_class: dict[Path, list[object]] = defaultdict(list)
        for path, row in zip(self.paths, self.log_pedagogic_paths(alpha), strict=True):
            by_class[visit_key(path)].append(ctx.exp(row[truth]))
        return {key: float(ctx.log(ctx.fsum(terms))) for key, terms in by_class.items()}


def as_floats(values: list[object]) -> FloatArray:
    """mpmath numbers as float64."""
    return np.array([float(v) for v in values])


def log_sum_exp(values: FloatArray, axis: int) -> FloatArray:
    """``log sum exp`` along ``axis`` (kept), with the maximum factored out; plain numpy."""
    top = values.max(axis=axis, keepdims=True)
    return top + np.log(np.exp(values - top).sum(axis=axis, keepdims=True))


def float_counts(paths: list[Path], features: FloatArray) -> FloatArray:
    """``(P, K)`` feature counts of listed paths, each an exactly rounded sum."""
    return np.array(
        [
            [math.fsum(features[list(path[1:]), j]) for j in range(features.shape[1])]
            for path in paths
        ]
    )


# ---- the games ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class Game:
    """A small phase with a batch of trials, their hypotheses and every path listed."""

    width: int
    height: int
    start: tuple[int, int]
    horizon: int
    stay: bool
    features: FloatArray
    """``(B, S, K)``"""
    thetas: FloatArray
    """``(B, H, K)``"""
    rationality: float

    @cached_property
    def paths(self) -> list[Path]:
        return list_paths(self.width, self.height, self.start, self.horizon, self.stay)

    @cached_property
    def phase(self) -> Phase:
        return phase_of(self.width, self.height, self.start, self.horizon, self.stay)

    @cached_property
    def model(self) -> MaxEnt:
        return MaxEnt(self.phase, self.features, self.rationality)

    def space(self, alpha: float, *, includes_truth: bool = True) -> HypothesisSpace:
        """A fresh space (its normaliser cache empty)."""
        return HypothesisSpace(self.model, self.thetas, includes_truth, alpha)

    def reference(self, b: int, thetas: FloatArray | None = None) -> Reference:
        """Trial ``b``'s reference, over its own hypotheses unless ``thetas`` ``(H, K)`` given."""
        space = self.thetas[b] if thetas is None else thetas
        return Reference(self.paths, self.features[b], space, self.rationality)

    def counts(self) -> FloatArray:
        """``(P, B, K)`` every listed path's feature counts in every trial."""
        return np.stack([float_counts(self.paths, f) for f in self.features], axis=1)


def make_game(
    width: int,
    height: int,
    start: tuple[int, int],
    horizon: int,
    stay: bool,
    *,
    rationality: float = 1.0,
    hypotheses: int = 4,
    num_features: int = 3,
    batch: int = 2,
    seed: int = 0,
) -> Game:
    """A seeded game: RBF features with random centers per trial, hypotheses in ``[-1, 1]^K``."""
    rng = np.random.default_rng(seed)
    grid = Gridworld(width, height)
    features = np.stack(
        [
            rbf_features(
                grid,
                rng.uniform([0, 0], [width - 1, height - 1], size=(num_features, 2)),
                rng.uniform(0.7, 2.0),
            )
            for _ in range(batch)
        ]
    )
    thetas = rng.uniform(-1.0, 1.0, size=(batch, hypotheses, num_features))
    return Game(width, height, start, horizon, stay, features, thetas, rationality)


GAMES: dict[str, tuple[int, int, tuple[int, int], int, bool]] = {
    "3x3-center-3-stay": (3, 3, (1, 1), 3, True),
    "3x3-corner-4-nostay": (3, 3, (0, 0), 4, False),
    "4x3-4-stay": (4, 3, (1, 2), 4, True),
    "4x3-3-nostay": (4, 3, (3, 0), 3, False),
    "3x3-2-nostay": (3, 3, (2, 1), 2, False),
}


# ---- 1. the listing and the visit classes -----------------------------------------------------


def test_the_reference_moves_follow_the_engine_s_action_order() -> None:
    """The reference's hard-coded move order is the documented one (stay, N, S, E, W)."""
    assert ACTIONS == ("stay", "N", "S", "E", "W")
    grid = Gridworld(3, 3)
    center = grid.index(1, 1)
    for a, (dx, dy) in enumerate(STEPS):
        assert grid.successors[center, a] == grid.index(1 + dx, 1 + dy)


@pytest.mark.parametrize(
    ("width", "height", "start", "horizon", "stay"),
    [
        *GAMES.values(),
        (1, 2, (0, 0), 3, False),
        # 300 or 200 cells and 8 moves: the class keys no longer fit in 63 bits (the bytes keys).
        (1, 300, (0, 150), 8, True),
        (2, 100, (0, 50), 8, False),
    ],
)
def test_visit_classes_group_exactly_the_listed_paths(
    width: int, height: int, start: tuple[int, int], horizon: int, stay: bool
) -> None:
    """``path_count``, ``paths``, ``cells``, ``multiplicity``, ``members``/``offsets``,
    ``representative`` and ``path_in`` against the listed paths, grouped directly by their
    sorted visited cells."""
    listed = list_paths(width, height, start, horizon, stay)
    phase = phase_of(width, height, start, horizon, stay)
    classes = VisitClasses.of(phase)

    assert path_count(phase) == len(listed)
    np.testing.assert_array_equal(classes.paths, np.array(listed))
    assert int(classes.multiplicity.sum()) == len(listed)

    keys = [visit_key(path) for path in listed]
    counted = Counter(keys)
    class_keys = [tuple(int(c) for c in row) for row in classes.cells]
    assert classes.size == len(counted) == len(set(class_keys))
    assert classes.cells.shape == (classes.size, horizon)
    assert {key: int(n) for key, n in zip(class_keys, classes.multiplicity, strict=True)} == counted

    assert classes.offsets[0] == 0
    assert classes.offsets[-1] == len(listed)
    np.testing.assert_array_equal(np.diff(classes.offsets), classes.multiplicity)
    np.testing.assert_array_equal(np.sort(classes.members), np.arange(len(listed)))
    members_of: dict[Path, list[int]] = defaultdict(list)
    for i, key in enumerate(keys):
        members_of[key].append(i)
    for m, key in enumerate(class_keys):
        got = classes.members[classes.offsets[m] : classes.offsets[m + 1]].tolist()
        assert got == members_of[key], key

    everything = np.arange(classes.size)
    first = classes.representative(everything)
    np.testing.assert_array_equal(first, np.array([listed[members_of[k][0]] for k in class_keys]))

    # path_in: uniforms at the centers of n equal bins pick each of a class's n paths once.
    rng = np.random.default_rng(1)
    for m in rng.choice(classes.size, size=min(classes.size, 40), replace=False):
        n = int(classes.multiplicity[m])
        uniforms = (np.arange(n) + rng.uniform(0.0, 1.0, size=n)) / n
        picked = classes.path_in(np.full(n, m), uniforms)
        assert sorted(listed.index(tuple(p)) for p in picked) == members_of[class_keys[m]]
        ends = classes.path_in(np.array([m, m]), np.array([0.0, np.nextafter(1.0, 0.0)]))
        assert [tuple(p) for p in ends] == [
            listed[members_of[class_keys[m]][0]],
            listed[members_of[class_keys[m]][-1]],
        ]
    drawn = classes.path_in(everything, rng.uniform(0.0, 1.0, size=classes.size))
    assert [visit_key(tuple(int(c) for c in p)) for p in drawn] == class_keys


# ---- 2. log-partitions and the literal posterior ----------------------------------------------


@pytest.mark.parametrize("rationality", [0.3, 4.0])
@pytest.mark.parametrize("name", ["3x3-center-3-stay", "3x3-corner-4-nostay", "4x3-3-nostay"])
def test_log_partition_and_literal_posterior_follow_bayes_rule_path_by_path(
    name: str, rationality: float
) -> None:
    """``log_partition`` is the log of the sum over every listed path; ``literal_log_likelihood``
    and ``literal_posterior`` at every path are each path's likelihood and Bayes' rule."""
    game = make_game(*GAMES[name], rationality=rationality, hypotheses=5, seed=11)
    space = game.space(1.0)
    counts = game.counts()
    for b in range(game.model.batch):
        ref = game.reference(b)
        np.testing.assert_allclose(
            space.log_partition[b], as_floats(ref.log_partition), rtol=RTOL, atol=LOG_ATOL
        )
        for p in range(len(game.paths)):
            loglik = space.literal_log_likelihood(counts[p])[b]
            np.testing.assert_allclose(
                loglik, as_floats(ref.log_likelihood[p]), rtol=RTOL, atol=LOG_ATOL
            )
            posterior = space.literal_posterior(counts[p])[b]
            want = np.exp(as_floats(ref.log_literal[p]))
            np.testing.assert_allclose(posterior, want, rtol=RTOL, atol=1e-300)
            assert posterior.sum() == pytest.approx(1.0, abs=1e-14)


# ---- 3. the pedagogic normaliser and the pragmatic posterior ----------------------------------


@pytest.mark.parametrize("alpha", [0.5, 1.0, 3.0])
@pytest.mark.parametrize("name", ["3x3-center-3-stay", "4x3-4-stay", "3x3-corner-4-nostay"])
def test_pedagogic_normaliser_and_posterior_sum_over_every_path(name: str, alpha: float) -> None:
    """``pedagogic_log_normaliser`` is ``log sum_tau P_L(h | tau)^alpha`` over the listed
    paths (alpha = 1 is the kernel's special case); ``pedagogic_posterior`` at every path is
    Bayes' rule with ``P_P(tau | h)``, and sums to 1."""
    game = make_game(*GAMES[name], rationality=2.0, hypotheses=4, seed=5)
    space = game.space(alpha)
    got = space.pedagogic_log_normaliser()
    assert got.shape == (game.model.batch, 4)
    refs = [game.reference(b) for b in range(game.model.batch)]
    for b, ref in enumerate(refs):
        np.testing.assert_allclose(
            got[b], as_floats(ref.log_normaliser(alpha)), rtol=RTOL, atol=LOG_ATOL
        )
    wants = [ref.pedagogic_posterior(alpha) for ref in refs]
    counts = game.counts()
    for p in range(len(game.paths)):
        posterior = space.pedagogic_posterior(counts[p])
        for b, want in enumerate(wants):
            np.testing.assert_allclose(posterior[b], want[p], rtol=RTOL, atol=1e-300)
        np.testing.assert_allclose(posterior.sum(axis=1), 1.0, rtol=0, atol=1e-14)


def test_the_pragmatic_observer_is_not_the_literal_one() -> None:
    """The check above can fail: with alpha != 1 the two posteriors differ at some path."""
    game = make_game(*GAMES["3x3-center-3-stay"], rationality=2.0, seed=5)
    space = game.space(3.0)
    counts = game.counts()
    gaps = [np.abs(space.pedagogic_posterior(c) - space.literal_posterior(c)).max() for c in counts]
    assert max(gaps) > 1e-3


# ---- 4. the teaching weights ------------------------------------------------------------------


@pytest.mark.parametrize("alpha", [0.5, 1.0, 3.0])
@pytest.mark.parametrize("includes_truth", [True, False])
@pytest.mark.parametrize("name", ["4x3-4-stay", "3x3-corner-4-nostay"])
def test_teaching_log_weights_are_the_pedagogic_path_probabilities_summed_by_class(
    name: str, includes_truth: bool, alpha: float
) -> None:
    """``teaching_log_weights(b, theta)`` per class ``m`` is ``log sum_{tau in m} P_P(tau |
    theta)`` over the demonstrator's space (the space itself when it includes the truth, at
    index 0; else ``[theta] + space``); the weights sum to 1. The space's own normaliser is
    unchanged by the call."""
    game = make_game(*GAMES[name], rationality=1.5, hypotheses=4, seed=8)
    space = game.space(alpha, includes_truth=includes_truth)
    classes = VisitClasses.of(game.phase)
    truths = np.random.default_rng(3).uniform(-1, 1, size=(game.model.batch, 3))
    for b in range(game.model.batch):
        theta = game.thetas[b, 0] if includes_truth else truths[b]
        weights = space.teaching_log_weights(b, theta)
        assert weights.shape == (classes.size,)
        assert logsumexp(weights) == pytest.approx(0.0, abs=1e-12)
        demonstrator = game.thetas[b] if includes_truth else np.vstack([theta, game.thetas[b]])
        want = game.reference(b, demonstrator).teaching_log_weights(alpha, 0)
        expected = np.array([want[tuple(int(c) for c in row)] for row in classes.cells])
        np.testing.assert_allclose(weights, expected, rtol=RTOL, atol=LOG_ATOL)
    normaliser = space.pedagogic_log_normaliser()
    for b in range(game.model.batch):
        want_n = as_floats(game.reference(b).log_normaliser(alpha))
        np.testing.assert_allclose(normaliser[b], want_n, rtol=RTOL, atol=LOG_ATOL)


def test_teaching_without_the_truth_teaches_over_the_truth_and_the_space() -> None:
    """The check above can fail: leaving the truth out of the space changes the weights."""
    game = make_game(*GAMES["4x3-4-stay"], rationality=1.5, seed=8)
    theta = game.thetas[0, 0]
    inside = game.space(3.0, includes_truth=True).teaching_log_weights(0, theta)
    outside = game.space(3.0, includes_truth=False).teaching_log_weights(0, theta)
    assert np.abs(inside - outside).max() > 1e-3


# ---- 5. the log-space fallback ----------------------------------------------------------------


@pytest.mark.parametrize(
    ("alpha", "rationality"),
    [(400.0, 2.0), (400.0, 30.0)],
)
def test_a_normaliser_below_the_floor_is_summed_in_log_space(
    alpha: float, rationality: float
) -> None:
    """Eight near-copies of one hypothesis share every path's posterior, so each copy's plain sum
    ``sum_tau P_L(h | tau)^alpha`` falls below ``SUM_FLOOR`` (the reference's float64 sum
    confirms it, and for some it underflows to 0 outright). ``log N_h``, the pragmatic
    posterior and the teaching weights still equal the 40-digit references."""
    width, height, start, horizon, stay = GAMES["3x3-center-3-stay"]
    rng = np.random.default_rng(21)
    game = make_game(width, height, start, horizon, stay, rationality=rationality, batch=1)
    base = rng.uniform(-1, 1, size=3)
    copies = base + rng.uniform(-1e-3, 1e-3, size=(8, 3))
    others = rng.uniform(-1, 1, size=(2, 3))
    thetas = np.vstack([copies, others])[None]
    game = Game(width, height, start, horizon, stay, game.features, thetas, rationality)
    ref = game.reference(0)

    plain = ref.plain_normaliser(alpha)
    assert (plain < SUM_FLOOR).any(), plain
    assert (plain == 0.0).any(), plain
    assert (plain >= SUM_FLOOR).any(), plain

    space = game.space(alpha)
    got = space.pedagogic_log_normaliser()[0]
    want = as_floats(ref.log_normaliser(alpha))
    assert np.isfinite(got).all()
    np.testing.assert_allclose(got, want, rtol=RTOL, atol=LOG_ATOL)

    wants = ref.pedagogic_posterior(alpha)
    for p, counts in enumerate(game.counts()):
        np.testing.assert_allclose(
            space.pedagogic_posterior(counts)[0], wants[p], rtol=RTOL, atol=1e-290
        )

    weights = game.space(alpha).teaching_log_weights(0, thetas[0, 0])
    classes = VisitClasses.of(game.phase)
    by_key = ref.teaching_log_weights(alpha, 0)
    expected = np.array([by_key[tuple(int(c) for c in row)] for row in classes.cells])
    assert logsumexp(weights) == pytest.approx(0.0, abs=1e-10)
    np.testing.assert_allclose(weights, expected, rtol=RTOL, atol=LOG_ATOL)


def test_identical_hypotheses_underflow_to_a_known_normaliser() -> None:
    """``H`` identical hypotheses have ``P_L(h | tau) = 1/H`` at every path, so ``log N_h =
    log P - alpha log H`` exactly, far below float64 at alpha = 400 (the plain sum is 0)."""
    game = make_game(*GAMES["4x3-3-nostay"], rationality=3.0, batch=1, seed=2)
    count = 6
    thetas = np.repeat(game.thetas[:, :1], count, axis=1)
    space = HypothesisSpace(game.model, thetas, True, 400.0)
    assert (1.0 / count) ** 400 * len(game.paths) < SUM_FLOOR
    want = math.log(len(game.paths)) - 400.0 * math.log(count)
    np.testing.assert_allclose(space.pedagogic_log_normaliser()[0], want, rtol=1e-12)


# ---- 6. drawing the hypotheses ----------------------------------------------------------------


@pytest.mark.parametrize("includes_truth", [True, False])
def test_draw_hypotheses_places_the_truth_and_depends_on_the_seed_alone(
    includes_truth: bool,
) -> None:
    """Shape ``(B, H, K)``; with the truth, row 0 is each trial's theta; the draws lie in the
    prior's box; equal seeds give equal spaces, other seeds other spaces, call after call."""
    rng = np.random.default_rng(0)
    theta = rng.uniform(-1, 1, size=(4, 3))
    seeds = np.array([7, 7, 8, 9])
    spaces = draw_hypotheses(theta, seeds, 5, includes_truth=includes_truth)
    assert spaces.shape == (4, 5, 3)
    again = draw_hypotheses(theta, seeds, 5, includes_truth=includes_truth)
    np.testing.assert_array_equal(spaces, again)
    first_drawn = 1 if includes_truth else 0
    drawn = spaces[:, first_drawn:]
    assert BOX == (-1.0, 1.0)
    assert (drawn >= -1.0).all()
    assert (drawn <= 1.0).all()
    if includes_truth:
        np.testing.assert_array_equal(spaces[:, 0], theta)
    else:
        assert (np.abs(spaces - theta[:, None]).max(axis=-1) > 0).all()
    np.testing.assert_array_equal(drawn[0], drawn[1])
    assert not np.array_equal(drawn[1], drawn[2])
    assert not np.array_equal(drawn[2], drawn[3])
    other_truth = draw_hypotheses(-theta, seeds, 5, includes_truth=includes_truth)
    np.testing.assert_array_equal(other_truth[:, first_drawn:], drawn)
    np.testing.assert_array_equal(
        draw_hypotheses(theta[:1], seeds[:1], 5, includes_truth=includes_truth), spaces[:1]
    )


# ---- random small games -----------------------------------------------------------------------


@st.composite
def small_games(draw: st.DrawFn) -> Game:
    """A random phase (at most 3x3, 3 moves, with or without stay), one trial, 2-4 hypotheses."""
    width = draw(st.integers(1, 3))
    height = draw(st.integers(2 if width == 1 else 1, 3))
    start = (draw(st.integers(0, width - 1)), draw(st.integers(0, height - 1)))
    return make_game(
        width,
        height,
        start,
        draw(st.integers(1, 3)),
        draw(st.booleans()),
        rationality=10.0 ** draw(st.floats(-1.0, 1.3)),
        hypotheses=draw(st.integers(2, 4)),
        num_features=draw(st.integers(1, 3)),
        batch=1,
        seed=draw(st.integers(0, 2**31)),
    )


@given(game=small_games(), alpha=st.sampled_from([0.25, 1.0, 2.0, 7.5]))
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
def test_random_small_games_match_the_reference(game: Game, alpha: float) -> None:
    """Path count, log Z, log N_h, the pragmatic posterior and the teaching weights of random
    small games all equal the path-by-path reference."""
    assert path_count(game.phase) == len(game.paths)
    ref = game.reference(0)
    space = game.space(alpha)
    np.testing.assert_allclose(
        space.log_partition[0], as_floats(ref.log_partition), rtol=RTOL, atol=LOG_ATOL
    )
    np.testing.assert_allclose(
        space.pedagogic_log_normaliser()[0],
        as_floats(ref.log_normaliser(alpha)),
        rtol=RTOL,
        atol=LOG_ATOL,
    )
    wants = ref.pedagogic_posterior(alpha)
    for p, counts in enumerate(game.counts()):
        np.testing.assert_allclose(
            space.pedagogic_posterior(counts)[0], wants[p], rtol=RTOL, atol=1e-300
        )
    classes = VisitClasses.of(game.phase)
    by_key = ref.teaching_log_weights(alpha, 0)
    expected = np.array([by_key[tuple(int(c) for c in row)] for row in classes.cells])
    weights = space.teaching_log_weights(0, game.thetas[0, 0])
    np.testing.assert_allclose(weights, expected, rtol=RTOL, atol=LOG_ATOL)


# ---- the paper's size -------------------------------------------------------------------------


def test_the_paper_s_phase_at_full_size() -> None:
    """10x10 grid, start (5, 5), 9 moves with stay: 1,910,313 paths in 407,677 classes. The
    classes are checked against a lexicographic sort of the sorted visits of independently
    built paths, and ``log N_h`` against a float64 sum over every path."""
    width = height = 10
    start, horizon = (5, 5), 9
    phase = phase_of(width, height, start, horizon, True)
    classes = VisitClasses.of(phase)
    assert path_count(phase) == 1_910_313
    assert classes.paths.shape == (1_910_313, horizon + 1)
    assert classes.size == 407_677
    assert int(classes.multiplicity.sum()) == 1_910_313

    rng = np.random.default_rng(9)
    features = rbf_features(Gridworld(width, height), rng.uniform(0, 9, size=(3, 2)), 2.0)
    thetas = rng.uniform(-1, 1, size=(4, 3))
    alpha, rationality = 2.0, 1.0
    rewards = rationality * features @ thetas.T

    # Paths built level by level from coordinates, in move order (stay, N, S, E, W), each
    # carrying its scores lambda theta_h . phi(tau) (a prefix's scores plus the new cell's).
    xs, ys = np.array([start[0]]), np.array([start[1]])
    cells = [(ys * width + xs).astype(np.uint8)]
    scores = np.zeros((1, len(thetas)))
    for _ in range(horizon):
        nx = (xs[:, None] + np.array([dx for dx, _ in STEPS])).ravel()
        ny = (ys[:, None] + np.array([dy for _, dy in STEPS])).ravel()
        keep = (nx >= 0) & (nx < width) & (ny >= 0) & (ny < height)
        parent = np.repeat(np.arange(len(xs)), len(STEPS))[keep]
        xs, ys = nx[keep], ny[keep]
        new = (ys * width + xs).astype(np.uint8)
        cells = [c[parent] for c in cells] + [new]
        scores = scores[parent] + rewards[new]
    paths = np.stack(cells, axis=1)
    assert np.array_equal(classes.paths, paths)

    # Grouped by sorting the sorted visits lexicographically and cutting where a row changes.
    visits = np.sort(paths[:, 1:], axis=1)
    ordered = visits[np.lexsort(visits.T[::-1])]
    starts = np.flatnonzero(np.concatenate([[True], (ordered[1:] != ordered[:-1]).any(axis=1)]))
    unique, counts = ordered[starts], np.diff(np.append(starts, len(ordered)))
    order = np.lexsort(classes.cells.T[::-1])
    np.testing.assert_array_equal(classes.cells[order], unique)
    np.testing.assert_array_equal(classes.multiplicity[order], counts)

    space = HypothesisSpace(MaxEnt(phase, features[None], rationality), thetas[None], True, alpha)
    loglik = scores - log_sum_exp(scores, axis=0)
    literal = loglik - log_sum_exp(loglik, axis=1)
    want = log_sum_exp(alpha * literal, axis=0)[0]
    np.testing.assert_allclose(space.pedagogic_log_normaliser()[0], want, rtol=1e-9, atol=1e-9)


def test_a_literal_posterior_below_the_smallest_double_still_counts_at_small_alpha() -> None:
    # One feature phi(s) = x on a 3x3 grid, hypotheses +1 and -1, lambda = 150: after the
    # path (4, 5, 5, 5) (counts 6) the literal posterior of -1 is exp(-900), far below the
    # smallest double, but raised to alpha = 0.01 it is 1.2e-4 of the pragmatic posterior.
    phase = phase_of(3, 3, (1, 1), 3, stay=True)
    features = np.array([[[float(cell % 3)] for cell in range(9)]])
    model = MaxEnt(phase, features, 150.0)
    space = HypothesisSpace(model, np.array([[[1.0], [-1.0]]]), True, 0.01)
    counts = model.path_counts(np.array([[4, 5, 5, 5]]))
    log_literal = space.literal_log_likelihood(counts)[0]
    log_normaliser = space.pedagogic_log_normaliser()[0]
    np.testing.assert_allclose(log_normaliser, [3.9228466, 3.9228466], rtol=1e-7)
    log_posterior = 0.01 * (log_literal - logsumexp(log_literal)) - log_normaliser
    pragmatic = np.exp(log_posterior - logsumexp(log_posterior))
    np.testing.assert_allclose(space.pedagogic_posterior(counts)[0], pragmatic, rtol=1e-12)
    np.testing.assert_allclose(pragmatic, [0.999876605, 1.23394576e-4], rtol=1e-8)


def test_the_pedagogic_probabilities_are_kept_for_a_subjects_other_humans(monkeypatch) -> None:
    """The second teaching human of a subject reads the first's pass over the classes: the
    same values, bit for bit, as a fresh space computes; shared by the spaces ``take`` makes,
    read-only, and the oldest dropped past the byte budget."""
    from cirl_study.core import hypotheses

    game = make_game(3, 3, (1, 1), 3, True, batch=3, hypotheses=4)
    space = game.space(2.0)
    theta = game.thetas[:, 0]
    first = space.pedagogic_path_log_probability(1, theta[1])
    again = space.take(np.array([1])).pedagogic_path_log_probability(0, theta[1])
    assert again is first and not first.flags.writeable
    fresh = game.space(2.0).pedagogic_path_log_probability(1, theta[1])
    assert fresh is not first and np.array_equal(fresh, first)
    monkeypatch.setattr(hypotheses, "TEACHING_CACHE_BYTES", first.nbytes)
    space.pedagogic_path_log_probability(2, theta[2])
    assert space.pedagogic_path_log_probability(1, theta[1]) is not first
