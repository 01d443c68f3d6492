"""Exact nearest-feature-count path search (the engine of the best-response human).

Problem: given per-trial cell features :math:`\\phi` (``(S, K)``), a start cell
:math:`s_0`, a horizon ``T`` and a target :math:`g \\in \\mathbb{R}^K`, find

.. math::

    \\tau^\\star = \\arg\\min_{\\tau} \\lVert \\phi(\\tau) - g \\rVert^2, \\qquad
    \\phi(\\tau) = \\sum_{t=1}^{T} \\phi(s_t),

over every available ``T``-step path from :math:`s_0`. The minimum is exact.

Method: branch and bound over path prefixes. For a prefix ending in cell ``s``
with ``r`` steps left and counts ``c``, every completion has counts ``c + f`` with
``f`` in the set :math:`\\mathcal{F}(s, r)` of ``r``-step suffix counts from ``s``.
For any orthonormal basis :math:`W` (rows :math:`w_j`),

.. math::

    \\lVert c + f - g \\rVert^2 = \\sum_j (w_j^\\top f - w_j^\\top (g - c))^2
    \\ge \\sum_j \\operatorname{dist}\\big(w_j^\\top (g - c),
    [\\ell_j(s, r), u_j(s, r)]\\big)^2,

where :math:`\\ell_j, u_j` are the minimum and maximum of :math:`w_j^\\top f` over
:math:`\\mathcal{F}(s, r)`, computed exactly by a min/max dynamic programme. The
bound is the maximum over three bases: the identity (per-feature intervals), a basis
whose first axis is the caller's ``direction`` (for the best response, :math:`\\theta`:
when :math:`g` is far away the objective is nearly linear along it), and the principal
axes of the cell features. A prefix is pruned when its bound exceeds the best complete
path found so far (the incumbent); a
small relative slack guards against pruning on floating-point noise, so no optimal
path is ever cut.

The search is depth-first (compiled with numba), visiting the children of each
prefix in order of increasing bound, so the first complete path is a greedy dive
and the incumbent improves as early as possible. The search itself holds ``O(T K)``
numbers; the suffix extremes of the bound hold ``2 (T + 1) S J K`` (``J = 3`` bases), one
trial's at a time in a table reused trial after trial.

Worst case: when no bound ever prunes, every one of the (at most ``5^T``) paths is
visited: time ``O(5^T K)``. At the paper's size (10x10 grid, 9 steps from the
center, K <= 10) the bounds typically leave a few thousand of the 1.9 million paths; the
nodes visited still grow about fourfold a step (up to 44 million at ``T = 16``, 22 s), so a
pipeline whose human searches is held to
:data:`cirl_study.study.limits.MAX_SEARCH_STEPS` learning steps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from cirl_study.core.maxent import Phase
from cirl_study.core.planning import FloatArray, IntArray

PRUNE_SLACK = 1e-9
"""Relative slack: a prefix is pruned only if ``bound > best * (1 + slack) + slack``."""


@dataclass(frozen=True)
class NearestPaths:
    """Result of :func:`nearest_paths` for a batch of trials.

    Attributes:
        actions: ``(B, T)`` action indices of an optimal path (among exact ties, the first met).
        values: ``(B,)`` the optimal objective
            :math:`\\min_\\tau \\lVert \\phi(\\tau) - g \\rVert^2`.
        visited: ``(B,)`` search nodes visited (a measure of the bounds' strength).
    """

    actions: IntArray
    values: FloatArray
    visited: IntArray


@dataclass(frozen=True)
class _Problem:
    rotated_features: FloatArray  # (B, S, bases, K): W_j phi(s)
    rotated_target: FloatArray  # (B, bases, K): W_j g
    needed: NDArray[np.bool_]  # (T + 1, S): cells a prefix with r steps left can end in


def _orthonormal_basis(first_axis: FloatArray) -> FloatArray:
    """``(B, K, K)`` orthonormal rows whose first row is ``first_axis`` normalised.

    Completes ``first_axis`` with the unit vectors by QR; a zero axis gives the identity.
    """
    batch, k = first_axis.shape
    norm = np.linalg.norm(first_axis, axis=1, keepdims=True)
    axis = np.where(norm > 0, first_axis / np.where(norm > 0, norm, 1.0), np.eye(k)[0])
    # [axis, e_1, ..., e_K] has rank K; QR's first K columns span R^K with axis first.
    stacked = np.concatenate([axis[:, :, None], np.broadcast_to(np.eye(k), (batch, k, k))], 2)
    q, r = np.linalg.qr(stacked)
    q = q * np.sign(r[:, 0, 0])[:, None, None]  # make the first row +axis, not -axis
    return q.transpose(0, 2, 1)[:, :k]


def _principal_axes(features: FloatArray) -> FloatArray:
    """``(B, K, K)`` principal axes (rows) of each trial's centered cell features."""
    centered = features - features.mean(axis=1, keepdims=True)
    _, vectors = np.linalg.eigh(np.matmul(centered.transpose(0, 2, 1), centered))
    return vectors.transpose(0, 2, 1)


@njit(cache=True)
def suffix_extremes(cell_values, successors, horizon, needed, low, high):  # pragma: no cover
    """Min and max of :math:`\\sum_{u=1}^{r} v(s_u)` over ``r``-step paths from each cell.

    Args:
        cell_values: ``(S, M)`` per-cell vectors ``v(s)``; every coordinate is optimised
            separately.
        successors: ``(S, A)`` successor table.
        horizon: largest ``r``.
        needed: ``(horizon + 1, S)`` mask of the ``(r, s)`` entries to compute; a move
            into a cell not needed at ``r - 1`` is unavailable (it cannot end in time), and
            entries that are not needed are left as they were.
        low, high: ``(horizon + 1, S, M)`` outputs; index ``r`` holds the extremes over
            ``r``-step suffixes, ``low[r, s] = min over available s -> s' of v(s') +
            low[r - 1, s']``, and row 0 must hold zeros. One trial's arrays are a few hundred
            kilobytes, reused trial after trial: a batch's would be fresh pages, and
            first-touching them cost several times the programme itself.
    """
    cells, m = cell_values.shape
    for r in range(1, horizon + 1):
        low_prev, high_prev = low[r - 1], high[r - 1]
        low_now, high_now = low[r], high[r]
        for s in range(cells):
            if not needed[r, s]:
                continue
            first = True
            for a in range(successors.shape[1]):
                nxt = successors[s, a]
                if nxt < 0 or not needed[r - 1, nxt]:
                    continue
                value, below, above = cell_values[nxt], low_prev[nxt], high_prev[nxt]
                lowest, highest = low_now[s], high_now[s]
                if first:
                    for i in range(m):
                        lowest[i] = value[i] + below[i]
                        highest[i] = value[i] + above[i]
                    first = False
                    continue
                for i in range(m):  # min and max: no branch on the values
                    lowest[i] = min(lowest[i], value[i] + below[i])
                    highest[i] = max(highest[i], value[i] + above[i])


def _prepare(
    features: FloatArray, target: FloatArray, direction: FloatArray, phase: Phase
) -> _Problem:
    batch, _, k = features.shape
    bases = np.stack(
        [
            np.broadcast_to(np.eye(k), (batch, k, k)),
            _orthonormal_basis(direction),
            _principal_axes(features),
        ],
        axis=1,
    )  # (B, J, K, K), rows of each basis
    flat = bases.reshape(batch, -1, k)  # (B, J*K, K)
    rotated_features = np.matmul(features, flat.transpose(0, 2, 1)).reshape(
        batch, features.shape[1], -1, k
    )
    rotated_target = np.matmul(flat, target[:, :, None]).reshape(batch, -1, k)
    # A prefix with r steps left ends in a cell reachable from the start in T - r steps, on a
    # path that can still end in time.
    return _Problem(rotated_features, rotated_target, phase.reachable[::-1].copy())


@njit(cache=True)
def _bound(counts, target, low, high, remaining, cell, limit):  # pragma: no cover
    """max over bases j of sum_k dist(w_j.(g - c), [low_j, high_j])^2 for one prefix.

    ``counts`` are the prefix's rotated counts ``(J, K)``; ``low[remaining, cell]`` and
    ``high[remaining, cell]`` the suffix extremes from its last cell. Returns early,
    with a valid bound above ``limit``, as soon as one basis exceeds ``limit``.
    """
    bases, k = counts.shape
    lows, highs = low[remaining, cell], high[remaining, cell]
    best = 0.0
    for j in range(bases):
        total = 0.0
        for i in range(k):
            # Branch-free (at most one of the two is positive): which side a coordinate
            # falls on is unpredictable, and a mispredicted branch costs more than both.
            gap = target[j, i] - counts[j, i]
            distance = max(lows[j, i] - gap, 0.0) + max(gap - highs[j, i], 0.0)
            total += distance * distance
        if total > best:
            best = total
            if best > limit:
                return best
    return best


@njit(cache=True)
def _search(successors, start, horizon, rotated_features, rotated_target, needed, slack):
    """Depth-first branch and bound, children visited in order of increasing bound."""
    batch, cells_count, bases, k = rotated_features.shape
    low = np.zeros((horizon + 1, cells_count, bases, k))
    high = np.zeros((horizon + 1, cells_count, bases, k))
    flat = (horizon + 1, cells_count, bases * k)
    actions = successors.shape[1]
    best_actions = np.zeros((batch, horizon), dtype=np.int64)
    best_values = np.empty(batch)
    visited = np.zeros(batch, dtype=np.int64)
    counts = np.zeros((horizon + 1, bases, k))
    cells = np.empty(horizon + 1, dtype=np.int64)
    path = np.empty(horizon, dtype=np.int64)
    order = np.empty((horizon, actions), dtype=np.int64)
    order_bound = np.empty((horizon, actions))
    n_children = np.zeros(horizon, dtype=np.int64)
    position = np.zeros(horizon, dtype=np.int64)
    child = np.empty((bases, k))
    for b in range(batch):
        feats, target = rotated_features[b], rotated_target[b]
        suffix_extremes(
            feats.reshape((cells_count, bases * k)),
            successors,
            horizon,
            needed,
            low.reshape(flat),
            high.reshape(flat),
        )
        best = np.inf
        cells[0] = start
        depth = 0
        fresh = True  # the children of the prefix ending at cells[depth] are not yet listed
        while depth >= 0:
            if fresh:
                remaining = horizon - depth - 1
                m = 0
                for a in range(actions):
                    nxt = successors[cells[depth], a]
                    if nxt < 0 or not needed[remaining, nxt]:
                        continue
                    for j in range(bases):
                        for i in range(k):
                            child[j, i] = counts[depth, j, i] + feats[nxt, j, i]
                    if remaining == 0:  # a complete path: exact objective (identity basis)
                        visited[b] += 1
                        value = 0.0
                        for i in range(k):
                            value += (child[0, i] - target[0, i]) ** 2
                        if value < best:
                            best = value
                            path[depth] = a
                            for t in range(horizon):
                                best_actions[b, t] = path[t]
                        continue
                    limit = best * (1 + slack) + slack
                    bound = _bound(child, target, low, high, remaining, nxt, limit)
                    if bound > limit:
                        continue
                    pos = m  # insertion sort by bound; ties keep action order
                    while pos > 0 and order_bound[depth, pos - 1] > bound:
                        order[depth, pos] = order[depth, pos - 1]
                        order_bound[depth, pos] = order_bound[depth, pos - 1]
                        pos -= 1
                    order[depth, pos] = a
                    order_bound[depth, pos] = bound
                    m += 1
                n_children[depth] = m
                position[depth] = 0
                fresh = False
            index = position[depth]
            # Children are sorted by bound: once one is pruned, so are the rest.
            if index >= n_children[depth] or order_bound[depth, index] > best * (1 + slack) + slack:
                depth -= 1
                continue
            position[depth] += 1
            a = order[depth, index]
            nxt = successors[cells[depth], a]
            path[depth] = a
            for j in range(bases):
                for i in range(k):
                    counts[depth + 1, j, i] = counts[depth, j, i] + feats[nxt, j, i]
            visited[b] += 1
            depth += 1
            cells[depth] = nxt
            fresh = True
        best_values[b] = best
    return best_actions, best_values, visited


def nearest_paths(
    features: FloatArray,
    target: FloatArray,
    phase: Phase,
    direction: FloatArray | None = None,
) -> NearestPaths:
    """Exact :math:`\\arg\\min_\\tau \\lVert \\phi(\\tau) - g \\rVert^2` for a batch of trials.

    Args:
        features: ``(B, S, K)`` per-trial cell features.
        target: ``(B, K)`` targets ``g``.
        phase: the paths searched: ``phase.horizon >= 1`` moves from ``phase.start``.
        direction: ``(B, K)`` first axis of the rotated bound (defaults to ``target``).
    """
    if phase.horizon < 1:
        raise ValueError(f"horizon must be at least 1, got {phase.horizon}")
    target = np.asarray(target, dtype=np.float64)
    if direction is None:
        direction = target
    problem = _prepare(
        np.asarray(features, dtype=np.float64), target, np.asarray(direction, float), phase
    )
    return NearestPaths(
        *_search(
            phase.successors,
            phase.start_cell,
            phase.horizon,
            problem.rotated_features,
            problem.rotated_target,
            problem.needed,
            PRUNE_SLACK,
        )
    )
