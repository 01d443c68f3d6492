"""The robot: Maximum-Entropy IRL with rationality lambda (paper section 4; DESIGN §2).

The robot models the human's demonstration :math:`\\tau` of ``T`` steps from the
start cell :math:`s_0` as

.. math::

    P(\\tau \\mid \\theta, \\lambda) = \\frac{\\exp(\\lambda\\, \\theta^\\top \\phi(\\tau))}
    {Z(\\theta)}, \\qquad \\log Z(\\theta) = V_0(s_0),

over all available paths (Ziebart et al., 2008), with :math:`V_0` from
:func:`cirl_study.planning.soft_value_iteration`. Its estimate is the MAP under the
uniform prior on the box :math:`[-1, 1]^K`, i.e. the maximiser of the concave
log-likelihood

.. math::

    L(\\theta) = \\lambda\\, \\theta^\\top \\phi(\\tau_{demo}) - \\log Z(\\theta), \\qquad
    \\nabla L = \\lambda\\,(\\phi(\\tau_{demo}) - E_\\theta[\\phi(\\tau)]), \\qquad
    \\nabla^2 L = -\\lambda^2\\, \\mathrm{Cov}_\\theta[\\phi(\\tau)].

Both moments are exact: the mean from the state visitation :math:`d_t`, and the
second moment from the future counts :math:`F_t` (see
:func:`cirl_study.planning.future_feature_counts`) through

.. math::

    E[\\phi(\\tau)\\phi(\\tau)^\\top] = \\sum_{t=1}^{T} \\sum_s d_t(s)\\,
    \\big[\\phi(s)\\phi(s)^\\top + \\phi(s) F_t(s)^\\top + F_t(s) \\phi(s)^\\top\\big].

The box-constrained problem is solved for a whole batch at once by the projected
Newton method (Bertsekas, 1982): variables at a bound whose gradient points out
of the box are held fixed, a Newton step is taken on the others, the step is
projected back onto the box, and an Armijo backtracking line search along the
projection arc guarantees ascent. Iteration stops when the projected gradient,
in feature-count units (:math:`\\lVert \\nabla L \\rVert_\\infty / \\lambda`), falls
below ``tolerance``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cirl_study.planning import (
    IntArray,
    soft_value_iteration,
    state_visitation,
    future_feature_counts,
)

FloatArray = NDArray[np.float64]

BOX = (-1.0, 1.0)
"""Support of the uniform prior on each reward weight."""


@dataclass(frozen=True)
class IRLFit:
    """MAP estimates for a batch of demonstrations.

    Attributes:
        theta_hat: ``(B, K)`` MAP reward weights in the box.
        log_likelihood: ``(B,)`` :math:`\\log P(\\tau_{demo} \\mid \\hat\\theta, \\lambda)`.
        iterations: ``(B,)`` projected-Newton iterations used.
        converged: ``(B,)`` whether the projected gradient met the tolerance.
    """

    theta_hat: FloatArray
    log_likelihood: FloatArray
    iterations: NDArray[np.int64]
    converged: NDArray[np.bool_]


@dataclass(frozen=True)
class _Moments:
    log_likelihood: FloatArray  # (B,)
    mean: FloatArray  # (B, K)  E[phi(tau)]
    covariance: FloatArray  # (B, K, K)  Cov[phi(tau)]


def _start_distribution(batch: int, cells: int, start: int) -> FloatArray:
    distribution = np.zeros((batch, cells))
    distribution[:, start] = 1.0
    return distribution


def demo_log_likelihood(
    theta: FloatArray,
    demo_counts: FloatArray,
    features: FloatArray,
    successors: IntArray,
    start: int,
    horizon: int,
    rationality: float,
) -> FloatArray:
    """:math:`L(\\theta) = \\lambda\\,\\theta^\\top\\phi(\\tau_{demo}) - \\log Z(\\theta)`, ``(B,)``."""
    rewards = np.einsum("bsk,bk->bs", features, theta)
    plan = soft_value_iteration(rewards, successors, horizon, rationality)
    return rationality * np.einsum("bk,bk->b", theta, demo_counts) - plan.values[0][:, start]


def trajectory_moments(
    theta: FloatArray,
    features: FloatArray,
    successors: IntArray,
    start: int,
    horizon: int,
    rationality: float,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Log-partition, mean and covariance of :math:`\\phi(\\tau)` under the MaxEnt model.

    Returns:
        ``log_z (B,)``, ``mean (B, K)`` and ``covariance (B, K, K)``.
    """
    rewards = np.einsum("bsk,bk->bs", features, theta)
    plan = soft_value_iteration(rewards, successors, horizon, rationality)
    policy = plan.policy
    batch, cells = rewards.shape
    visitation = state_visitation(policy, successors, _start_distribution(batch, cells, start))
    future = future_feature_counts(policy, successors, features)
    mean = future[0][:, start]
    # sum_t sum_s d_t(s) phi(s) (phi(s) + 2 F_t(s))^T, symmetrised, is E[phi phi^T]:
    # one batched (K, T*S) @ (T*S, K) product per trial.
    k = features.shape[-1]
    weighted = (visitation[1:, :, :, None] * features[None]).transpose(1, 0, 2, 3)
    ahead = (features[None] + 2.0 * future[1:]).transpose(1, 0, 2, 3)
    cross = np.matmul(
        weighted.reshape(batch, -1, k).transpose(0, 2, 1), ahead.reshape(batch, -1, k)
    )
    second = 0.5 * (cross + cross.transpose(0, 2, 1))
    covariance = second - mean[:, :, None] * mean[:, None, :]
    return plan.values[0][:, start], mean, covariance


