"""The teaching humans and robots (:mod:`cirl_study.core.teaching`) against listing every path.

Every reference here lists the learning phase's paths one at a time, by a recursion over the
moves written out from the grid's coordinates (it reads none of the engine's successor tables
or visit classes), and applies the definitions path by path in float64, with each path's
feature counts an exactly rounded sum (:func:`math.fsum`, so paths through the same cells have
bit-for-bit equal counts):

* literal likelihood   ``log P_L(tau | h) = lambda theta_h . phi(tau) - log Z_h``, ``Z_h`` summed
  over the listed paths;
* literal posterior    ``P_L(h | tau) ∝ P_L(tau | h)`` (uniform prior);
* pedagogic human      ``P_P(tau | theta) ∝ P_L(theta | tau)^alpha`` over every listed path, the
  posterior taken over the demonstrator's space (the space itself when it includes the truth,
  else ``[theta] + space``);
* pragmatic posterior  ``P_P(h | tau) ∝ P_L(h | tau)^alpha / N_h``, ``N_h = sum_tau P_L(h |
  tau)^alpha`` over every listed path;
* MAP-robot regret     ``regret(deployment, theta, map_estimate(tau).theta_hat)``, one call of
  :func:`~cirl_study.core.robot.map_estimate` per listed path.

Ties go, as documented, to the first path in move order of the lowest-numbered visit class
(the engine's class order, :class:`~cirl_study.core.hypotheses.VisitClasses`). The pedagogic
mode breaks exact ties by rounding instead: that test is marked as an expected failure.

Tolerances: ``1e-10`` relative on the robots' estimates; regrets are compared exactly (they are
computed by the same functions, path by path); draws by a chi-square test at ``p > 1e-3``
(deterministic: the draws are fixed by their seeds).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import pytest
from numpy.typing import NDArray
from scipy import stats
from scipy.special import logsumexp

from cirl_study.core import teaching
from cirl_study.core.apprenticeship import Apprenticeship
from cirl_study.core.estimate import Estimate
from cirl_study.core.gridworld import ACTIONS, Gridworld, rbf_features
from cirl_study.core.humans import best_response_paths, expert_paths, human_generator
from cirl_study.core.hypotheses import HypothesisSpace, VisitClasses
from cirl_study.core.maxent import MaxEnt, Phase
from cirl_study.core.measures import regret
from cirl_study.core.robot import map_estimate
from cirl_study.record import Teaching

Path = tuple[int, ...]
FloatArray = NDArray[np.float64]

STEPS: tuple[tuple[int, int], ...] = ((0, 0), (0, 1), (0, -1), (1, 0), (-1, 0))
"""``(dx, dy)`` of stay, N, S, E, W: the documented action order, written out here."""

RTOL = 1e-10
"""Relative tolerance of the robots' estimates against the reference."""

ATOL = 1e-13
"""Absolute tolerance on estimate coordinates that cancel to near zero."""


# ---- the independent listing ------------------------------------------------------------------


@dataclass(frozen=True)
class Setting:
    """A learning phase of ``horizon`` moves from ``start`` (stay allowed iff ``stay``) on a
    ``width x height`` grid, and a deployment phase of ``deployment`` moves from every cell."""

    width: int
    height: int
    start: tuple[int, int]
    horizon: int
    stay: bool
    deployment: int = 3

    @cached_property
    def paths(self) -> list[Path]:
        """Every learning path, in lexicographic order of its moves (stay, N, S, E, W)."""
        out: list[Path] = []
        path = [self.start[1] * self.width + self.start[0]]

        def extend(x: int, y: int, left: int) -> None:
            if left == 0:
                out.append(tuple(path))
                return
            for a, (dx, dy) in enumerate(STEPS):
                if a == 0 and not self.stay:
                    continue
                nx, ny = x + dx, y + dy
                if 0 <= nx < self.width and 0 <= ny < self.height:
                    path.append(ny * self.width + nx)
                    extend(nx, ny, left - 1)
                    path.pop()

        extend(*self.start, self.horizon)
        return out

    def moves(self, path: Path) -> tuple[int, ...]:
        """The action indices of a path, from the coordinates of its consecutive cells."""
        out = []
        for here, there in zip(path[:-1], path[1:], strict=True):
            dx = there % self.width - here % self.width
            dy = there // self.width - here // self.width
            out.append(STEPS.index((dx, dy)))
        return tuple(out)

    @cached_property
    def grid(self) -> Gridworld:
        """The engine's grid."""
        return Gridworld(self.width, self.height)

    @cached_property
    def learning(self) -> Phase:
        """The engine's learning phase (the demonstrator's moves)."""
        return Phase(
            self.grid.demonstrator_moves(self.stay), self.grid.index(*self.start), self.horizon
        )

    @cached_property
    def deployment_phase(self) -> Phase:
        """The engine's deployment phase: every move, from every cell."""
        return Phase(self.grid.successors, None, self.deployment)

    def features(self, seed: int, k: int) -> FloatArray:
        """``(S, K)`` RBF features with seeded random centers and width."""
        rng = np.random.default_rng(seed)
        centers = rng.uniform([0, 0], [self.width - 1, self.height - 1], size=(k, 2))
        return rbf_features(self.grid, centers, rng.uniform(0.7, 2.0))

    def game(
        self,
        features: FloatArray,
        rationality: float,
        thetas: FloatArray | None = None,
        settings: Teaching | None = None,
    ) -> Apprenticeship:
        """The engine's game of a batch: ``features`` ``(B, S, K)``, hypotheses ``(B, H, K)``."""
        learning = MaxEnt(self.learning, features, rationality)
        deployment = MaxEnt(self.deployment_phase, features, rationality)
        space = None
        if thetas is not None:
            assert settings is not None
            space = HypothesisSpace(learning, thetas, settings.includes_truth, settings.alpha)
        return Apprenticeship(learning, deployment, space, settings)


