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
Newton method (Bertsekas, 1982): a Newton step is taken on the free variables, the
step is projected back onto the box, and an Armijo backtracking line search along the
projection arc guarantees ascent. A Levenberg-Marquardt ridge on the Newton system, raised
whenever the full step fails and lowered when it succeeds, keeps the method robust where the
covariance is nearly singular (nearly collinear features, tiny or huge lambda). Variables
within a small epsilon of a bound and pushed against it take a scaled gradient step instead
of a Newton step (the epsilon-active set). Iteration stops when the projected gradient,
in feature-count units (:math:`\\lVert \\nabla L \\rVert_\\infty / \\lambda`), falls
below ``tolerance``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from cirl_study.planning import (
    IntArray,
    backward_future_counts,
    forward_visitation,
    reachable_cells,
    soft_backup,
)

FloatArray = NDArray[np.float64]

BOX = (-1.0, 1.0)
"""Support of the uniform prior on each reward weight."""

MIN_DAMPING, MAX_DAMPING = 1e-10, 1e10
"""Range of the Levenberg-Marquardt ridge, relative to the mean curvature."""


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

    def take(self, rows: NDArray[np.bool_]) -> _Moments:
        return _Moments(self.log_likelihood[rows], self.mean[rows], self.covariance[rows])

    def replace(self, rows: NDArray[np.bool_], other: _Moments) -> _Moments:
        """A copy with ``rows`` taken from ``other`` (which holds exactly those rows)."""
        merged = [field.copy() for field in (self.log_likelihood, self.mean, self.covariance)]
        fields = (other.log_likelihood, other.mean, other.covariance)
        for target, source in zip(merged, fields, strict=True):
            target[rows] = source
        return _Moments(*merged)


@njit(cache=True)
def _log_partition(scaled, successors, start, horizon):  # pragma: no cover - compiled
    batch, cells = scaled.shape
    actions = successors.shape[1]
    values = np.empty((horizon + 1, cells))
    log_policy = np.empty((horizon, cells, actions))
    policy = np.empty((horizon, cells, actions))
    log_z = np.empty(batch)
    needed = reachable_cells(successors, start, horizon)
    for b in range(batch):
        soft_backup(scaled[b], successors, horizon, values, log_policy, policy, needed)
        log_z[b] = values[0, start]
    return log_z


@njit(cache=True)
def _trajectory_moments(scaled, features, successors, start, horizon):  # pragma: no cover
    batch, cells, k = features.shape
    actions = successors.shape[1]
    values = np.empty((horizon + 1, cells))
    log_policy = np.empty((horizon, cells, actions))
    policy = np.empty((horizon, cells, actions))
    visitation = np.empty((horizon + 1, cells))
    future = np.empty((horizon + 1, cells, k))
    log_z = np.empty(batch)
    mean = np.empty((batch, k))
    covariance = np.empty((batch, k, k))
    needed = reachable_cells(successors, start, horizon)
    for b in range(batch):
        phi = features[b]
        soft_backup(scaled[b], successors, horizon, values, log_policy, policy, needed)
        visitation[0, :] = 0.0
        visitation[0, start] = 1.0
        forward_visitation(policy, successors, visitation)
        backward_future_counts(policy, successors, phi, future, needed)
        log_z[b] = values[0, start]
        mean[b] = future[0, start]
        # E[phi phi^T] = sum_t sum_s d_t(s) sym(phi(s) (phi(s) + 2 F_t(s))^T)
        #              = sum_s sym(phi(s) (D(s) phi(s) + 2 G(s))^T),
        # with D(s) = sum_t d_t(s) and G(s) = sum_t d_t(s) F_t(s), t = 1..T.
        second = np.zeros((k, k))
        for s in range(cells):
            occupancy = 0.0
            ahead = np.zeros(k)
            for t in range(1, horizon + 1):
                d = visitation[t, s]
                if d != 0.0:
                    occupancy += d
                    for j in range(k):
                        ahead[j] += d * future[t, s, j]
            if occupancy == 0.0:
                continue
            for i in range(k):
                for j in range(k):
                    second[i, j] += phi[s, i] * (occupancy * phi[s, j] + 2.0 * ahead[j])
        for i in range(k):
            for j in range(k):
                covariance[b, i, j] = 0.5 * (second[i, j] + second[j, i]) - mean[b, i] * mean[b, j]
    return log_z, mean, covariance


