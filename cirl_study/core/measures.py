"""The study's dependent measures (paper section 4.2; docs/design.md §4), exact and batched.

All three compare the true reward weights :math:`\\theta` with the robot's estimate
:math:`\\hat\\theta` on the deployment phase: ``T`` steps from a start cell drawn
uniformly from all cells (``phase.start = None``; the paper's setting) or from one fixed
start (``phase.start = s``); in a phase with goals, ``T`` is the most moves and a path ends
on entering a goal, and the starts are the cells that are not goals (and can reach one in
time). Expectations over the start are taken exactly, by averaging over the starts
(:attr:`~cirl_study.core.maxent.Phase.starts`; every cell in the paper),
:math:`\\frac{1}{|S|}\\sum_s`; a fixed start replaces that average by the value at ``s``.
Each takes the MaxEnt model of the deployment phase (:class:`cirl_study.core.maxent.MaxEnt`:
its dynamics, the trials' features and :math:`\\lambda`).

* ``regret``: :math:`\\frac{1}{|S|}\\sum_s V^*_\\theta(s) - V^{\\pi_{\\hat\\theta}}_\\theta(s)`,
  where :math:`\\pi_{\\hat\\theta}` is the optimal (hard-max) ``T``-step policy for
  :math:`r_{\\hat\\theta}` and values sum :math:`r_\\theta(s_t)` for ``t = 1..T``.
* ``regret_under_estimate``: the other reading of the paper's words, both values under the
  estimate, :math:`\\frac{1}{|S|}\\sum_s V^*_{\\hat\\theta}(s) -
  V^{\\pi_\\theta}_{\\hat\\theta}(s)`: :func:`regret` with the roles of :math:`\\theta` and
  :math:`\\hat\\theta` swapped, ``regret(deployment, theta_hat, theta)``.
* ``kl``: :math:`\\frac{1}{|S|}\\sum_s KL(P(\\cdot \\mid s, \\theta, \\lambda) \\,\\|\\,
  P(\\cdot \\mid s, \\hat\\theta, \\lambda))` between the MaxEnt trajectory distributions,
  by the chain rule as the occupancy-weighted sum of per-step policy KLs,
  :math:`\\sum_t \\sum_s d_t(s)\\, KL(\\pi_t(\\cdot \\mid s) \\| \\hat\\pi_t(\\cdot \\mid s))`,
  computed backwards for every start at once:
  :math:`D_T = 0`, :math:`D_t(s) = \\sum_a \\pi_t(a \\mid s)[\\log \\pi_t(a \\mid s)
  - \\log \\hat\\pi_t(a \\mid s) + D_{t+1}(s')]`.
* ``reward_l2``: :math:`\\lVert \\Phi\\theta - \\Phi\\hat\\theta \\rVert_2` over all cells.

Each is registered by name (:mod:`cirl_study.measure_registry`) as the function of a played
batch (an :class:`~cirl_study.core.apprenticeship.Outcome`) that ends this module
(:func:`regret_of`, ...).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from cirl_study.core.apprenticeship import Outcome
from cirl_study.core.maxent import MaxEnt, Phase
from cirl_study.core.planning import FloatArray, optimal_plan, shared_policy_values, soft_backup


def regret(deployment: MaxEnt, theta: FloatArray, theta_hat: FloatArray) -> FloatArray:
    """:math:`V^*_\\theta - V^{\\pi_{\\hat\\theta}}_\\theta` over the deployment's starts ``(B,)``.

    The values :math:`V` sum :math:`r_\\theta(s_t)`, ``t = 1..T``, from each start;
    :math:`\\pi_{\\hat\\theta}` shares its mass evenly among tied optimal actions
    (:func:`cirl_study.core.planning.shared_policy_values`), so regret is a function of the
    game, not of the order of the action list. It is non-negative (up to rounding) for any
    two weight vectors, so the call with the roles swapped is the second reading,
    ``regret_under_estimate``.
    """
    phase = deployment.phase
    successors, horizon, live = phase.successors, phase.horizon, phase.finishing
    true_rewards = deployment.cell_rewards(theta)
    best = optimal_plan(true_rewards, successors, horizon, live).values[0]
    achieved = shared_policy_values(
        true_rewards, deployment.cell_rewards(theta_hat), successors, horizon, live
    )
    return over_starts(best - achieved, phase)


def trajectory_kl(deployment: MaxEnt, theta: FloatArray, theta_hat: FloatArray) -> FloatArray:
    """The KL between MaxEnt trajectory distributions over the deployment's starts, ``(B,)``."""
    phase, rationality = deployment.phase, deployment.rationality
    divergence = _divergence_from_every_cell(
        rationality * deployment.cell_rewards(theta),
        rationality * deployment.cell_rewards(theta_hat),
        phase.successors,
        phase.horizon,
        phase.finishing,
    )
    return over_starts(divergence, phase)


