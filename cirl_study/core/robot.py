"""The robots: estimate the reward weights from one demonstration (docs/design.md §2).

A robot turns the demonstration's feature counts :math:`\\phi(\\tau_{demo})` into an estimate
:math:`\\hat\\theta`, reading the demonstration through the MaxEnt model of the learning phase
(:class:`cirl_study.core.maxent.MaxEnt`). Robots are looked up by name in :data:`ROBOTS`;
adding one is one function and one :func:`register_robot` line.

``map`` (the paper's robot) is the MAP under the uniform prior on the box
:math:`[-1, 1]^K`, i.e. the maximiser of the concave log-likelihood
:math:`L(\\theta) = \\lambda\\,\\theta^\\top\\phi(\\tau_{demo}) - \\log Z(\\theta)`, with gradient
:math:`\\lambda(\\phi(\\tau_{demo}) - E_\\theta[\\phi(\\tau)])` and Hessian
:math:`-\\lambda^2 \\mathrm{Cov}_\\theta[\\phi(\\tau)]`, both exact
(:meth:`cirl_study.core.maxent.MaxEnt.moments`).

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

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cirl_study.core.maxent import MaxEnt, Moments
from cirl_study.core.planning import FloatArray
from cirl_study.record import MAP

BOX = (-1.0, 1.0)
"""Support of the uniform prior on each reward weight."""

MIN_DAMPING, MAX_DAMPING = 1e-10, 1e10
"""Range of the Levenberg-Marquardt ridge, relative to the mean curvature."""


@dataclass(frozen=True)
class Estimate:
    """A robot's estimates for a batch of demonstrations.

    Attributes:
        theta_hat: ``(B, K)`` estimated reward weights in the box.
        log_likelihood: ``(B,)`` :math:`\\log P(\\tau_{demo} \\mid \\hat\\theta, \\lambda)`.
        iterations: ``(B,)`` iterations of the estimator.
        converged: ``(B,)`` whether the estimator met its stopping rule.
        theta_hat_se: ``(B, K)`` Monte-Carlo standard error of each coordinate, for a robot
            whose estimate is random (else ``None``).
        effective_sample_size: ``(B,)`` the Monte-Carlo effective sample size (else ``None``).
    """

    theta_hat: FloatArray
    log_likelihood: FloatArray
    iterations: NDArray[np.int64]
    converged: NDArray[np.bool_]
    theta_hat_se: FloatArray | None = None
    effective_sample_size: FloatArray | None = None


Estimator = Callable[[MaxEnt, FloatArray, NDArray[np.int64]], Estimate]
"""A robot: ``estimate(model, demo_counts, seeds)`` for the batch of ``model``'s trials.

``seeds`` ``(B,)`` are the trials' own seeds (:attr:`cirl_study.record.TrialSpec.seed`); a
robot that draws random numbers derives its generator from them with
:func:`robot_generator`, so its estimate depends on its trial alone.
"""

ROBOT_STREAM = 1
"""Spawn key that separates a robot's random stream from the trial's other uses of its seed."""


def robot_generator(seed: int) -> np.random.Generator:
    """The random generator of the robot of the trial with ``seed``."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(ROBOT_STREAM,)))


@dataclass(frozen=True)
class _Ascent:
    """The log-likelihood at the current iterates, with the moments that give its derivatives."""

    log_likelihood: FloatArray  # (B,)
    mean: FloatArray  # (B, K)  E[phi(tau)]
    covariance: FloatArray  # (B, K, K)  Cov[phi(tau)]

    @classmethod
    def at(cls, model: MaxEnt, theta: FloatArray, demo_counts: FloatArray) -> _Ascent:
        moments: Moments = model.moments(theta)
        log_likelihood = model.rationality * np.einsum("bk,bk->b", theta, demo_counts)
        return cls(log_likelihood - moments.log_partition, moments.mean, moments.covariance)

    def take(self, rows: NDArray[np.bool_]) -> _Ascent:
        return _Ascent(self.log_likelihood[rows], self.mean[rows], self.covariance[rows])

    def replace(self, rows: NDArray[np.bool_], other: _Ascent) -> _Ascent:
        """A copy with ``rows`` taken from ``other`` (which holds exactly those rows)."""
        merged = [field.copy() for field in (self.log_likelihood, self.mean, self.covariance)]
        fields = (other.log_likelihood, other.mean, other.covariance)
        for target, source in zip(merged, fields, strict=True):
            target[rows] = source
        return _Ascent(*merged)


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