def _moments(
    theta: FloatArray,
    demo_counts: FloatArray,
    features: FloatArray,
    successors: IntArray,
    start: int,
    horizon: int,
    rationality: float,
) -> _Moments:
    log_z, mean, covariance = trajectory_moments(
        theta, features, successors, start, horizon, rationality
    )
    log_likelihood = rationality * np.einsum("bk,bk->b", theta, demo_counts) - log_z
    return _Moments(log_likelihood, mean, covariance)


def _newton_direction(gradient: FloatArray, hessian_neg: FloatArray, free: NDArray[np.bool_]):
    """Solve ``(H_FF + mu I) d_F = g_F`` with ``d = 0`` off the free set, for a batch.

    ``hessian_neg`` is the positive semi-definite :math:`-\\nabla^2 L`; the small ridge
    ``mu`` keeps the system solvable where the covariance is singular.
    """
    k = gradient.shape[-1]
    eye = np.eye(k)
    pair_free = free[:, :, None] & free[:, None, :]
    matrix = np.where(pair_free, hessian_neg, 0.0)
    scale = np.trace(matrix, axis1=1, axis2=2) / k
    ridge = 1e-10 * scale + 1e-300
    matrix = matrix + np.where(free[:, :, None], ridge[:, None, None] * eye, eye)
    rhs = np.where(free, gradient, 0.0)
    return np.linalg.solve(matrix, rhs[..., None])[..., 0]


