"""Independent brute-force references for the core engine (no code shared with ``cirl_study``).

Everything here follows the study contract (``docs/design.md`` §1-4) by the most direct route:
every path of ``T`` steps is enumerated, and each quantity is computed from its definition over
that list of paths. Nothing is clever; sums that decide a comparison use :func:`math.fsum`.

Notation (the paper's): a path ``tau = (s_0, ..., s_T)``, its feature counts
``phi(tau) = sum_{t=1..T} phi(s_t)`` (start cell not counted), its reward ``theta . phi(tau)``,
the MaxEnt model ``P(tau | s_0, theta, lambda) = exp(lambda theta . phi(tau)) / Z(s_0)``.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from fractions import Fraction

import numpy as np
from hypothesis import strategies as st

# docs/design.md §1: actions in this order; a step is (dx, dy).
ACTIONS: tuple[str, ...] = ("stay", "N", "S", "E", "W")
STEPS: dict[str, tuple[int, int]] = {
    "stay": (0, 0),
    "N": (0, 1),
    "S": (0, -1),
    "E": (1, 0),
    "W": (-1, 0),
}


# --------------------------------------------------------------------------------------------
# The grid
# --------------------------------------------------------------------------------------------


def cell(width: int, x: int, y: int) -> int:
    """Flat index ``y * width + x`` of cell ``[x, y]``."""
    return y * width + x


def xy(width: int, index: int) -> tuple[int, int]:
    """Cell ``[x, y]`` of a flat index."""
    return index % width, index // width


def move(width: int, height: int, index: int, action: str) -> int | None:
    """Successor of ``index`` under ``action``, or ``None`` if the move leaves the grid."""
    x, y = xy(width, index)
    dx, dy = STEPS[action]
    nx, ny = x + dx, y + dy
    if 0 <= nx < width and 0 <= ny < height:
        return cell(width, nx, ny)
    return None


def move_table(width: int, height: int) -> np.ndarray:
    """``(S, 5)`` successor table in ``ACTIONS`` order, ``-1`` for an unavailable move."""
    table = np.full((width * height, len(ACTIONS)), -1, dtype=np.int64)
    for s in range(width * height):
        for a, name in enumerate(ACTIONS):
            nxt = move(width, height, s, name)
            if nxt is not None:
                table[s, a] = nxt
    return table


def rbf_features(
    width: int, height: int, centers: Sequence[Sequence[float]], sigma: float
) -> np.ndarray:
    """``(S, K)`` matrix ``phi_k(s) = exp(-||s - c_k||^2 / (2 sigma^2))``, one cell at a time."""
    rows = []
    for s in range(width * height):
        x, y = xy(width, s)
        rows.append(
            [math.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2.0 * sigma**2)) for cx, cy in centers]
        )
    return np.array(rows, dtype=float).reshape(width * height, len(centers))


# --------------------------------------------------------------------------------------------
# Paths
# --------------------------------------------------------------------------------------------


def enumerate_paths(width: int, height: int, start: int, horizon: int) -> list[tuple[int, ...]]:
    """Every available path of ``horizon`` steps from ``start``, via ``itertools.product``.

    Paths come in lexicographic order of their action sequences (``ACTIONS`` order).
    """
    paths = []
    for actions in itertools.product(ACTIONS, repeat=horizon):
        states = [start]
        for name in actions:
            nxt = move(width, height, states[-1], name)
            if nxt is None:
                break
            states.append(nxt)
        else:
            paths.append(tuple(states))
    return paths


@functools.lru_cache(maxsize=8)
def _path_tree(
    width: int, height: int, start: int, horizon: int
) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """All paths as a tree, level by level: for step ``t``, each prefix's parent and last cell.

    Level ``t`` lists the prefixes ``(s_0..s_t)`` in lexicographic action order, as the index
    of their parent prefix in level ``t - 1`` and the cell ``s_t``.
    """
    table = move_table(width, height)
    last = np.array([start])
    levels = []
    for _ in range(horizon):
        nxt = table[last]  # (P, 5): row-major = prefix-major, then action order
        valid = (nxt >= 0).ravel()
        parents = np.repeat(np.arange(len(last)), len(ACTIONS))[valid]
        last = nxt.ravel()[valid]
        levels.append((parents, last))
    return tuple(levels)


@functools.lru_cache(maxsize=8)
def enumerate_paths_array(width: int, height: int, start: int, horizon: int) -> np.ndarray:
    """The same paths as :func:`enumerate_paths`, in the same order, built level by level.

    Returns a read-only ``(P, horizon + 1)`` int16 array; fast enough for the paper's grid
    (10 x 10, 9 steps: about 1.9 million paths).
    """
    paths = np.array([[start]], dtype=np.int16)
    for parents, cells in _path_tree(width, height, start, horizon):
        paths = np.concatenate([paths[parents], cells[:, None].astype(np.int16)], axis=1)
    paths.setflags(write=False)
    return paths


def feature_counts_fast(
    width: int, height: int, start: int, horizon: int, features: np.ndarray
) -> np.ndarray:
    """:func:`feature_counts` of :func:`enumerate_paths_array`, prefix by prefix down the tree."""
    counts = np.zeros((1, features.shape[1]))
    for parents, cells in _path_tree(width, height, start, horizon):
        counts = counts[parents] + features[cells]
    return counts


def count_paths(width: int, height: int, start: int, horizon: int) -> int:
    """Number of available paths, by exact integer powers of the move matrix (no enumeration)."""
    n = width * height
    counts = [0] * n
    counts[start] = 1
    for _ in range(horizon):
        nxt = [0] * n
        for s in range(n):
            for name in ACTIONS:
                t = move(width, height, s, name)
                if t is not None:
                    nxt[t] += counts[s]
        counts = nxt
    return sum(counts)


def is_path(width: int, height: int, states: Sequence[int], start: int, horizon: int) -> bool:
    """Whether ``states`` is an available path of ``horizon`` steps from ``start``."""
    if len(states) != horizon + 1 or int(states[0]) != start:
        return False
    return all(
        any(move(width, height, int(a), name) == int(b) for name in ACTIONS)
        for a, b in itertools.pairwise(states)
    )


def feature_counts(paths: Sequence[Sequence[int]] | np.ndarray, features: np.ndarray) -> np.ndarray:
    """``(P, K)`` feature counts ``phi(tau) = sum_{t=1..T} phi(s_t)``; the start is not counted."""
    paths = np.asarray(paths)
    total = np.zeros((paths.shape[0], features.shape[1]))
    for t in range(1, paths.shape[1]):
        total += features[paths[:, t]]
    return total


def path_rewards(counts: np.ndarray, theta: Sequence[float]) -> np.ndarray:
    """``(P,)`` rewards ``theta . phi(tau)``, each an exactly rounded sum."""
    theta = np.asarray(theta, dtype=float)
    return np.array([math.fsum(row * theta) for row in counts])


# --------------------------------------------------------------------------------------------
# The MaxEnt trajectory model (docs/design.md §2)
# --------------------------------------------------------------------------------------------


def logsumexp(values: np.ndarray) -> float:
    """``log sum exp(values)`` with the maximum factored out and an exactly rounded sum."""
    m = float(np.max(values))
    return m + math.log(math.fsum(np.exp(values - m)))


def log_partition(counts: np.ndarray, theta: Sequence[float], rationality: float) -> float:
    """``log Z = log sum_tau exp(lambda theta . phi(tau))`` over the enumerated paths."""
    return logsumexp(rationality * path_rewards(counts, theta))


def path_log_probs(counts: np.ndarray, theta: Sequence[float], rationality: float) -> np.ndarray:
    """``(P,)`` ``log P(tau) = lambda theta . phi(tau) - log Z``."""
    scores = rationality * path_rewards(counts, theta)
    return scores - logsumexp(scores)


def expected_features(counts: np.ndarray, theta: Sequence[float], rationality: float) -> np.ndarray:
    """``(K,)`` ``phi_theta = E[phi(tau) | theta, lambda] = sum_tau P(tau) phi(tau)``."""
    p = np.exp(path_log_probs(counts, theta, rationality))
    return np.array([math.fsum(p * counts[:, k]) for k in range(counts.shape[1])])


def feature_covariance(
    counts: np.ndarray, theta: Sequence[float], rationality: float
) -> np.ndarray:
    """``(K, K)`` ``Cov[phi(tau) | theta, lambda]`` by summing over the enumerated paths."""
    p = np.exp(path_log_probs(counts, theta, rationality))
    centered = counts - expected_features(counts, theta, rationality)
    k = counts.shape[1]
    return np.array(
        [[math.fsum(p * centered[:, i] * centered[:, j]) for j in range(k)] for i in range(k)]
    )


def log_likelihood(
    demo_counts: Sequence[float], counts: np.ndarray, theta: Sequence[float], rationality: float
) -> float:
    """MaxEnt log-likelihood ``lambda theta . phi(tau_demo) - log Z(theta)`` of a demonstration."""
    score = rationality * math.fsum(np.asarray(demo_counts) * np.asarray(theta, dtype=float))
    return score - log_partition(counts, theta, rationality)


def occupancy(paths: np.ndarray, log_probs: np.ndarray, num_cells: int) -> np.ndarray:
    """``(T+1, S)`` probability of being in each cell at each time, summed over paths."""
    p = np.exp(log_probs)
    out = np.zeros((paths.shape[1], num_cells))
    for t in range(paths.shape[1]):
        for s in range(num_cells):
            out[t, s] = math.fsum(p[paths[:, t] == s])
    return out


# --------------------------------------------------------------------------------------------
# The humans (docs/design.md §3)
# --------------------------------------------------------------------------------------------


def expert(counts: np.ndarray, theta: Sequence[float]) -> tuple[int, float]:
    """Index and reward of the path maximising ``theta . phi(tau)``."""
    rewards = path_rewards(counts, theta)
    best = int(np.argmax(rewards))
    return best, float(rewards[best])


def best_response_objective(
    counts: np.ndarray,
    theta: Sequence[float],
    eta: float,
    phi_theta: Sequence[float],
) -> np.ndarray:
    """``(P,)`` the paper's objective ``theta . phi(tau) - eta ||phi_theta - phi(tau)||^2``."""
    diff = np.asarray(phi_theta)[None, :] - counts
    return np.array(
        [
            math.fsum(row * np.asarray(theta, dtype=float)) - eta * math.fsum(d * d)
            for row, d in zip(counts, diff, strict=True)
        ]
    )