def settings_of(
    hypotheses: int,
    *,
    alpha: float = 1.0,
    includes_truth: bool = True,
    demonstration: str = "draw",
    search_etas: tuple[float, ...] = (0.1, 1.0),
) -> Teaching:
    """Teaching settings (the hypothesis seed plays no part: the tests give the spaces)."""
    return Teaching(
        hypotheses=hypotheses,
        includes_truth=includes_truth,
        hypothesis_seed=0,
        alpha=alpha,
        demonstration=demonstration,
        search_etas=search_etas,
    )


def batch_of(array: FloatArray, size: int) -> FloatArray:
    """``size`` copies of one trial's array, stacked on a new first axis."""
    return np.ascontiguousarray(np.broadcast_to(array, (size, *array.shape)))


# ---- the path-by-path reference ---------------------------------------------------------------


def visits(path: Path) -> Path:
    """The multiset of cells ``s_1..s_T`` a path visits, as a sorted tuple (its visit class)."""
    return tuple(sorted(path[1:]))


def class_numbers(setting: Setting) -> dict[Path, int]:
    """The engine's number of each visit class (its order among the candidates), by multiset."""
    cells = VisitClasses.of(setting.learning).cells
    return {tuple(int(c) for c in row): m for m, row in enumerate(cells)}


def exact_counts(paths: list[Path], features: FloatArray) -> FloatArray:
    """``(P, K)`` feature counts ``sum_{t >= 1} phi(s_t)``, each an exactly rounded sum."""
    k = features.shape[1]
    return np.array([[math.fsum(features[list(p[1:]), j]) for j in range(k)] for p in paths])


def log_literal_posterior(counts: FloatArray, thetas: FloatArray, rationality: float) -> FloatArray:
    """``(P, H)`` ``log P_L(h | tau)``: Bayes' rule at each path, ``Z_h`` over the listed paths."""
    scores = rationality * counts @ thetas.T
    log_likelihood = scores - logsumexp(scores, axis=0, keepdims=True)
    return log_likelihood - logsumexp(log_likelihood, axis=1, keepdims=True)


def log_pedagogic(
    counts: FloatArray, thetas: FloatArray, rationality: float, alpha: float
) -> FloatArray:
    """``(P, H)`` ``log P_P(tau | h) = alpha log P_L(h | tau) - log N_h``, ``N_h`` over paths."""
    powered = alpha * log_literal_posterior(counts, thetas, rationality)
    return powered - logsumexp(powered, axis=0, keepdims=True)


def demonstrator_space(theta: FloatArray, space: FloatArray, includes_truth: bool) -> FloatArray:
    """The hypotheses the pedagogic human teaches over, her truth first."""
    if includes_truth:
        np.testing.assert_array_equal(space[0], theta)
        return space
    return np.vstack([theta, space])


def map_regret(
    setting: Setting, features: FloatArray, theta: FloatArray, path: Path, rationality: float
) -> float:
    """One trial's MAP-robot regret after demonstration ``path``, by a call of its own."""
    learning = MaxEnt(setting.learning, features[None], rationality)
    estimate = map_estimate(learning, np.array([path], dtype=np.int64))
    deployment = MaxEnt(setting.deployment_phase, features[None], rationality)
    return float(regret(deployment, theta[None], estimate.theta_hat)[0])


def chi_square_p(paths: NDArray[np.int64], listed: list[Path], probability: FloatArray) -> float:
    """p-value of the drawn ``paths`` against ``probability`` over the ``listed`` paths; cells
    expected fewer than 5 times are pooled into one."""
    index = {path: i for i, path in enumerate(listed)}
    counts = np.bincount([index[tuple(int(c) for c in p)] for p in paths], minlength=len(listed))
    assert counts.sum() == len(paths)  # every draw is a listed path
    expected = probability * len(paths)
    pooled = expected >= 5
    observed = np.append(counts[pooled], counts[~pooled].sum())
    wanted = np.append(expected[pooled], expected[~pooled].sum())
    keep = wanted > 0
    assert observed[~keep].sum() == 0  # nothing drawn where the probability is 0
    _, p = stats.chisquare(observed[keep], wanted[keep] * observed.sum() / wanted[keep].sum())
    return float(p)