@njit(cache=True)
def _divergence_from_every_cell(scaled, scaled_hat, successors, horizon, live):  # pragma: no cover
    # D_t(s) = max(sum_a pi_t(a|s) [log pi_t(a|s) - log pi_hat_t(a|s)], 0)
    #          + sum_a pi_t(a|s) D_{t+1}(s'), one trial at a time in scratch arrays (the
    # clipping removes only rounding below zero from a per-step KL, which is >= 0).
    batch, cells = scaled.shape
    actions = successors.shape[1]
    values, values_hat = np.empty((horizon + 1, cells)), np.empty((horizon + 1, cells))
    shape = (horizon, cells, actions)
    log_policy, log_policy_hat = np.empty(shape), np.empty(shape)
    policy, policy_hat = np.empty(shape), np.empty(shape)
    later, now = np.zeros(cells), np.zeros(cells)
    divergence = np.empty((batch, cells))
    for b in range(batch):
        soft_backup(scaled[b], successors, horizon, values, log_policy, policy, live)
        soft_backup(
            scaled_hat[b], successors, horizon, values_hat, log_policy_hat, policy_hat, live
        )
        later[:] = 0.0
        for t in range(horizon - 1, -1, -1):
            for s in range(cells):
                step, ahead = 0.0, 0.0
                if not live[t, s]:
                    now[s] = 0.0
                    continue
                for a in range(actions):
                    nxt = successors[s, a]
                    if nxt < 0 or not live[t + 1, nxt]:
                        continue
                    p = policy[t, s, a]
                    step += p * (log_policy[t, s, a] - log_policy_hat[t, s, a])
                    ahead += p * later[nxt]
                now[s] = max(step, 0.0) + ahead
            later, now = now, later
        for s in range(cells):
            divergence[b, s] = later[s]
    return divergence


def over_starts(values: FloatArray, phase: Phase) -> FloatArray:
    """``(B, S)`` values per cell (``S + 1`` with a sink), averaged over the phase's starts
    (:attr:`~cirl_study.core.maxent.Phase.starts`): ``(B,)``."""
    if phase.start is not None:
        return values[:, phase.start]
    # ``compress`` keeps the rows C-contiguous, so the mean over every cell sums in the same
    # order, to the bit, as ``values.mean(axis=1)``; a boolean index would lay them out by
    # column and sum in another order.
    return values[:, : phase.cells].compress(phase.starts, axis=1).mean(axis=1)


def reward_l2(features: FloatArray, theta: FloatArray, theta_hat: FloatArray) -> FloatArray:
    """:math:`\\lVert \\Phi(\\theta - \\hat\\theta) \\rVert_2` over all cells, ``(B,)``.

    ``features`` is ``(B, S, K)``: each trial's :math:`\\Phi` (a sink's row of zeros adds
    nothing).
    """
    return np.linalg.norm(np.einsum("bsk,bk->bs", features, theta - theta_hat), axis=1)


def regret_of(outcome: Outcome) -> FloatArray:
    """:func:`regret` of a played batch: the registry's ``regret``."""
    return regret(outcome.game.deployment, outcome.theta, outcome.theta_hat)


def regret_under_estimate_of(outcome: Outcome) -> FloatArray:
    """:func:`regret` of a played batch with the roles of ``theta`` and ``theta_hat`` swapped:
    the registry's ``regret_under_estimate``."""
    return regret(outcome.game.deployment, outcome.theta_hat, outcome.theta)


def kl_of(outcome: Outcome) -> FloatArray:
    """:func:`trajectory_kl` of a played batch: the registry's ``kl``."""
    return trajectory_kl(outcome.game.deployment, outcome.theta, outcome.theta_hat)


def reward_l2_of(outcome: Outcome) -> FloatArray:
    """:func:`reward_l2` of a played batch on its deployment features: the registry's
    ``reward_l2``."""
    return reward_l2(outcome.game.deployment.features, outcome.theta, outcome.theta_hat)