def best_response(
    counts: np.ndarray, theta: Sequence[float], eta: float, rationality: float
) -> tuple[int, float]:
    """Index and objective value of the path maximising the paper's best-response objective.

    ``phi_theta`` is the MaxEnt expectation over the same enumerated paths.
    """
    phi_theta = expected_features(counts, theta, rationality)
    objective = best_response_objective(counts, theta, eta, phi_theta)
    best = int(np.argmax(objective))
    return best, float(objective[best])


# Fast variants for the paper's size (about 1.9 million paths): plain numpy, no fsum.


def expert_fast(counts: np.ndarray, theta: Sequence[float]) -> tuple[int, float]:
    """:func:`expert` with a numpy dot product (for millions of paths)."""
    rewards = counts @ np.asarray(theta, dtype=float)
    best = int(np.argmax(rewards))
    return best, float(rewards[best])


def expected_features_fast(
    counts: np.ndarray, theta: Sequence[float], rationality: float
) -> np.ndarray:
    """:func:`expected_features` with numpy sums (for millions of paths)."""
    scores = rationality * (counts @ np.asarray(theta, dtype=float))
    weights = np.exp(scores - scores.max())
    return (weights @ counts) / weights.sum()


def log_likelihood_fast(
    demo_counts: Sequence[float], counts: np.ndarray, theta: Sequence[float], rationality: float
) -> float:
    """:func:`log_likelihood` with numpy sums (for millions of paths)."""
    theta = np.asarray(theta, dtype=float)
    scores = rationality * (counts @ theta)
    top = scores.max()
    log_z = top + math.log(np.exp(scores - top).sum())
    return rationality * float(np.asarray(demo_counts) @ theta) - log_z