CENTER3 = Setting(3, 3, (1, 1), 3, True)
"""81 paths in 47 visit classes."""

SETTINGS: dict[str, Setting] = {
    "3x3-center-3-stay": CENTER3,
    "3x3-corner-4-nostay": Setting(3, 3, (0, 0), 4, False, deployment=4),
    "4x3-3-nostay": Setting(4, 3, (1, 2), 3, False, deployment=4),
    "4x3-4-stay": Setting(4, 3, (1, 2), 4, True),
    "3x3-2-nostay": Setting(3, 3, (2, 1), 2, False, deployment=2),
}


def test_the_reference_moves_follow_the_engine_s_action_order() -> None:
    """The hard-coded move order is the engine's (stay, N, S, E, W), and the listing is every
    path the engine's phase holds, in its move order."""
    assert ACTIONS == ("stay", "N", "S", "E", "W")
    grid = Gridworld(3, 3)
    for a, (dx, dy) in enumerate(STEPS):
        assert grid.successors[grid.index(1, 1), a] == grid.index(1 + dx, 1 + dy)
    for setting in SETTINGS.values():
        np.testing.assert_array_equal(
            VisitClasses.of(setting.learning).paths, np.array(setting.paths)
        )


# ---- 1. the pedagogic human -------------------------------------------------------------------

DRAWS = 20_000
"""Trials of the chi-square test, one draw each."""


@pytest.mark.parametrize("alpha", [0.5, 4.0])
@pytest.mark.parametrize("includes_truth", [True, False])
def test_pedagogic_draws_follow_the_pedagogic_distribution_over_every_path(
    includes_truth: bool, alpha: float
) -> None:
    """20,000 trials (one seed each, all with the same theta, features and hypotheses) draw
    paths whose counts match ``P_P(tau | theta) ∝ P_L(theta | tau)^alpha`` computed path by path
    over the demonstrator's space (chi-square, p > 1e-3); the reference is far from the literal
    distribution, which the same test rejects."""
    setting, rationality = CENTER3, 2.0
    features = setting.features(5, 2)
    rng = np.random.default_rng(11)
    theta = rng.uniform(-1, 1, size=2)
    space = rng.uniform(-1, 1, size=(4, 2))
    if includes_truth:
        space[0] = theta
    settings = settings_of(4, alpha=alpha, includes_truth=includes_truth)
    game = setting.game(batch_of(features, DRAWS), rationality, batch_of(space, DRAWS), settings)
    drawn = teaching.pedagogic_paths(game, batch_of(theta, DRAWS), np.arange(DRAWS))
    assert drawn.shape == (DRAWS, setting.horizon + 1)

    counts = exact_counts(setting.paths, features)
    demonstrator = demonstrator_space(theta, space, includes_truth)
    pedagogic = np.exp(log_pedagogic(counts, demonstrator, rationality, alpha)[:, 0])
    assert pedagogic.sum() == pytest.approx(1.0, abs=1e-12)
    assert chi_square_p(drawn, setting.paths, pedagogic) > 1e-3

    scores = rationality * counts @ theta
    literal = np.exp(scores - logsumexp(scores))
    assert chi_square_p(drawn, setting.paths, literal) < 1e-12


def test_a_pedagogic_draw_inverts_the_class_weights_then_picks_within_the_class() -> None:
    """As documented, a trial's two uniforms from ``human_generator(seed)`` pick, in turn, the
    visit class (by inverting the cumulative class weights ``sum_{tau in m} P_P(tau | theta)``,
    summed path by path, in the engine's class order) and the path within it (the
    ``floor(u n_m)``-th in move order): 300 seeds reproduced exactly."""
    setting, rationality, alpha, batch = CENTER3, 2.0, 2.0, 300
    features = setting.features(5, 2)
    space = np.random.default_rng(12).uniform(-1, 1, size=(4, 2))
    settings = settings_of(4, alpha=alpha)
    game = setting.game(batch_of(features, batch), rationality, batch_of(space, batch), settings)
    seeds = np.arange(batch) * 7 + 3
    drawn = teaching.pedagogic_paths(game, batch_of(space[0], batch), seeds)
    pedagogic = np.exp(
        log_pedagogic(exact_counts(setting.paths, features), space, rationality, alpha)[:, 0]
    )
    numbers = class_numbers(setting)
    members: list[list[Path]] = [[] for _ in numbers]
    weights = np.zeros(len(numbers))
    for path, p in zip(setting.paths, pedagogic, strict=True):
        members[numbers[visits(path)]].append(path)
        weights[numbers[visits(path)]] += p
    cumulative = np.cumsum(weights)
    for seed, got in zip(seeds, drawn, strict=True):
        first, second = human_generator(int(seed)).random(2)
        m = min(
            int(np.searchsorted(cumulative, first * cumulative[-1], side="right")), len(weights) - 1
        )
        n = len(members[m])
        assert tuple(int(c) for c in got) == members[m][min(int(second * n), n - 1)]


