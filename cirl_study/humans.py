"""The human's demonstration policies (paper sections 3.3-3.4; DESIGN §3).

* **Demonstration by expert** (:math:`\\pi^E`): the human greedily maximises her own
  reward, ignoring what the robot will learn:
  :math:`\\tau^E = \\arg\\max_\\tau \\theta^\\top \\phi(\\tau)`, by exact dynamic programming.
* **Instructive best response** (:math:`\\mathbf{br}`, the paper's equation in
  section 3.4): the human trades reward against matching the feature counts the
  robot expects under the true :math:`\\theta`,

  .. math::

      \\tau^H = \\arg\\max_\\tau\\; \\phi(\\tau)^\\top\\theta
      - \\eta \\lVert \\phi_\\theta - \\phi(\\tau) \\rVert^2,
      \\qquad \\phi_\\theta = E[\\phi(\\tau) \\mid \\theta, \\lambda].

  Completing the square, the objective equals
  :math:`-\\eta \\lVert \\phi(\\tau) - (\\phi_\\theta + \\theta / (2\\eta)) \\rVert^2`
  plus a constant, so :math:`\\tau^H` is the path whose counts are nearest to
  :math:`\\phi_\\theta + \\theta/(2\\eta)`, found exactly by
  :func:`cirl_study.path_search.nearest_paths`.

Paths are returned as ``(B, T + 1)`` arrays of flat cell indices, starting at ``start``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from cirl_study.irl import trajectory_moments
from cirl_study.path_search import nearest_paths
from cirl_study.planning import IntArray, optimal_plan

FloatArray = NDArray[np.float64]


def rollout(successors: IntArray, start: int | IntArray, actions: IntArray) -> IntArray:
    """States visited by time-indexed action sequences ``(B, T)`` from ``start``."""
    batch, horizon = actions.shape
    states = np.empty((batch, horizon + 1), dtype=np.int64)
    states[:, 0] = start
    for t in range(horizon):
        states[:, t + 1] = successors[states[:, t], actions[:, t]]
    if (states < 0).any():
        raise ValueError("action sequence leaves the grid")
    return states


def follow_policy(successors: IntArray, start: IntArray, policy: IntArray) -> IntArray:
    """States visited by a deterministic policy ``(T, B, S)`` from the cells ``start`` ``(B,)``."""
    horizon, batch, _ = policy.shape
    states = np.empty((batch, horizon + 1), dtype=np.int64)
    states[:, 0] = start
    rows = np.arange(batch)
    for t in range(horizon):
        states[:, t + 1] = successors[states[:, t], policy[t, rows, states[:, t]]]
    return states


def expert_paths(
    theta: FloatArray, features: FloatArray, successors: IntArray, start: int, horizon: int
) -> IntArray:
    """Expert demonstration: the path from ``start`` maximising :math:`\\theta^\\top\\phi(\\tau)`.

    Ties go to the lowest action index at each step (see
    :func:`cirl_study.planning.optimal_plan`).
    """
    rewards = np.einsum("bsk,bk->bs", features, theta)
    plan = optimal_plan(rewards, successors, horizon)
    return follow_policy(successors, np.full(len(theta), start), plan.actions)


def best_response_target(
    theta: FloatArray,
    eta: FloatArray,
    features: FloatArray,
    successors: IntArray,
    start: int,
    horizon: int,
    rationality: float,
) -> FloatArray:
    """The counts the best response aims at, :math:`\\phi_\\theta + \\theta / (2\\eta)` ``(B, K)``.

    :math:`\\phi_\\theta` is the robot's expected demonstration counts under the true
    :math:`\\theta` (:func:`cirl_study.irl.trajectory_moments`).
    """
    _, expected, _ = trajectory_moments(theta, features, successors, start, horizon, rationality)
    return expected + theta / (2.0 * np.asarray(eta, dtype=np.float64)[:, None])


def best_response_paths(
    theta: FloatArray,
    eta: FloatArray,
    features: FloatArray,
    successors: IntArray,
    start: int,
    horizon: int,
    rationality: float,
) -> IntArray:
    """Instructive best response: the exact maximiser of the paper's section 3.4 rule.

    Args:
        theta: ``(B, K)`` true reward weights.
        eta: ``(B,)`` trade-off :math:`\\eta > 0` between reward and feature matching.
        features: ``(B, S, K)`` cell features.
        successors: ``(S, A)`` successor table.
        start: flat index of :math:`s_0`.
        horizon: demonstration length ``T``.
        rationality: the robot's :math:`\\lambda`, which defines :math:`\\phi_\\theta`.
    """
    target = best_response_target(theta, eta, features, successors, start, horizon, rationality)
    actions, _, _ = nearest_paths(features, target, successors, start, horizon, direction=theta)
    return rollout(successors, start, actions)