def best_response_fast(
    counts: np.ndarray, theta: Sequence[float], eta: float, rationality: float
) -> tuple[int, float, np.ndarray]:
    """:func:`best_response` with numpy sums; also returns ``phi_theta``."""
    theta = np.asarray(theta, dtype=float)
    phi_theta = expected_features_fast(counts, theta, rationality)
    diff = counts - phi_theta
    objective = counts @ theta - eta * np.einsum("pk,pk->p", diff, diff)
    best = int(np.argmax(objective))
    return best, float(objective[best]), phi_theta


# --------------------------------------------------------------------------------------------
# Hard planning and the measures (docs/design.md §4)
# --------------------------------------------------------------------------------------------


def optimal_values(
    width: int, height: int, features: np.ndarray, theta: Sequence[float], horizon: int
) -> np.ndarray:
    """``(S,)`` ``V*_theta(s) = max over paths from s of theta . phi(tau)``, by enumeration."""
    out = np.zeros(width * height)
    for s in range(width * height):
        counts = feature_counts(enumerate_paths(width, height, s, horizon), features)
        out[s] = path_rewards(counts, theta).max()
    return out


def greedy_actions(
    width: int, height: int, features: np.ndarray, theta: Sequence[float], horizon: int
) -> np.ndarray:
    """``(T, S)`` an optimal time-indexed policy, action indices, ties to the lowest index.

    At step ``t`` in cell ``s`` the action maximises ``r(s') + V*_{T-t-1}(s')``, where the
    continuation value is itself a maximum over enumerated paths. Values within ``1e-12`` of
    the largest, relative to the largest magnitude among the cell's values, count as ties.
    """
    rewards = features @ np.asarray(theta, dtype=float)
    future = {
        steps: optimal_values(width, height, features, theta, steps) for steps in range(horizon)
    }
    actions = np.zeros((horizon, width * height), dtype=np.int64)
    for t in range(horizon):
        cont = future[horizon - t - 1]
        for s in range(width * height):
            q = {}
            for a, name in enumerate(ACTIONS):
                nxt = move(width, height, s, name)
                if nxt is not None:
                    q[a] = rewards[nxt] + cont[nxt]
            top = max(q.values())
            tol = 1e-12 * max(abs(v) for v in q.values())
            actions[t, s] = min(a for a, v in q.items() if v >= top - tol)
    return actions