def test_leaving_the_truth_out_changes_the_pedagogic_distribution() -> None:
    """The check above can tell the two spaces apart: the demonstrator's distribution over
    ``[theta] + space`` is far from the one over ``space`` with the truth in place of its
    first hypothesis."""
    setting, rationality, alpha = CENTER3, 2.0, 4.0
    features = setting.features(5, 2)
    rng = np.random.default_rng(11)
    theta = rng.uniform(-1, 1, size=2)
    space = rng.uniform(-1, 1, size=(4, 2))
    counts = exact_counts(setting.paths, features)
    outside = np.exp(log_pedagogic(counts, np.vstack([theta, space]), rationality, alpha)[:, 0])
    space[0] = theta
    inside = np.exp(log_pedagogic(counts, space, rationality, alpha)[:, 0])
    assert 0.5 * np.abs(outside - inside).sum() > 0.05


def test_a_pedagogic_path_depends_on_its_seed_alone() -> None:
    """Three trials (each its own features, truth and hypotheses) drawn together equal each
    drawn alone in a batch of one; another seed gives another path for some trial."""
    setting, rationality = SETTINGS["4x3-4-stay"], 1.5
    rng = np.random.default_rng(3)
    features = np.stack([setting.features(seed, 3) for seed in (1, 2, 3)])
    thetas = rng.uniform(-1, 1, size=(3, 5, 3))
    truths = rng.uniform(-1, 1, size=(3, 3))
    seeds = np.array([101, 202, 303])
    for includes_truth in (True, False):
        if includes_truth:
            thetas[:, 0] = truths
        settings = settings_of(5, alpha=2.0, includes_truth=includes_truth)
        together = teaching.pedagogic_paths(
            setting.game(features, rationality, thetas, settings), truths, seeds
        )
        for b in range(3):
            alone = setting.game(features[b : b + 1], rationality, thetas[b : b + 1], settings)
            np.testing.assert_array_equal(
                teaching.pedagogic_paths(alone, truths[b : b + 1], seeds[b : b + 1]),
                together[b : b + 1],
            )
        others = [
            teaching.pedagogic_paths(
                setting.game(features, rationality, thetas, settings), truths, seeds + shift
            )
            for shift in range(1, 6)
        ]
        assert any(not np.array_equal(other, together) for other in others)


@pytest.mark.parametrize("alpha", [0.5, 3.0])
@pytest.mark.parametrize("includes_truth", [True, False])
@pytest.mark.parametrize("name", ["3x3-center-3-stay", "4x3-4-stay", "3x3-corner-4-nostay"])
def test_the_pedagogic_mode_is_the_first_path_most_telling_of_the_truth(
    name: str, includes_truth: bool, alpha: float
) -> None:
    """With ``demonstration = "mode"`` each trial shows the first path, in move order, of those
    maximising ``P_L(theta | tau)`` over the demonstrator's space, whatever its seed (a clear
    maximum: the runner-up class is checked to be at least 1e-9 behind)."""
    setting, rationality, batch = SETTINGS[name], 1.5, 6
    rng = np.random.default_rng(17)
    features = np.stack([setting.features(40 + b, 3) for b in range(batch)])
    thetas = rng.uniform(-1, 1, size=(batch, 4, 3))
    truths = thetas[:, 0].copy() if includes_truth else rng.uniform(-1, 1, size=(batch, 3))
    settings = settings_of(4, alpha=alpha, includes_truth=includes_truth, demonstration="mode")
    game = setting.game(features, rationality, thetas, settings)
    shown = teaching.pedagogic_paths(game, truths, np.arange(batch))
    np.testing.assert_array_equal(
        teaching.pedagogic_paths(game, truths, np.arange(batch) + 1000), shown
    )
    for b in range(batch):
        counts = exact_counts(setting.paths, features[b])
        demonstrator = demonstrator_space(truths[b], thetas[b], includes_truth)
        telling = log_literal_posterior(counts, demonstrator, rationality)[:, 0]
        best = int(np.argmax(telling))  # the first maximiser
        elsewhere = [visits(p) != visits(setting.paths[best]) for p in setting.paths]
        runner_up = telling[elsewhere].max()
        assert telling[best] - runner_up > 1e-9
        assert tuple(shown[b]) == setting.paths[best]