def fit_maxent_irl(
    demo_counts: FloatArray,
    features: FloatArray,
    successors: IntArray,
    start: int,
    horizon: int,
    rationality: float,
    *,
    tolerance: float = 1e-8,
    max_iterations: int = 100,
) -> IRLFit:
    """MAP estimate of :math:`\\theta` in :math:`[-1, 1]^K` for a batch of demonstrations.

    Args:
        demo_counts: ``(B, K)`` feature counts :math:`\\phi(\\tau_{demo})` of the demonstrations.
        features: ``(B, S, K)`` per-trial feature matrices.
        successors: ``(S, A)`` successor table.
        start: flat index of the demonstration's start cell :math:`s_0`.
        horizon: demonstration length ``T``.
        rationality: :math:`\\lambda > 0`.
        tolerance: stop when :math:`\\lVert P_{box}\\nabla L\\rVert_\\infty / \\lambda` is below it.
        max_iterations: cap on projected-Newton iterations per trial.

    Returns:
        An :class:`IRLFit`. Iteration starts at the prior mean :math:`\\theta = 0`.

    Examples:
        >>> import numpy as np
        >>> from cirl_study.gridworld import Gridworld, rbf_features
        >>> grid = Gridworld(4, 4)
        >>> phi = rbf_features(grid, [[0.0, 0.0], [3.0, 3.0]], 1.0)[None]
        >>> demo = phi[0, [grid.index(1, 1), grid.index(2, 2), grid.index(3, 3)]].sum(0)
        >>> fit = fit_maxent_irl(demo[None], phi, grid.successors, grid.index(1, 0), 3, 1.0)
        >>> bool(fit.converged[0]), bool(fit.theta_hat[0, 1] > fit.theta_hat[0, 0])
        (True, True)
    """
    low, high = BOX
    demo_counts = np.asarray(demo_counts, dtype=np.float64)
    batch, k = demo_counts.shape
    theta = np.zeros((batch, k))
    log_likelihood = np.empty(batch)
    iterations = np.zeros(batch, dtype=np.int64)
    converged = np.zeros(batch, dtype=bool)
    running = np.arange(batch)
    problem = (successors, start, horizon, rationality)

    moments = _moments(theta, demo_counts, features, *problem)
    for _ in range(max_iterations + 1):
        gradient = rationality * (demo_counts[running] - moments.mean)
        th = theta[running]
        binding = ((th <= low) & (gradient < 0)) | ((th >= high) & (gradient > 0))
        projected = np.where(binding, 0.0, gradient)
        done = np.abs(projected).max(axis=1) <= tolerance * rationality
        log_likelihood[running] = moments.log_likelihood
        converged[running] = done
        stalled = iterations[running] >= max_iterations
        keep = ~(done | stalled)
        if not keep.any():
            break
        running, gradient, th, binding = running[keep], gradient[keep], th[keep], binding[keep]
        current = moments.log_likelihood[keep]
        direction = _newton_direction(
            gradient, rationality**2 * moments.covariance[keep], ~binding
        )
        step, accepted = _armijo_search(
            th, direction, gradient, current, demo_counts[running], features[running], problem
        )
        iterations[running] += 1
        theta[running] = np.where(accepted[:, None], step, th)
        # A trial whose line search failed cannot improve further at this precision.
        stuck = ~accepted
        iterations[running[stuck]] = max_iterations
        moments = _moments(theta[running], demo_counts[running], features[running], *problem)
    return IRLFit(theta, log_likelihood, iterations, converged)


def _armijo_search(
    theta: FloatArray,
    direction: FloatArray,
    gradient: FloatArray,
    current: FloatArray,
    demo_counts: FloatArray,
    features: FloatArray,
    problem: tuple[IntArray, int, int, float],
    *,
    sufficient: float = 1e-4,
    max_halvings: int = 40,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Backtracking along the projection arc :math:`P(\\theta + \\alpha d)`.

    Accepts the first :math:`\\alpha \\in \\{1, 1/2, \\dots\\}` with
    :math:`L(\\theta_\\alpha) \\ge L(\\theta) + \\sigma \\nabla L^\\top (\\theta_\\alpha - \\theta)`
    and a strict increase in :math:`\\theta`. Returns the accepted points and which trials
    found one.
    """
    low, high = BOX
    result = theta.copy()
    accepted = np.zeros(len(theta), dtype=bool)
    searching = np.arange(len(theta))
    alpha = 1.0
    for _ in range(max_halvings):
        candidate = np.clip(theta[searching] + alpha * direction[searching], low, high)
        moved = candidate - theta[searching]
        value = demo_log_likelihood(candidate, demo_counts[searching], features[searching], *problem)
        increase = np.einsum("bk,bk->b", gradient[searching], moved)
        ok = (value >= current[searching] + sufficient * increase) & (np.abs(moved).max(1) > 0)
        result[searching[ok]] = candidate[ok]
        accepted[searching[ok]] = True
        searching = searching[~ok]
        if searching.size == 0:
            break
        alpha *= 0.5
    return result, accepted
