"""The humans' demonstrations (paper sections 3.3-3.4; docs/design.md §3).

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
  :func:`cirl_study.core.path_search.nearest_paths`.
* **Literal demonstrator** (Ho, Littman, MacGlashan, Cushman & Austerweil 2016, "Showing
  versus doing"): Boltzmann-rational, she draws her path from the very model the robot
  assumes, :math:`P(\\tau \\mid \\theta, \\lambda) \\propto \\exp(\\lambda\\,
  \\theta^\\top \\phi(\\tau))`, with the trial's seed (:func:`literal_paths`).

Each is a function of the robot's MaxEnt model of the learning phase
(:class:`cirl_study.core.maxent.MaxEnt`, which carries the dynamics, the features and the
robot's :math:`\\lambda`), the true :math:`\\theta`, for a human with a trade-off its
:math:`\\eta`, and for a human that draws the trials' seeds (:func:`human_generator`). Paths
are returned as ``(B, T + 1)`` arrays of flat cell indices, starting at :math:`s_0`. The
teaching humans are in :mod:`cirl_study.core.teaching`; every human is registered by name in
:data:`cirl_study.core.players.HUMANS`.
"""

from __future__ import annotations

import numpy as np

from cirl_study.core.maxent import MaxEnt
from cirl_study.core.path_search import nearest_paths
from cirl_study.core.planning import (
    FloatArray,
    IntArray,
    follow_policy,
    optimal_plan,
    rollout,
    soft_value_iteration,
)

HUMAN_STREAM = 2
"""Spawn key of a human's random stream, apart from the robot's
(:data:`cirl_study.core.estimate.ROBOT_STREAM`) and the replay's uses of the trial's seed."""


def human_generator(seed: int) -> np.random.Generator:
    """The random generator of the human of the trial with ``seed``."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(HUMAN_STREAM,)))


def expert_paths(model: MaxEnt, theta: FloatArray) -> IntArray:
    """Expert demonstration: the path from :math:`s_0` maximising :math:`\\theta^\\top\\phi(\\tau)`.

    Ties go to the lowest action index at each step (see
    :func:`cirl_study.core.planning.optimal_plan`). The robot's :math:`\\lambda` plays no part.
    """
    phase = model.phase
    plan = optimal_plan(model.cell_rewards(theta), phase.successors, phase.horizon, phase.reachable)
    return follow_policy(phase.successors, np.full(len(theta), phase.start_cell), plan.actions)


def best_response_target(model: MaxEnt, theta: FloatArray, eta: FloatArray) -> FloatArray:
    """The counts the best response aims at, :math:`\\phi_\\theta + \\theta / (2\\eta)` ``(B, K)``.

    :math:`\\phi_\\theta` is the robot's expected demonstration counts under the true
    :math:`\\theta` (:meth:`cirl_study.core.maxent.MaxEnt.moments`).
    """
    expected = model.moments(theta, covariance=False).mean
    return expected + theta / (2.0 * np.asarray(eta, dtype=np.float64)[:, None])


def best_response_paths(model: MaxEnt, theta: FloatArray, eta: FloatArray) -> IntArray:
    """Instructive best response: the exact maximiser of the paper's section 3.4 rule.

    Its search grows about fourfold a learning step (:func:`nearest_paths`): a pipeline where
    she plays has at most :data:`cirl_study.study.limits.MAX_SEARCH_STEPS` (14) of them, about
    0.2 s a trial on the paper's grid.

    Args:
        model: the robot's model of the learning phase; its :math:`\\lambda` defines
            :math:`\\phi_\\theta`.
        theta: ``(B, K)`` true reward weights.
        eta: ``(B,)`` trade-off :math:`\\eta > 0` between reward and feature matching.
    """
    phase = model.phase
    target = best_response_target(model, theta, eta)
    found = nearest_paths(model.features, target, phase, direction=theta)
    return rollout(phase.successors, phase.start_cell, found.actions)


def literal_paths(model: MaxEnt, theta: FloatArray, seeds: IntArray) -> IntArray:
    """Literal demonstration: a path drawn from :math:`P(\\tau \\mid \\theta, \\lambda) \\propto
    \\exp(\\lambda\\, \\theta^\\top \\phi(\\tau))` over the phase's paths from :math:`s_0`.

    That distribution is the Markov chain of the soft policy :math:`\\pi_t(a \\mid s) =
    \\exp(Q_t(s, a) - V_t(s))` of finite-horizon soft value iteration
    (:func:`cirl_study.core.planning.soft_value_iteration`: :math:`V_T = 0`, :math:`Q_t(s, a) =
    \\lambda r(s') + V_{t+1}(s')`), since the product of its steps telescopes to
    :math:`\\exp(\\lambda \\theta^\\top \\phi(\\tau) - V_0(s_0))`. So each move is drawn in
    turn, :math:`a_t \\sim \\pi_t(\\cdot \\mid s_t)`, by inverting the cumulative policy at one
    uniform per step from the trial's :func:`human_generator`; the path depends on its trial
    alone.

    Args:
        model: the MaxEnt model of the learning phase (its :math:`\\lambda` is the human's).
        theta: ``(B, K)`` true reward weights.
        seeds: ``(B,)`` the trials' seeds.
    """
    phase = model.phase
    plan = soft_value_iteration(
        model.cell_rewards(theta),
        phase.successors,
        phase.horizon,
        model.rationality,
        phase.reachable,
    )
    batch = len(theta)
    uniforms = np.array([human_generator(seed).random(phase.horizon) for seed in seeds])
    paths = np.empty((batch, phase.horizon + 1), dtype=np.int64)
    paths[:, 0] = phase.start_cell
    rows = np.arange(batch)
    for t in range(phase.horizon):
        cumulative = np.cumsum(plan.policy[t][rows, paths[:, t]], axis=1)
        # The first action whose cumulative probability exceeds u (scaled by the total, which
        # rounding may leave a hair below 1): unavailable moves have probability 0.
        action = np.argmax(cumulative > uniforms[:, t, None] * cumulative[:, -1:], axis=1)
        paths[:, t + 1] = phase.successors[paths[:, t], action]
    return paths