def test_the_pedagogic_mode_is_not_the_literal_mode() -> None:
    """The check above can fail: the most telling path differs from the expert's path (the most
    likely under ``P_L(tau | theta)``) in some trial."""
    setting, rationality = SETTINGS["4x3-4-stay"], 1.5
    rng = np.random.default_rng(17)
    thetas = rng.uniform(-1, 1, size=(6, 4, 3))
    differs = []
    for b in range(6):
        counts = exact_counts(setting.paths, setting.features(40 + b, 3))
        telling = log_literal_posterior(counts, thetas[b], rationality)[:, 0]
        differs.append(int(np.argmax(telling)) != int(np.argmax(counts @ thetas[b, 0])))
    assert any(differs)


@dataclass(frozen=True)
class TiedModes:
    """Trials whose most telling paths tie exactly across classes, and what the mode shows."""

    shown: list[Path]
    """Each checked trial's mode."""
    maximisers: list[list[Path]]
    """Each checked trial's paths maximising ``P_L(theta | tau)``, in move order."""


def tied_modes() -> TiedModes:
    """40 trials on :data:`CENTER3` with the integer feature ``phi(s) = x`` and three hypotheses
    in quarters: every score is exact, so classes with equal counts (e.g. {5, 5, 5} and {2, 5,
    8}) tie bit for bit. Trials where another count vector comes within 1e-9 of the maximum
    ``P_L(theta | tau)`` are left out."""
    setting, batch = CENTER3, 40
    features = setting.grid.cell_coordinates()[:, :1]
    thetas = np.random.default_rng(0).integers(-4, 5, size=(batch, 3, 1)) / 4.0
    game = setting.game(
        batch_of(features, batch), 1.0, thetas, settings_of(3, demonstration="mode")
    )
    shown = teaching.pedagogic_paths(game, thetas[:, 0], np.arange(batch))
    counts = exact_counts(setting.paths, features)
    out = TiedModes([], [])
    for b in range(batch):
        telling = log_literal_posterior(counts, thetas[b], 1.0)[:, 0]
        same = (counts == counts[int(np.argmax(telling))]).all(axis=1)
        if telling.max() - telling[~same].max() < 1e-9:
            continue
        out.shown.append(tuple(int(c) for c in shown[b]))
        out.maximisers.append([p for p, keep in zip(setting.paths, same, strict=True) if keep])
    assert len(out.shown) >= 20
    assert sum(len({visits(p) for p in best}) > 1 for best in out.maximisers) >= 10
    return out


def test_under_exact_ties_the_pedagogic_mode_is_a_maximiser() -> None:
    """Exact ties between classes (:func:`tied_modes`): the mode is one of the paths maximising
    ``P_L(theta | tau)``, the first in move order of its class."""
    found = tied_modes()
    for shown, best in zip(found.shown, found.maximisers, strict=True):
        assert shown in best
        assert shown == next(p for p in best if visits(p) == visits(shown))


def test_under_exact_ties_the_pedagogic_mode_is_the_first_maximiser_in_move_order() -> None:
    """Exact ties between classes (:func:`tied_modes`): as documented, the mode is the first
    path in move order among every path maximising ``P_L(theta | tau)``. In some trial that
    path is not in the lowest-numbered class among the maximisers, so a rule by class would
    fail here."""
    found = tied_modes()
    numbers = class_numbers(CENTER3)
    differ = 0
    for best in found.maximisers:
        first = min({visits(p) for p in best}, key=numbers.__getitem__)
        differ += next(p for p in best if visits(p) == first) != best[0]
    assert differ >= 1
    for shown, best in zip(found.shown, found.maximisers, strict=True):
        assert shown == best[0]


# ---- 2. the regret-optimal human --------------------------------------------------------------


@pytest.mark.parametrize("name", ["3x3-center-3-stay", "4x3-3-nostay", "3x3-corner-4-nostay"])
def test_regret_optimal_on_a_small_phase_is_the_minimum_over_every_path(name: str) -> None:
    """A phase of at most ``EXHAUSTIVE_CLASSES`` classes: each trial's demonstration has the
    least MAP-robot regret of every listed path (each fitted by a call of its own), and among
    equal minima it is the first path (in move order) of the lowest-numbered class. The
    instances are checked to have ties at the minimum and minima that neither the expert nor
    the first path attain."""
    setting, rationality = SETTINGS[name], 1.0
    trials = (0, 1, 4, 5)
    features = np.stack([setting.features(seed, 3) for seed in trials])
    truths = np.stack([np.random.default_rng(seed).uniform(-1, 1, size=3) for seed in trials])
    numbers = class_numbers(setting)
    assert len(numbers) <= teaching.EXHAUSTIVE_CLASSES
    got = teaching.regret_optimal_paths(
        setting.game(features, rationality), truths, np.arange(len(trials))
    )
    assert got.shape == (len(trials), setting.horizon + 1)
    ties, beaten = 0, 0
    for b in range(len(trials)):
        regrets = [
            map_regret(setting, features[b], truths[b], path, rationality) for path in setting.paths
        ]
        least = min(regrets)
        assert map_regret(setting, features[b], truths[b], tuple(got[b]), rationality) == least
        tied = {visits(p) for p, r in zip(setting.paths, regrets, strict=True) if r == least}
        first = min(tied, key=numbers.__getitem__)
        want = next(p for p in setting.paths if visits(p) == first)
        assert tuple(got[b]) == want
        ties += len(tied) > 1
        expert = expert_paths(MaxEnt(setting.learning, features[b][None], 1.0), truths[b][None])
        expert_regret = map_regret(setting, features[b], truths[b], tuple(expert[0]), rationality)
        beaten += least < min(expert_regret, regrets[0])
    assert ties >= 1
    assert beaten >= 1