def policy_value(
    width: int,
    height: int,
    features: np.ndarray,
    theta: Sequence[float],
    actions: np.ndarray,
    start: int,
) -> float:
    """Reward under ``theta`` of following a deterministic time-indexed policy from ``start``.

    ``actions[t, s]`` is the action index taken at step ``t`` in cell ``s``; the path is rolled
    out and its cells ``s_1..s_T`` are summed.
    """
    rewards = features @ np.asarray(theta, dtype=float)
    s, collected = start, []
    for t in range(actions.shape[0]):
        nxt = move(width, height, s, ACTIONS[int(actions[t, s])])
        if nxt is None:
            raise ValueError(f"policy takes an unavailable move at step {t} in cell {s}")
        s = nxt
        collected.append(rewards[s])
    return math.fsum(collected)


def regret(
    width: int,
    height: int,
    features: np.ndarray,
    theta: Sequence[float],
    theta_hat: Sequence[float],
    horizon: int,
    actions: np.ndarray | None = None,
) -> float:
    """Mean over all starts of ``V*_theta(s) - V^{pi_theta_hat}_theta(s)``.

    ``pi_theta_hat`` is ``actions`` if given, else the optimal policy for ``theta_hat`` that
    shares its mass evenly among tied moves (:func:`shared_policy_value`, docs/design.md §1).
    """
    best = optimal_values(width, height, features, theta, horizon)
    if actions is None:
        table = move_table(width, height)
        true, planned = features @ np.asarray(theta), features @ np.asarray(theta_hat)
        achieved = [
            shared_policy_value(table, true, planned, s, horizon, ()) for s in range(len(best))
        ]
    else:
        achieved = [
            policy_value(width, height, features, theta, actions, s) for s in range(len(best))
        ]
    gaps = [best[s] - achieved[s] for s in range(len(best))]
    return math.fsum(gaps) / len(gaps)