def demo_log_likelihood(
    theta: FloatArray,
    demo_counts: FloatArray,
    features: FloatArray,
    successors: IntArray,
    start: int,
    horizon: int,
    rationality: float,
) -> FloatArray:
    """Demonstration log-likelihood, ``(B,)``.

    :math:`L(\\theta) = \\lambda\\,\\theta^\\top\\phi(\\tau_{demo}) - \\log Z(\\theta)`.
    """
    scaled = rationality * np.einsum("bsk,bk->bs", features, theta)
    log_z = _log_partition(scaled, successors, start, horizon)
    return rationality * np.einsum("bk,bk->b", theta, demo_counts) - log_z


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
    scaled = rationality * np.einsum("bsk,bk->bs", features, theta)
    return _trajectory_moments(
        scaled,
        np.ascontiguousarray(features, dtype=np.float64),
        np.ascontiguousarray(successors, dtype=np.int64),
        int(start),
        int(horizon),
    )


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


def _search_direction(
    gradient: FloatArray,
    hessian_neg: FloatArray,
    near_active: NDArray[np.bool_],
    damping: FloatArray,
) -> FloatArray:
    """Bertsekas's projected-Newton direction for a batch, with Levenberg-Marquardt damping.

    On the free set ``F`` it solves ``(H_FF + mu I) d_F = g_F``; on the epsilon-active set
    it takes the diagonally scaled gradient step ``d_k = g_k / (H_kk + mu)``. Both parts are
    ascent directions, which is what the line search needs. The ridge
    ``mu = damping * mean(diag H)`` keeps the system solvable where the covariance is
    singular and, when large, turns the step towards (scaled) gradient ascent.
    """
    k = gradient.shape[-1]
    free = ~near_active
    diagonal = np.diagonal(hessian_neg, axis1=1, axis2=2)
    ridge = damping * diagonal.mean(axis=1) + 1e-300
    matrix = np.where(free[:, :, None] & free[:, None, :], hessian_neg, 0.0)
    matrix = matrix + np.eye(k) * np.where(free, ridge[:, None], 1.0)[:, None, :]
    newton = np.linalg.solve(matrix, np.where(free, gradient, 0.0)[..., None])[..., 0]
    scaled_gradient = gradient / (diagonal + ridge[:, None])
    return np.where(free, newton, scaled_gradient)


