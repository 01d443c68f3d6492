"""Finite-horizon planning on the gridworld, batched over reward vectors.

Every function works on a batch of ``B`` problems at once: rewards are ``(B, S)``
arrays (one reward per cell), and the grid's moves are the ``(S, A)`` successor
table of :class:`cirl_study.core.gridworld.Gridworld` (``-1`` where a move is
unavailable). Entering cell ``s'`` earns ``r(s')``, so a path
:math:`\\tau = (s_0, \\dots, s_T)` earns :math:`\\sum_{t=1}^T r(s_t)`.

Maximum-entropy (soft) planning with rationality :math:`\\lambda` (docs/design.md §2):

.. math::

    V_T = 0, \\quad Q_t(s, a) = \\lambda r(s') + V_{t+1}(s'), \\quad
    V_t(s) = \\log \\sum_a e^{Q_t(s, a)}, \\quad \\pi_t(a \\mid s) = e^{Q_t(s, a) - V_t(s)},

so that :math:`P(\\tau \\mid s_0) = \\exp(\\lambda\\, r(\\tau) - V_0(s_0))` over all available
paths: :math:`V_0(s_0)` is the log-partition function :math:`\\log Z`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class SoftPlan:
    """Result of :func:`soft_value_iteration`.

    Attributes:
        log_policy: ``(T, B, S, A)`` :math:`\\log \\pi_t(a \\mid s)`, ``-inf`` where unavailable.
        policy: ``(T, B, S, A)`` action probabilities :math:`\\pi_t(a \\mid s)`.
        values: ``(T + 1, B, S)`` soft values :math:`V_t(s)`; ``values[0]`` is :math:`\\log Z`.
    """

    log_policy: FloatArray
    policy: FloatArray
    values: FloatArray


@dataclass(frozen=True)
class HardPlan:
    """Result of :func:`optimal_plan`.

    Attributes:
        values: ``(T + 1, B, S)`` optimal values :math:`V^*_t(s)`.
        actions: ``(T, B, S)`` optimal action index at each step (lowest index on exact
            ties).
    """

    values: FloatArray
    actions: IntArray


@njit(cache=True)
def reachable_cells(successors, start, horizon):  # pragma: no cover - compiled
    """``(T + 1, S)`` mask: ``[t, s]`` is true iff ``s`` can be reached in exactly ``t`` steps."""
    cells, actions = successors.shape
    reachable = np.zeros((horizon + 1, cells), dtype=np.bool_)
    reachable[0, start] = True
    for t in range(horizon):
        for s in range(cells):
            if reachable[t, s]:
                for a in range(actions):
                    if successors[s, a] >= 0:
                        reachable[t + 1, successors[s, a]] = True
    return reachable


@njit(cache=True)
def finishing_cells(successors, horizon, ends):  # pragma: no cover - compiled
    """``(T + 1, S)`` mask: ``[t, s]`` is true iff some path of ``T - t`` moves from ``s`` ends
    in a cell of ``ends (S,)`` (all true when every cell ends a path)."""
    cells, actions = successors.shape
    finishing = np.zeros((horizon + 1, cells), dtype=np.bool_)
    finishing[horizon] = ends
    for t in range(horizon - 1, -1, -1):
        for s in range(cells):
            for a in range(actions):
                nxt = successors[s, a]
                if nxt >= 0 and finishing[t + 1, nxt]:
                    finishing[t, s] = True
                    break
    return finishing


@njit(cache=True)
def soft_backup(
    scaled, successors, horizon, values, log_policy, policy, needed
):  # pragma: no cover
    """Soft value iteration for one reward vector, written into the output arrays.

    ``scaled`` is :math:`\\lambda r` ``(S,)``; fills ``values (T+1, S)``,
    ``log_policy (T, S, A)`` and ``policy (T, S, A)`` (``-inf`` / 0 where unavailable)
    at the steps and cells where ``needed (T + 1, S)`` is true (all of them, or those
    reachable from the start on a path that can still end in time,
    :attr:`cirl_study.core.maxent.Phase.reachable`). A move into a cell that is not needed at
    the next step is unavailable there: no path that takes it ends in time. Entries that are
    not needed are left undefined.
    """
    cells, actions = successors.shape
    values[horizon, :] = 0.0
    for t in range(horizon - 1, -1, -1):
        for s in range(cells):
            if not needed[t, s]:
                continue
            top = -np.inf
            for a in range(actions):
                nxt = successors[s, a]
                if nxt >= 0 and needed[t + 1, nxt]:
                    q = scaled[nxt] + values[t + 1, nxt]
                    log_policy[t, s, a] = q
                    if q > top:
                        top = q
                else:
                    log_policy[t, s, a] = -np.inf
            total = 0.0
            for a in range(actions):
                if successors[s, a] >= 0:
                    weight = np.exp(log_policy[t, s, a] - top)
                    policy[t, s, a] = weight
                    total += weight
                else:
                    policy[t, s, a] = 0.0
            value = top + np.log(total)
            values[t, s] = value
            for a in range(actions):
                policy[t, s, a] /= total
                log_policy[t, s, a] -= value


@njit(cache=True)
def _soft_value_iteration(scaled, successors, horizon, live):  # pragma: no cover - compiled
    """Batch-major ``(B, T + 1, S)``, ``(B, T, S, A)`` x 2 results of :func:`soft_backup`."""
    batch, cells = scaled.shape
    actions = successors.shape[1]
    values = np.empty((batch, horizon + 1, cells))
    log_policy = np.empty((batch, horizon, cells, actions))
    policy = np.empty((batch, horizon, cells, actions))
    for b in range(batch):
        soft_backup(scaled[b], successors, horizon, values[b], log_policy[b], policy[b], live)
    return values, log_policy, policy


def everywhere(successors: IntArray, horizon: int) -> NDArray[np.bool_]:
    """The ``(T + 1, S)`` mask of a fixed horizon from any cell: every cell at every step."""
    return np.ones((horizon + 1, successors.shape[0]), dtype=np.bool_)


def soft_value_iteration(
    cell_rewards: FloatArray,
    successors: IntArray,
    horizon: int,
    rationality: float,
    live: NDArray[np.bool_] | None = None,
) -> SoftPlan:
    """Finite-horizon soft value iteration for a batch of reward vectors.

    Args:
        cell_rewards: ``(B, S)`` reward :math:`r(s)` of entering each cell.
        successors: ``(S, A)`` successor table (``-1`` = unavailable).
        horizon: number of steps ``T >= 0``.
        rationality: :math:`\\lambda > 0`.
        live: ``(T + 1, S)`` the steps and cells on paths that end in time
            (:attr:`cirl_study.core.maxent.Phase.reachable`); every one by default.

    Returns:
        The soft policy and values; see :class:`SoftPlan` (undefined outside ``live``).
    """
    scaled = rationality * np.ascontiguousarray(cell_rewards, dtype=np.float64)
    values, log_policy, policy = _soft_value_iteration(
        scaled,
        np.ascontiguousarray(successors, dtype=np.int64),
        horizon,
        everywhere(successors, horizon) if live is None else live,
    )
    # Computed trial by trial (batch-major); returned as (T, B, ...) views.
    return SoftPlan(
        log_policy=log_policy.transpose(1, 0, 2, 3),
        policy=policy.transpose(1, 0, 2, 3),
        values=values.transpose(1, 0, 2),
    )


@njit(cache=True)
def forward_visitation(policy, successors, visitation):  # pragma: no cover - compiled
    """:math:`d_{t+1}(s') = \\sum_{s, a: s \\to_a s'} d_t(s)\\, \\pi_t(a \\mid s)` for one trial.

    ``policy (T, S, A)``; ``visitation (T+1, S)`` must hold :math:`d_0` in row 0.
    """
    horizon, cells, actions = policy.shape
    for t in range(horizon):
        visitation[t + 1, :] = 0.0
        for s in range(cells):
            mass = visitation[t, s]
            if mass == 0.0:
                continue
            for a in range(actions):
                nxt = successors[s, a]
                if nxt >= 0:
                    visitation[t + 1, nxt] += mass * policy[t, s, a]


@njit(cache=True)
def backward_future_counts(policy, successors, features, future, needed):  # pragma: no cover
    """:math:`F_t(s) = \\sum_a \\pi_t(a \\mid s)[\\phi(s') + F_{t+1}(s')]` for one trial.

    ``policy (T, S, A)``, ``features (S, K)``; fills ``future (T+1, S, K)`` where
    ``needed (T + 1, S)`` is true (see :func:`soft_backup`).
    """
    horizon, cells, actions = policy.shape
    k = features.shape[1]
    future[horizon, :, :] = 0.0
    for t in range(horizon - 1, -1, -1):
        for s in range(cells):
            if not needed[t, s]:
                continue
            for i in range(k):
                future[t, s, i] = 0.0
            for a in range(actions):
                nxt = successors[s, a]
                if nxt < 0 or not needed[t + 1, nxt]:
                    continue
                p = policy[t, s, a]
                for i in range(k):
                    future[t, s, i] += p * (features[nxt, i] + future[t + 1, nxt, i])


@njit(cache=True)
def _state_visitation(policy, successors, start_distribution):  # pragma: no cover - compiled
    horizon, batch, cells, _ = policy.shape
    visitation = np.empty((horizon + 1, batch, cells))
    one = np.empty((horizon + 1, cells))
    for b in range(batch):
        one[0] = start_distribution[b]
        forward_visitation(policy[:, b], successors, one)
        visitation[:, b] = one
    return visitation


def state_visitation(
    policy: FloatArray, successors: IntArray, start_distribution: FloatArray
) -> FloatArray:
    """State distribution at every step under a (stochastic) time-indexed policy.

    :math:`d_0 = ` ``start_distribution`` and
    :math:`d_{t+1}(s') = \\sum_{s, a: s \\to_a s'} d_t(s)\\, \\pi_t(a \\mid s)`.

    Args:
        policy: ``(T, B, S, A)`` action probabilities (zero where unavailable).
        successors: ``(S, A)`` successor table.
        start_distribution: ``(B, S)`` distribution of :math:`s_0`.

    Returns:
        ``(T + 1, B, S)`` array of :math:`d_t`.
    """
    return _state_visitation(
        np.ascontiguousarray(policy, dtype=np.float64),
        np.ascontiguousarray(successors, dtype=np.int64),
        np.ascontiguousarray(start_distribution, dtype=np.float64),
    )


@njit(cache=True)
def _future_feature_counts(policy, successors, features):  # pragma: no cover - compiled
    horizon, batch, cells, _ = policy.shape
    counts = np.empty((horizon + 1, batch, cells, features.shape[2]))
    one = np.empty((horizon + 1, cells, features.shape[2]))
    everywhere = np.ones((horizon + 1, cells), dtype=np.bool_)
    for b in range(batch):
        backward_future_counts(policy[:, b], successors, features[b], one, everywhere)
        counts[:, b] = one
    return counts


def future_feature_counts(
    policy: FloatArray, successors: IntArray, features: FloatArray
) -> FloatArray:
    """Expected feature counts still to come, from every step and cell.

    :math:`F_T(s) = 0` and
    :math:`F_t(s) = \\sum_a \\pi_t(a \\mid s)\\,[\\phi(s') + F_{t+1}(s')]`, so that
    :math:`F_0(s_0) = E[\\phi(\\tau) \\mid s_0]` and
    :math:`F_t(s) = E[\\sum_{u > t} \\phi(s_u) \\mid s_t = s]`.

    Args:
        policy: ``(T, B, S, A)`` action probabilities.
        successors: ``(S, A)`` successor table.
        features: ``(B, S, K)`` per-trial feature matrices.

    Returns:
        ``(T + 1, B, S, K)`` array of :math:`F_t`.
    """
    return _future_feature_counts(
        np.ascontiguousarray(policy, dtype=np.float64),
        np.ascontiguousarray(successors, dtype=np.int64),
        np.ascontiguousarray(features, dtype=np.float64),
    )


def optimal_plan(
    cell_rewards: FloatArray,
    successors: IntArray,
    horizon: int,
    live: NDArray[np.bool_] | None = None,
) -> HardPlan:
    """Finite-horizon value iteration (hard max) for a batch of reward vectors.

    :math:`V^*_T = 0`, :math:`V^*_t(s) = \\max_a r(s') + V^*_{t+1}(s')` over the moves into
    ``live`` cells (every cell by default; see :func:`soft_value_iteration`); ``actions`` takes
    the lowest action index among exact ties, so the path it follows is a deterministic
    function of the rewards (the policy the measures evaluate shares ties instead:
    :func:`shared_policy_values`). Values are ``-inf`` where no live move is left.
    """
    values, actions = _hard_value_iteration(
        np.ascontiguousarray(cell_rewards, dtype=np.float64),
        np.ascontiguousarray(successors, dtype=np.int64),
        horizon,
        everywhere(successors, horizon) if live is None else live,
    )
    return HardPlan(values=values, actions=actions)


@njit(cache=True)
def _hard_value_iteration(rewards, successors, horizon, live):  # pragma: no cover - compiled
    batch, cells = rewards.shape
    values = np.zeros((horizon + 1, batch, cells))
    actions = np.zeros((horizon, batch, cells), dtype=np.int64)
    for t in range(horizon - 1, -1, -1):
        for b in range(batch):
            for s in range(cells):
                best, chosen = -np.inf, 0
                for a in range(successors.shape[1]):
                    nxt = successors[s, a]
                    if nxt < 0 or not live[t + 1, nxt]:
                        continue
                    q = rewards[b, nxt] + values[t + 1, b, nxt]
                    if q > best:
                        best, chosen = q, a
                values[t, b, s] = best
                actions[t, b, s] = chosen
    return values, actions


TIE_TOLERANCE = 2.0**-40
"""Actions whose value under the planned reward is within ``TIE_TOLERANCE * T * max_s |r(s)|``
of the best are tied (:func:`shared_policy_values`). The values are sums of at most ``T``
rewards, and two sums of the same rewards in another order differ by at most
:math:`T^2\\, 2^{-53} \\max_s |r(s)|`, below the tolerance for every ``T < 8192``: actions
that tie in exact arithmetic (paths through the same cells, or cells of equal reward, in
another order) always tie here, and a real gap below the tolerance (a relative
:math:`10^{-12} T`) is taken for a tie too."""


def shared_policy_values(
    cell_rewards: FloatArray,
    planned_rewards: FloatArray,
    successors: IntArray,
    horizon: int,
    live: NDArray[np.bool_] | None = None,
) -> FloatArray:
    """Values under ``cell_rewards`` of the optimal policy for ``planned_rewards`` whose ties
    share the mass: ``(B, S)`` :math:`V^{\\pi}_0(s)` from every cell.

    The policy :math:`\\pi_t(\\cdot \\mid s)` is uniform over the actions ``a`` whose
    :math:`\\hat Q_t(s, a) = \\hat r(s') + \\hat V^*_{t+1}(s')` is the best up to
    :data:`TIE_TOLERANCE` (``planned_rewards`` :math:`\\hat r`), so no value depends on the
    order of the action list; its value is :math:`V_T = 0`,
    :math:`V_t(s) = \\frac{1}{|A^*_t(s)|} \\sum_{a \\in A^*_t(s)} r(s') + V_{t+1}(s')`, both
    recursions in one backward pass. ``live`` as in :func:`optimal_plan`; values are ``-inf``
    where no live move is left.
    """
    return _shared_policy_values(
        np.ascontiguousarray(cell_rewards, dtype=np.float64),
        np.ascontiguousarray(planned_rewards, dtype=np.float64),
        np.ascontiguousarray(successors, dtype=np.int64),
        horizon,
        everywhere(successors, horizon) if live is None else live,
    )


@njit(cache=True)
def _shared_policy_values(rewards, planned, successors, horizon, live):  # pragma: no cover
    batch, cells = rewards.shape
    actions = successors.shape[1]
    planned_later, planned_now = np.zeros(cells), np.zeros(cells)
    later, now = np.zeros(cells), np.zeros(cells)
    achieved = np.empty((batch, cells))
    for b in range(batch):
        scale = 0.0
        for s in range(cells):
            scale = max(scale, abs(planned[b, s]))
        tolerance = TIE_TOLERANCE * horizon * scale
        planned_later[:] = 0.0
        later[:] = 0.0
        for t in range(horizon - 1, -1, -1):
            for s in range(cells):
                best = -np.inf
                for a in range(actions):
                    nxt = successors[s, a]
                    if nxt >= 0 and live[t + 1, nxt]:
                        best = max(best, planned[b, nxt] + planned_later[nxt])
                planned_now[s] = best
                if best == -np.inf:
                    now[s] = -np.inf
                    continue
                total, tied = 0.0, 0
                for a in range(actions):
                    nxt = successors[s, a]
                    if (
                        nxt >= 0
                        and live[t + 1, nxt]
                        and planned[b, nxt] + planned_later[nxt] >= best - tolerance
                    ):
                        total += rewards[b, nxt] + later[nxt]
                        tied += 1
                now[s] = total / tied
            planned_later, planned_now = planned_now, planned_later
            later, now = now, later
        for s in range(cells):
            achieved[b, s] = later[s]
    return achieved


def rollout(successors: IntArray, start: int | IntArray, actions: IntArray) -> IntArray:
    """States ``(B, T + 1)`` visited by time-indexed action sequences ``(B, T)`` from ``start``."""
    batch, horizon = actions.shape
    states = np.empty((batch, horizon + 1), dtype=np.int64)
    states[:, 0] = start
    for t in range(horizon):
        states[:, t + 1] = successors[states[:, t], actions[:, t]]
    if (states < 0).any():
        raise ValueError("action sequence leaves the grid")
    return states


def follow_policy(successors: IntArray, start: IntArray, policy: IntArray) -> IntArray:
    """States ``(B, T + 1)`` visited by a deterministic policy ``(T, B, S)`` from ``start (B,)``."""
    horizon, batch, _ = policy.shape
    states = np.empty((batch, horizon + 1), dtype=np.int64)
    states[:, 0] = start
    rows = np.arange(batch)
    for t in range(horizon):
        states[:, t + 1] = successors[states[:, t], policy[t, rows, states[:, t]]]
    return states