def kl_per_start(
    width: int,
    height: int,
    features: np.ndarray,
    theta: Sequence[float],
    theta_hat: Sequence[float],
    horizon: int,
    rationality: float,
) -> np.ndarray:
    """``(S,)`` ``KL(P(.|s, theta, lambda) || P(.|s, theta_hat, lambda))``, summing over paths."""
    out = np.zeros(width * height)
    for s in range(width * height):
        counts = feature_counts(enumerate_paths(width, height, s, horizon), features)
        logp = path_log_probs(counts, theta, rationality)
        logq = path_log_probs(counts, theta_hat, rationality)
        out[s] = math.fsum(np.exp(logp) * (logp - logq))
    return out


def kl(
    width: int,
    height: int,
    features: np.ndarray,
    theta: Sequence[float],
    theta_hat: Sequence[float],
    horizon: int,
    rationality: float,
) -> float:
    """Mean over all starts of the enumerated trajectory KL divergence."""
    per_start = kl_per_start(width, height, features, theta, theta_hat, horizon, rationality)
    return math.fsum(per_start) / len(per_start)


def reward_l2(features: np.ndarray, theta: Sequence[float], theta_hat: Sequence[float]) -> float:
    """``||Phi theta - Phi theta_hat||_2`` over all cells, with exact rational arithmetic."""
    diff = [Fraction(a) - Fraction(b) for a, b in zip(theta, theta_hat, strict=True)]
    total = Fraction(0)
    for row in features:
        r = sum((Fraction(float(f)) * d for f, d in zip(row, diff, strict=True)), Fraction(0))
        total += r * r
    return math.sqrt(total)


# --------------------------------------------------------------------------------------------
# Random small instances for property-based tests
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Instance:
    """A small random game: grid, RBF features, start cell, horizon, reward and rationality."""

    width: int
    height: int
    start: int
    horizon: int
    centers: tuple[tuple[float, float], ...]
    sigma: float
    theta: tuple[float, ...]
    rationality: float

    @property
    def num_cells(self) -> int:
        """``S = width * height``."""
        return self.width * self.height

    @functools.cached_property
    def features(self) -> np.ndarray:
        """``(S, K)`` RBF features."""
        return rbf_features(self.width, self.height, self.centers, self.sigma)

    @functools.cached_property
    def paths(self) -> np.ndarray:
        """``(P, T + 1)`` every path from the start."""
        return np.array(enumerate_paths(self.width, self.height, self.start, self.horizon))

    @functools.cached_property
    def counts(self) -> np.ndarray:
        """``(P, K)`` feature counts of :attr:`paths`."""
        return feature_counts(self.paths, self.features)


_unit = st.floats(min_value=-1.0, max_value=1.0, allow_nan=False, allow_subnormal=False)


@st.composite
def instances(
    draw: st.DrawFn,
    max_side: int = 4,
    max_horizon: int = 4,
    max_features: int = 3,
    log10_rationality: tuple[float, float] = (-4.0, 3.0),
) -> Instance:
    """Hypothesis strategy for a small :class:`Instance` (at most a few thousand paths)."""
    width = draw(st.integers(1, max_side))
    height = draw(st.integers(1 if width > 1 else 2, max_side))
    k = draw(st.integers(1, max_features))
    coord = st.tuples(st.floats(-0.5, width - 0.5), st.floats(-0.5, height - 0.5))
    return Instance(
        width=width,
        height=height,
        start=draw(st.integers(0, width * height - 1)),
        horizon=draw(st.integers(1, max_horizon)),
        centers=tuple(draw(st.lists(coord, min_size=k, max_size=k))),
        sigma=draw(st.floats(0.5, 3.0)),
        theta=tuple(draw(st.lists(_unit, min_size=k, max_size=k))),
        rationality=10.0 ** draw(st.floats(*log10_rationality)),
    )