def fit_maxent_irl(
    demo_counts: FloatArray,
    features: FloatArray,
    successors: IntArray,
    start: int,
    horizon: int,
    rationality: float,
    *,
    tolerance: float = 1e-6,
    max_iterations: int = 200,
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
    # Relative ridge of each trial: raised when the full step fails, lowered when it succeeds.
    damping = np.full(batch, MIN_DAMPING)

    moments = _moments(theta, demo_counts, features, *problem)
    while True:
        gradient = rationality * (demo_counts[running] - moments.mean)
        th = theta[running]
        # Projected gradient: zero where a bound blocks the ascent direction.
        projected = np.clip(th + gradient, low, high) - th
        done = np.abs(projected).max(axis=1) <= tolerance * rationality
        log_likelihood[running] = moments.log_likelihood
        converged[running] = done
        keep = ~done & (iterations[running] < max_iterations)
        if not keep.any():
            break
        running, gradient, th = running[keep], gradient[keep], th[keep]
        # Epsilon-active set (Bertsekas 1982): near a bound and pushed against it.
        epsilon = np.minimum(1e-3, np.linalg.norm(projected[keep], axis=1))[:, None]
        near_active = ((th <= low + epsilon) & (gradient < 0)) | (
            (th >= high - epsilon) & (gradient > 0)
        )
        direction = _search_direction(
            gradient, rationality**2 * moments.covariance[keep], near_active, damping[running]
        )
        # The full step usually succeeds, and its moments are the next iteration's.
        full_step = np.clip(th + direction, low, high)
        at_full_step = _moments(full_step, demo_counts[running], features[running], *problem)
        step, accepted, full = _armijo_search(
            th,
            direction,
            gradient,
            near_active,
            moments.log_likelihood[keep],
            at_full_step.log_likelihood,
            demo_counts[running],
            features[running],
            problem,
        )
        iterations[running] += 1
        theta[running] = step
        damping[running] = np.where(
            full,
            np.maximum(damping[running] / 10, MIN_DAMPING),
            np.minimum(damping[running] * 100, MAX_DAMPING),
        )
        # No ascent at floating-point resolution: the fit cannot improve further.
        iterations[running[~accepted]] = max_iterations
        shorter = accepted & ~full
        moments = moments.take(keep).replace(full, at_full_step.take(full))
        if shorter.any():
            rows = running[shorter]
            moments = moments.replace(
                shorter, _moments(theta[rows], demo_counts[rows], features[rows], *problem)
            )
    return IRLFit(theta, log_likelihood, iterations, converged)


def _armijo_search(
    theta: FloatArray,
    direction: FloatArray,
    gradient: FloatArray,
    near_active: NDArray[np.bool_],
    current: FloatArray,
    at_full_step: FloatArray,
    demo_counts: FloatArray,
    features: FloatArray,
    problem: tuple[IntArray, int, int, float],
    *,
    sufficient: float = 1e-4,
    max_halvings: int = 30,
) -> tuple[FloatArray, NDArray[np.bool_], NDArray[np.bool_]]:
    """Backtracking along the projection arc :math:`\\theta(\\alpha) = P(\\theta + \\alpha d)`.

    Accepts the first :math:`\\alpha \\in \\{1, 1/2, \\dots\\}` with (Bertsekas 1982)

    .. math::

        L(\\theta(\\alpha)) - L(\\theta) \\ge \\sigma \\Big[\\alpha \\sum_{k \\in F} g_k d_k
        + \\sum_{k \\in A} g_k (\\theta_k(\\alpha) - \\theta_k)\\Big],

    ``F`` the free and ``A`` the epsilon-active coordinates; ``at_full_step`` is
    :math:`L(\\theta(1))`, already known. Returns the new points (the old ones where no step
    was accepted), which trials accepted a step, and which accepted the full step.
    """
    low, high = BOX
    result = theta.copy()
    accepted = np.zeros(len(theta), dtype=bool)
    searching = np.arange(len(theta))
    free_slope = np.where(near_active, 0.0, gradient * direction).sum(axis=1)
    full = np.zeros(len(theta), dtype=bool)
    alpha = 1.0
    for halving in range(max_halvings):
        candidate = np.clip(theta[searching] + alpha * direction[searching], low, high)
        moved = candidate - theta[searching]
        active_slope = np.where(near_active[searching], gradient[searching] * moved, 0.0).sum(1)
        predicted = alpha * free_slope[searching] + active_slope
        if halving == 0:
            value = at_full_step
        else:
            value = demo_log_likelihood(
                candidate, demo_counts[searching], features[searching], *problem
            )
        ok = (value - current[searching] >= sufficient * predicted) & (np.abs(moved).max(1) > 0)
        result[searching[ok]] = candidate[ok]
        accepted[searching[ok]] = True
        if halving == 0:
            full[:] = ok
        searching = searching[~ok]
        if searching.size == 0:
            break
        alpha *= 0.5
    return result, accepted, full