SEARCHED = Setting(4, 3, (1, 2), 4, True)
"""263 paths in 131 classes: more than the 16 pedagogic candidates."""


ETAS = (0.5, 2.0, 5.0)
"""The trade-offs whose best responses seed the search."""


def search_game(
    with_hypotheses: bool,
) -> tuple[Apprenticeship, FloatArray, FloatArray, FloatArray]:
    """Nine trials of :data:`SEARCHED`: the game, features ``(B, S, K)``, truths ``(B, K)`` and
    hypotheses ``(B, H, K)`` (the truth first), with or without the hypothesis space."""
    trials = (1, 2, 12, 22, 23, 26, 27, 36, 110)
    features = np.stack([SEARCHED.features(seed, 3) for seed in trials])
    thetas = np.stack(
        [np.random.default_rng(seed + 1000).uniform(-1, 1, size=(5, 3)) for seed in trials]
    )
    truths = thetas[:, 0].copy()
    settings = settings_of(5, alpha=2.0, search_etas=ETAS)
    game = SEARCHED.game(features, 1.0, thetas if with_hypotheses else None, settings)
    return game, features, truths, thetas


def starting_candidates(
    with_hypotheses: bool, features: FloatArray, truth: FloatArray, space: FloatArray
) -> list[Path]:
    """The search's starts for one trial, directly: the expert's path, the best response at each
    searched eta and, with hypotheses, the first path of each of the 16 classes with the largest
    ``P_L(theta | tau)`` (by the reference; the 16th is checked to lead the 17th by 1e-9)."""
    model = MaxEnt(SEARCHED.learning, features[None], 1.0)
    starts = [tuple(int(c) for c in expert_paths(model, truth[None])[0])]
    for eta in ETAS:
        found = best_response_paths(model, truth[None], np.array([eta]))[0]
        starts.append(tuple(int(c) for c in found))
    if with_hypotheses:
        numbers = class_numbers(SEARCHED)
        telling = log_literal_posterior(exact_counts(SEARCHED.paths, features), space, 1.0)[:, 0]
        by_class: dict[Path, tuple[float, Path]] = {}
        for path, value in zip(SEARCHED.paths, telling, strict=True):
            by_class.setdefault(visits(path), (float(value), path))
        ranked = sorted(by_class.values(), key=lambda v: (-v[0], numbers[visits(v[1])]))
        assert ranked[15][0] - ranked[16][0] > 1e-9
        starts += [path for _, path in ranked[: teaching.PEDAGOGIC_CANDIDATES]]
    return starts


def neighbours(setting: Setting, path: Path) -> list[Path]:
    """Every listed path whose moves differ from ``path``'s at exactly one step, ordered by that
    step and then by the new move."""
    moves = setting.moves(path)
    found = {}
    for q in setting.paths:
        changed = [
            t for t, (a, b) in enumerate(zip(setting.moves(q), moves, strict=True)) if a != b
        ]
        if len(changed) == 1:
            found[(changed[0], setting.moves(q)[changed[0]])] = q
    return [found[key] for key in sorted(found)]


@dataclass
class TrialRegrets:
    """One trial's MAP-robot regret of any path (:func:`map_regret`), remembered."""

    features: FloatArray
    truth: FloatArray
    known: dict[Path, float]

    def __call__(self, path: Path) -> float:
        path = tuple(int(c) for c in path)
        if path not in self.known:
            self.known[path] = map_regret(SEARCHED, self.features, self.truth, path, 1.0)
        return self.known[path]


def reference_search(regret_of: TrialRegrets, starts: list[Path], rounds: int) -> Path:
    """The documented search, directly: the start with the least regret (the first among
    equals), then up to ``rounds`` moves to the best path one move away (the first among
    equals), each only if it lowers the regret."""
    values = [regret_of(start) for start in starts]
    best, value = starts[int(np.argmin(values))], min(values)
    for _ in range(rounds):
        around = neighbours(SEARCHED, best)
        values = [regret_of(q) for q in around]
        if not min(values) < value:
            break
        best, value = around[int(np.argmin(values))], min(values)
    return best