def random_game(
    width: int, height: int, start: int, horizon: int, num_features: int, seed: int
) -> tuple[np.random.Generator, np.ndarray, np.ndarray, np.ndarray]:
    """A seeded random game: ``(rng, features (S, K), every path (N, T + 1), their counts)``.

    Centers uniform over the grid's extent, ``sigma`` uniform on ``[0.8, 2]``; ``rng`` is
    left where the draw ended, for the caller's further draws.
    """
    rng = np.random.default_rng(seed)
    centers = rng.uniform([0, 0], [width - 1, height - 1], size=(num_features, 2))
    features = rbf_features(width, height, centers, rng.uniform(0.8, 2.0))
    paths = np.array(enumerate_paths(width, height, start, horizon))
    return rng, features, paths, feature_counts(paths, features)


# --------------------------------------------------------------------------------------------
# Episodes that end at a goal, and policies that share ties (docs/design.md §1, §4)
# --------------------------------------------------------------------------------------------


def episode_paths(
    table: np.ndarray, start: int, horizon: int, goals: Sequence[int]
) -> list[tuple[int, ...]]:
    """Every path from ``start`` over the move table ``table`` (``-1`` unavailable): with
    ``goals``, each path of at most ``horizon`` moves that ends on entering a goal and enters
    none before; without, every ``horizon``-move path. By recursion over moves."""
    goals = set(goals)
    found: list[tuple[int, ...]] = []

    def extend(path: tuple[int, ...]) -> None:
        if goals and path[-1] in goals and len(path) > 1:
            found.append(path)
            return
        if len(path) == horizon + 1:
            if not goals:
                found.append(path)
            return
        for nxt in table[path[-1]]:
            if nxt >= 0:
                extend((*path, int(nxt)))

    extend((start,))
    return found


def episode_counts(paths: Sequence[Sequence[int]], features: np.ndarray) -> np.ndarray:
    """``(N, K)`` counts of paths of any lengths, the start cell not counted."""
    return np.array([features[list(path[1:])].sum(axis=0) for path in paths])


def best_episode_value(
    table: np.ndarray, rewards: np.ndarray, start: int, horizon: int, goals: Sequence[int]
) -> float:
    """``max`` over :func:`episode_paths` from ``start`` of the summed rewards (or ``-inf``)."""
    paths = episode_paths(table, start, horizon, goals)
    return max((math.fsum(rewards[list(p[1:])]) for p in paths), default=-math.inf)


def shared_policy_value(
    table: np.ndarray,
    true_rewards: np.ndarray,
    planned_rewards: np.ndarray,
    start: int,
    horizon: int,
    goals: Sequence[int],
    tolerance: float = 2.0**-40,
) -> float:
    """Value under ``true_rewards`` of the policy optimal for ``planned_rewards`` that shares
    its mass evenly among tied moves: the sum over every path of the tie tree of its
    probability times its true reward. A move's value is its planned reward plus the best
    planned value of the episodes after it (by enumeration); a move within ``tolerance``
    (relative to ``horizon * max |planned|``) of the best is tied."""
    goals = tuple(goals)
    scale = tolerance * horizon * float(np.abs(planned_rewards).max())

    def move_values(cell: int, left: int) -> dict[int, float]:
        values = {}
        for nxt in table[cell]:
            if nxt < 0:
                continue
            nxt = int(nxt)
            if goals and nxt in goals:
                after = 0.0
            elif left == 1:
                after = -math.inf if goals else 0.0
            else:
                after = best_episode_value(table, planned_rewards, nxt, left - 1, goals)
            values[nxt] = planned_rewards[nxt] + after
        return values

    def value(cell: int, left: int) -> float:
        if left == 0 or (goals and cell in goals):
            return 0.0
        options = move_values(cell, left)
        best = max(options.values())
        tied = [nxt for nxt, v in options.items() if v >= best - scale]
        return math.fsum(true_rewards[n] + value(n, left - 1) for n in tied) / len(tied)

    return value(start, horizon)
