"""Finite-horizon planning on the gridworld, batched over reward vectors.

Every function works on a batch of ``B`` problems at once: rewards are ``(B, S)``
arrays (one reward per cell), and the grid's moves are the ``(S, A)`` successor
table of :class:`cirl_study.gridworld.Gridworld` (``-1`` where a move is
unavailable). Entering cell ``s'`` earns ``r(s')``, so a path
:math:`\\tau = (s_0, \\dots, s_T)` earns :math:`\\sum_{t=1}^T r(s_t)`.

Maximum-entropy (soft) planning with rationality :math:`\\lambda` (DESIGN §2):

.. math::

    V_T = 0, \\quad Q_t(s, a) = \\lambda r(s') + V_{t+1}(s'), \\quad
    V_t(s) = \\log \\sum_a e^{Q_t(s, a)}, \\quad \\pi_t(a \\mid s) = e^{Q_t(s, a) - V_t(s)},

so that :math:`P(\\tau \\mid s_0) = \\exp(\\lambda\\, r(\\tau) - V_0(s_0))` over all available
paths: :math:`V_0(s_0)` is the log-partition function :math:`\\log Z`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import sparse

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
        actions: ``(T, B, S)`` optimal action index at each step (lowest index on ties).
    """

    values: FloatArray
    actions: IntArray


def _successor_gather(successors: IntArray) -> tuple[IntArray, NDArray[np.bool_]]:
    """Successor indices safe for fancy indexing, and the mask of available moves."""
    available = successors >= 0
    return np.where(available, successors, 0), available


def soft_value_iteration(
    cell_rewards: FloatArray, successors: IntArray, horizon: int, rationality: float
) -> SoftPlan:
    """Finite-horizon soft value iteration for a batch of reward vectors.

    Args:
        cell_rewards: ``(B, S)`` reward :math:`r(s)` of entering each cell.
        successors: ``(S, A)`` successor table (``-1`` = unavailable).
        horizon: number of steps ``T >= 0``.
        rationality: :math:`\\lambda > 0`.

    Returns:
        The soft policy and values; see :class:`SoftPlan`.
    """
    gather, available = _successor_gather(successors)
    blocked = np.where(available, 0.0, -np.inf)
    scaled = rationality * np.asarray(cell_rewards, dtype=np.float64)
    batch, cells = scaled.shape
    values = np.zeros((horizon + 1, batch, cells))
    log_policy = np.empty((horizon, batch, cells, successors.shape[1]))
    policy = np.empty_like(log_policy)
    for t in range(horizon - 1, -1, -1):
        q = (scaled + values[t + 1])[:, gather] + blocked
        top = q.max(axis=-1, keepdims=True)
        weights = np.exp(q - top)
        total = weights.sum(axis=-1, keepdims=True)
        values[t] = (top + np.log(total))[..., 0]
        log_policy[t] = q - values[t][..., None]
        policy[t] = weights / total
    return SoftPlan(log_policy=log_policy, policy=policy, values=values)


def transition_matrix(successors: IntArray) -> sparse.csr_array:
    """Sparse ``(S, S * A)`` 0/1 matrix: entry ``(s', s * A + a)`` is 1 iff ``s -> s'`` by ``a``."""
    cells, actions = successors.shape
    pairs = np.flatnonzero(successors.ravel() >= 0)
    return sparse.csr_array(
        (np.ones(pairs.size), (successors.ravel()[pairs], pairs)), shape=(cells, cells * actions)
    )


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
    horizon, batch, cells, actions = policy.shape
    moves = transition_matrix(successors)
    visitation = np.empty((horizon + 1, batch, cells))
    visitation[0] = start_distribution
    for t in range(horizon):
        flow = visitation[t][..., None] * policy[t]
        visitation[t + 1] = (moves @ flow.reshape(batch, cells * actions).T).T
    return visitation


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
    gather, _ = _successor_gather(successors)
    horizon, batch, cells, actions = policy.shape
    k = features.shape[-1]
    # Row of (trial b, successor of s by a) in the (B * S, K) flattening, for every (b, s, a).
    rows = (np.arange(batch)[:, None, None] * cells + gather[None]).ravel()
    counts = np.zeros((horizon + 1, batch, cells, k))
    for t in range(horizon - 1, -1, -1):
        ahead = np.take((features + counts[t + 1]).reshape(-1, k), rows, axis=0)
        # Unavailable moves have probability 0, so their (arbitrary) rows do not count.
        counts[t] = np.matmul(policy[t][:, :, None, :], ahead.reshape(batch, cells, actions, k))[
            :, :, 0
        ]
    return counts


def optimal_plan(cell_rewards: FloatArray, successors: IntArray, horizon: int) -> HardPlan:
    """Finite-horizon value iteration (hard max) for a batch of reward vectors.

    :math:`V^*_T = 0`, :math:`V^*_t(s) = \\max_a r(s') + V^*_{t+1}(s')`; ties go to the
    lowest action index, so the policy is a deterministic function of the rewards.
    """
    gather, available = _successor_gather(successors)
    rewards = np.asarray(cell_rewards, dtype=np.float64)
    batch, cells = rewards.shape
    values = np.zeros((horizon + 1, batch, cells))
    actions = np.empty((horizon, batch, cells), dtype=np.int64)
    for t in range(horizon - 1, -1, -1):
        q = (rewards + values[t + 1])[:, gather]
        q[:, ~available] = -np.inf
        actions[t] = q.argmax(axis=-1)
        values[t] = np.take_along_axis(q, actions[t][..., None], axis=-1)[..., 0]
    return HardPlan(values=values, actions=actions)


def evaluate_policy(cell_rewards: FloatArray, successors: IntArray, actions: IntArray) -> FloatArray:
    """Values of a deterministic time-indexed policy under the given rewards.

    :math:`V_T = 0`, :math:`V_t(s) = r(s') + V_{t+1}(s')` with :math:`s'` the successor of
    ``s`` under ``actions[t, :, s]`` (which must be available).

    Returns:
        ``(T + 1, B, S)`` values.
    """
    rewards = np.asarray(cell_rewards, dtype=np.float64)
    horizon, batch, cells = actions.shape
    chosen = successors[np.arange(cells), actions]  # (T, B, S)
    if (chosen < 0).any():
        raise ValueError("policy takes an unavailable action")
    values = np.zeros((horizon + 1, batch, cells))
    rows = np.arange(batch)[:, None]
    for t in range(horizon - 1, -1, -1):
        values[t] = (rewards + values[t + 1])[rows, chosen[t]]
    return values