@pytest.mark.parametrize("with_hypotheses", [True, False])
def test_the_regret_optimal_search_is_never_worse_than_its_starts(
    monkeypatch: pytest.MonkeyPatch, with_hypotheses: bool
) -> None:
    """With the exhaustive search switched off, each trial's demonstration is a listed path
    whose MAP-robot regret is at most the expert's path's, the best response's at every eta
    of ``search_etas`` (each computed directly) and, with hypotheses, the 16 most telling
    classes'. Without teaching settings the search fails."""
    monkeypatch.setattr(teaching, "EXHAUSTIVE_CLASSES", 0)
    game, features, truths, thetas = search_game(with_hypotheses)
    got = teaching.regret_optimal_paths(game, truths, np.arange(len(truths)))
    assert got.shape == (len(truths), SEARCHED.horizon + 1)
    for b in range(len(truths)):
        path = tuple(int(c) for c in got[b])
        assert path in SEARCHED.paths
        found = map_regret(SEARCHED, features[b], truths[b], path, 1.0)
        for start in starting_candidates(with_hypotheses, features[b], truths[b], thetas[b]):
            assert found <= map_regret(SEARCHED, features[b], truths[b], start, 1.0)
    no_settings = SEARCHED.game(features, 1.0)
    with pytest.raises(ValueError):
        teaching.regret_optimal_paths(no_settings, truths, np.arange(len(truths)))


@pytest.mark.parametrize("with_hypotheses", [True, False])
def test_the_regret_optimal_search_is_the_documented_search(
    monkeypatch: pytest.MonkeyPatch, with_hypotheses: bool
) -> None:
    """With the exhaustive search switched off and 0, 1, the default and 100 rounds of local
    moves, each trial's demonstration is :func:`reference_search`'s from the directly computed
    starts; after 100 rounds no listed path one move away has a lower regret. The instances are
    checked to need the expert's start, a later eta's and, with hypotheses, the pedagogic
    candidates, without them more than one round."""
    monkeypatch.setattr(teaching, "EXHAUSTIVE_CLASSES", 0)
    game, features, truths, thetas = search_game(with_hypotheses)
    seeds = np.arange(len(truths))
    regrets = [TrialRegrets(features[b], truths[b], {}) for b in range(len(truths))]
    starts = [
        starting_candidates(with_hypotheses, features[b], truths[b], thetas[b])
        for b in range(len(truths))
    ]
    results: dict[int, list[Path]] = {}
    for rounds in (0, 1, teaching.SEARCH_ROUNDS, 100):
        monkeypatch.setattr(teaching, "SEARCH_ROUNDS", rounds)
        got = teaching.regret_optimal_paths(game, truths, seeds)
        results[rounds] = [reference_search(regrets[b], starts[b], rounds) for b in seeds]
        for b in seeds:
            assert tuple(int(c) for c in got[b]) == results[rounds][b]
    for b, (regret_of, local) in enumerate(zip(regrets, results[100], strict=True)):
        assert all(regret_of(q) >= regret_of(local) for q in neighbours(SEARCHED, local))
        assert regret_of(local) <= regret_of(results[0][b])
    first = [[r(s) for s in trial] for r, trial in zip(regrets, starts, strict=True)]
    assert any(v[0] < min(v[1:]) for v in first)  # the expert's start alone is best
    assert any(min(v[2:4]) < min(v[:2] + v[4:]) for v in first)  # a later eta's
    if with_hypotheses:
        assert any(min(v[4:]) < min(v[:4]) for v in first)
    else:  # more rounds than one
        assert any(r(a) > r(b) for r, a, b in zip(regrets, results[1], results[100], strict=True))


# ---- 3. the literal and the pragmatic robot ---------------------------------------------------


def robot_game(
    setting: Setting, alpha: float, includes_truth: bool
) -> tuple[Apprenticeship, NDArray[np.int64], FloatArray, FloatArray]:
    """Two trials (each its own features and five hypotheses) observed at every listed path:
    the game of ``2 P`` rows, the demonstrations, features ``(2, S, K)``, hypotheses
    ``(2, H, K)``."""
    rows = len(setting.paths)
    features = np.stack([setting.features(seed, 3) for seed in (60, 61)])
    thetas = np.random.default_rng(62).uniform(-1, 1, size=(2, 5, 3))
    settings = settings_of(5, alpha=alpha, includes_truth=includes_truth)
    game = setting.game(
        np.repeat(features, rows, axis=0), 1.5, np.repeat(thetas, rows, axis=0), settings
    )
    demos = np.tile(np.array(setting.paths, dtype=np.int64), (2, 1))
    return game, demos, features, thetas


def assert_posterior_mean(
    got: Estimate,
    weights: FloatArray,
    thetas: FloatArray,
    counts: FloatArray,
    rows: slice,
    rationality: float,
) -> None:
    """``theta_hat`` is ``sum_h w_h theta_h`` at each path, ``log_likelihood`` the MaxEnt
    log-likelihood of the path at ``theta_hat`` (``log Z`` over the listed paths), all
    converged."""
    assert weights.sum(axis=1) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(got.theta_hat[rows], weights @ thetas, rtol=RTOL, atol=ATOL)
    scores = rationality * counts @ got.theta_hat[rows].T  # (path, at the estimate of a path)
    want = np.diag(scores) - logsumexp(scores, axis=0)
    np.testing.assert_allclose(got.log_likelihood[rows], want, rtol=RTOL, atol=ATOL)
    assert got.converged[rows].all()