def map_estimate(
    model: MaxEnt,
    demo_counts: FloatArray,
    *,
    tolerance: float = 1e-6,
    max_iterations: int = 200,
) -> Estimate:
    """MAP estimate of :math:`\\theta` in :math:`[-1, 1]^K` for a batch of demonstrations.

    Args:
        model: the MaxEnt model of the learning phase for the batch.
        demo_counts: ``(B, K)`` feature counts :math:`\\phi(\\tau_{demo})` of the demonstrations.
        tolerance: stop when :math:`\\lVert P_{box}\\nabla L\\rVert_\\infty / \\lambda` is below it.
        max_iterations: cap on projected-Newton iterations per trial.

    Returns:
        An :class:`Estimate`. Iteration starts at the prior mean :math:`\\theta = 0`.

    Examples:
        >>> import numpy as np
        >>> from cirl_study.core.gridworld import Gridworld, rbf_features
        >>> from cirl_study.core.maxent import MaxEnt, Phase
        >>> grid = Gridworld(4, 4)
        >>> phi = rbf_features(grid, [[0.0, 0.0], [3.0, 3.0]], 1.0)[None]
        >>> demo = phi[0, [grid.index(1, 1), grid.index(2, 2), grid.index(3, 3)]].sum(0)
        >>> model = MaxEnt(Phase(grid.successors, grid.index(1, 0), 3), phi, 1.0)
        >>> fit = map_estimate(model, demo[None])
        >>> bool(fit.converged[0]), bool(fit.theta_hat[0, 1] > fit.theta_hat[0, 0])
        (True, True)
    """
    low, high = BOX
    rationality = model.rationality
    demo_counts = np.asarray(demo_counts, dtype=np.float64)
    batch, k = demo_counts.shape
    theta = np.zeros((batch, k))
    log_likelihood = np.empty(batch)
    iterations = np.zeros(batch, dtype=np.int64)
    converged = np.zeros(batch, dtype=bool)
    running = np.arange(batch)
    # Relative ridge of each trial: raised when the full step fails, lowered when it succeeds.
    damping = np.full(batch, MIN_DAMPING)

    ascent = _Ascent.at(model, theta, demo_counts)
    while True:
        gradient = rationality * (demo_counts[running] - ascent.mean)
        th = theta[running]
        # Projected gradient: zero where a bound blocks the ascent direction.
        projected = np.clip(th + gradient, low, high) - th
        done = np.abs(projected).max(axis=1) <= tolerance * rationality
        log_likelihood[running] = ascent.log_likelihood
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
            gradient, rationality**2 * ascent.covariance[keep], near_active, damping[running]
        )
        # The full step usually succeeds, and its moments are the next iteration's.
        running_model = model.take(running)
        full_step = np.clip(th + direction, low, high)
        at_full_step = _Ascent.at(running_model, full_step, demo_counts[running])
        step, accepted, full = _armijo_search(
            running_model,
            th,
            direction,
            gradient,
            near_active,
            ascent.log_likelihood[keep],
            at_full_step.log_likelihood,
            demo_counts[running],
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
        ascent = ascent.take(keep).replace(full, at_full_step.take(full))
        if shorter.any():
            rows = running[shorter]
            ascent = ascent.replace(
                shorter, _Ascent.at(model.take(rows), theta[rows], demo_counts[rows])
            )
    return Estimate(theta, log_likelihood, iterations, converged)


def _armijo_search(
    model: MaxEnt,
    theta: FloatArray,
    direction: FloatArray,
    gradient: FloatArray,
    near_active: NDArray[np.bool_],
    current: FloatArray,
    at_full_step: FloatArray,
    demo_counts: FloatArray,
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
            value = model.take(searching).log_likelihood(candidate, demo_counts[searching])
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


ROBOTS: dict[str, Estimator] = {}
"""Every robot, by the name a pipeline and a trial record use (``robot``)."""


def register_robot(name: str, estimate: Estimator) -> None:
    """Make ``estimate`` playable as the robot ``name``."""
    if name in ROBOTS:
        raise ValueError(f"a robot named {name!r} is already registered")
    ROBOTS[name] = estimate


register_robot(MAP, lambda model, demo_counts, seeds: map_estimate(model, demo_counts))