@pytest.mark.parametrize("alpha", [0.5, 3.0])
@pytest.mark.parametrize("name", ["3x3-center-3-stay", "4x3-4-stay", "3x3-corner-4-nostay"])
def test_the_robots_posterior_means_are_bayes_rule_at_every_path(name: str, alpha: float) -> None:
    """``literal_estimate`` and ``pragmatic_estimate`` at every listed path of two trials: the
    posterior mean with weights ``∝ P_L(tau | theta_h)`` and ``∝ P_L(theta_h | tau)^alpha /
    N_h`` (``N_h`` summed over every listed path) respectively, computed path by path."""
    setting = SETTINGS[name]
    game, demos, features, thetas = robot_game(setting, alpha, True)
    seeds = np.arange(len(demos))
    literal = teaching.literal_estimate(game, demos, seeds)
    pragmatic = teaching.pragmatic_estimate(game, demos, seeds)
    rows = len(setting.paths)
    for t in range(2):
        counts = exact_counts(setting.paths, features[t])
        part = slice(t * rows, (t + 1) * rows)
        literal_weights = np.exp(log_literal_posterior(counts, thetas[t], 1.5))
        assert_posterior_mean(literal, literal_weights, thetas[t], counts, part, 1.5)
        pedagogic = log_pedagogic(counts, thetas[t], 1.5, alpha)
        pragmatic_weights = np.exp(pedagogic - logsumexp(pedagogic, axis=1, keepdims=True))
        assert_posterior_mean(pragmatic, pragmatic_weights, thetas[t], counts, part, 1.5)
    assert np.abs(literal.theta_hat - pragmatic.theta_hat).max() > 1e-2


@pytest.mark.parametrize("includes_truth", [True, False])
def test_the_pragmatic_robot_reads_its_own_space_after_the_human_has_taught(
    includes_truth: bool,
) -> None:
    """The pragmatic posterior's ``N_h`` is over the space's hypotheses even after the pedagogic
    human of the same game has taught (over ``[theta] + space`` when the space leaves the truth
    out): the reference as above."""
    setting, alpha = SETTINGS["4x3-3-nostay"], 3.0
    game, demos, features, thetas = robot_game(setting, alpha, includes_truth)
    rows = len(setting.paths)
    truths = np.repeat(np.array([[0.9, -0.8, 0.3], [-0.2, 0.7, -0.9]]), rows, axis=0)
    if includes_truth:
        truths = game.space().thetas[:, 0]
    teaching.pedagogic_paths(game, truths, np.arange(len(demos)))
    pragmatic = teaching.pragmatic_estimate(game, demos, np.arange(len(demos)))
    for t in range(2):
        counts = exact_counts(setting.paths, features[t])
        pedagogic = log_pedagogic(counts, thetas[t], 1.5, alpha)
        weights = np.exp(pedagogic - logsumexp(pedagogic, axis=1, keepdims=True))
        part = slice(t * rows, (t + 1) * rows)
        assert_posterior_mean(pragmatic, weights, thetas[t], counts, part, 1.5)


def test_the_teaching_players_need_a_hypothesis_space() -> None:
    """A game without hypotheses: both robots and the pedagogic human raise ``ValueError``."""
    setting = CENTER3
    features = batch_of(setting.features(0, 2), 2)
    demos = np.array(setting.paths[:2], dtype=np.int64)
    game = setting.game(features, 1.0, None, settings_of(3))
    theta, seeds = np.zeros((2, 2)), np.arange(2)
    with pytest.raises(ValueError):
        teaching.literal_estimate(game, demos, seeds)
    with pytest.raises(ValueError):
        teaching.pragmatic_estimate(game, demos, seeds)
    with pytest.raises(ValueError):
        teaching.pedagogic_paths(game, theta, seeds)


# ---- 4. single moves --------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(SETTINGS))
def test_single_moves_are_every_path_one_move_away(name: str) -> None:
    """For every listed path: each returned path is listed (valid), its moves (read from the
    coordinates) differ from the input's at exactly one step, none repeats, and together they
    are every listed path that does so."""
    setting = SETTINGS[name]
    for path in setting.paths:
        got = teaching._single_moves(setting.learning, np.array(path, dtype=np.int64))
        assert got.shape[1] == setting.horizon + 1
        rows = [tuple(int(c) for c in row) for row in got]
        assert len(set(rows)) == len(rows)
        moves = setting.moves(path)
        for row in rows:
            assert row in setting.paths
            changed = [
                t for t, (a, b) in enumerate(zip(setting.moves(row), moves, strict=True)) if a != b
            ]
            assert len(changed) == 1
        assert set(rows) == set(neighbours(setting, path))
