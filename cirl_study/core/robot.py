"""The robots: estimate the reward weights from one demonstration (docs/design.md §2).

A robot turns the demonstration :math:`\\tau_{demo}` into an estimate :math:`\\hat\\theta`,
reading it through the MaxEnt model of the learning phase
(:class:`cirl_study.core.maxent.MaxEnt`). Every robot is registered by name in
:data:`cirl_study.core.players.ROBOTS`; this module holds the paper's.

``map`` (the paper's robot) is the MAP under the uniform prior on the box
:math:`[-1, 1]^K`: the maximiser of the concave log-likelihood
:math:`L(\\theta) = \\lambda\\,\\theta^\\top\\phi(\\tau_{demo}) - \\log Z(\\theta)
= -\\log(m + R(\\theta))`, where ``m`` paths share the demonstration's feature counts and
:math:`R(\\theta) = \\sum_{\\Delta_\\tau \\ne 0} e^{\\lambda\\theta^\\top\\Delta_\\tau}`,
:math:`\\Delta_\\tau = \\phi(\\tau) - \\phi(\\tau_{demo})`, is the mass of all the others
(:class:`cirl_study.core.maxent.OffDemonstration`). It is found by minimising
:math:`f = \\log R / \\lambda` (convex, with gradient :math:`E_q[\\Delta]` and Hessian
:math:`\\lambda\\mathrm{Cov}_q[\\Delta]` computed without cancellation): the gradient of
:math:`L` itself, :math:`\\lambda(\\phi_{demo} - E_\\theta[\\phi])`, is lost to rounding once
the demonstration holds all but :math:`10^{-16}` of the mass (large lambda), and an iteration
that stopped on it stopped wherever rounding left it, differently on every CPU.

The box-constrained problem is solved for a whole batch at once by the projected Newton
method (Bertsekas, 1982): a Newton step on the free variables, projected back onto the box,
with an Armijo backtracking search along the projection arc (and doubling along it where
Newton's steps stay short in exponentially flat valleys); a Levenberg-Marquardt ridge keeps
it robust where the covariance is nearly singular, and variables within a small epsilon of a
bound and pushed against it take a scaled gradient step (the epsilon-active set). It stops
on the estimate, not on the gradient: once the undamped Newton step on the free set is
within the tolerance, that step is taken and the result certified by the KKT conditions
(``converged``). Every linear solve is compiled (:func:`solve`), so no BLAS or LAPACK kernel
enters the estimate: it is the same on every CPU.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import NDArray

from cirl_study.core.estimate import Estimate
from cirl_study.core.maxent import DemonstrationClass, MaxEnt
from cirl_study.core.planning import FloatArray, IntArray

BOX = (-1.0, 1.0)
"""Support of the uniform prior on each reward weight."""

MAX_STEP = BOX[1] - BOX[0]
"""Longest search direction, in every coordinate: the width of the box."""

MIN_DAMPING, MAX_DAMPING = 1e-16, 1e10
"""Range of the Levenberg-Marquardt ridge, relative to the mean curvature: from machine
precision (the Hessian at large lambda can have a condition number of 1e13) to plain
gradient steps."""

ACTIVE_EPSILON = 1e-3
"""Largest distance to a bound at which a coordinate pushed against it counts as active
(Bertsekas's epsilon, shrunk further with the distance to the optimum)."""

RESOLUTION = 16 * np.finfo(float).eps
"""Relative rounding of the objective: changes below it are not resolved."""

MAX_STALLS = 8
"""Steps in a row that leave the objective unchanged at its rounding before a fit gives up."""

RIDGE_FLOOR = 1e-30
"""Absolute floor of the ridge, where the curvature vanishes (a single path outside the
demonstration's class holds the mass): the step is then a gradient step, cut to the box."""


@dataclass(frozen=True)
class _Objective:
    """:math:`g(\\theta) = -\\log R(\\theta) / \\lambda` at the iterates, with its gradient
    :math:`-E_q[\\Delta]` and negative Hessian :math:`\\lambda\\,\\mathrm{Cov}_q[\\Delta]`
    (feature-count units; see :class:`cirl_study.core.maxent.OffDemonstration`)."""

    value: FloatArray  # (B,)
    gradient: FloatArray  # (B, K)
    curvature: FloatArray  # (B, K, K)

    @classmethod
    def at(cls, model: MaxEnt, classes: DemonstrationClass, theta: FloatArray) -> _Objective:
        off = model.off_demonstration(theta, classes)
        return cls(-off.log_mass / model.rationality, -off.mean, model.rationality * off.covariance)

    @staticmethod
    def value_at(model: MaxEnt, classes: DemonstrationClass, theta: FloatArray) -> FloatArray:
        off = model.off_demonstration(theta, classes, moments=0)
        return -off.log_mass / model.rationality

    def take(self, rows: NDArray[np.bool_]) -> _Objective:
        return _Objective(self.value[rows], self.gradient[rows], self.curvature[rows])

    def replace(self, rows: NDArray[np.bool_], other: _Objective) -> _Objective:
        """A copy with ``rows`` taken from ``other`` (which holds exactly those rows)."""
        merged = [field.copy() for field in (self.value, self.gradient, self.curvature)]
        fields = (other.value, other.gradient, other.curvature)
        for target, source in zip(merged, fields, strict=True):
            target[rows] = source
        return _Objective(*merged)


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
    singular and, when large, turns the step towards (scaled) gradient ascent. The Newton
    part is shortened to at most :data:`MAX_STEP` in every coordinate (the box's width).
    """
    k = gradient.shape[-1]
    free = ~near_active
    diagonal = np.diagonal(hessian_neg, axis1=1, axis2=2)
    ridge = damping * diagonal.mean(axis=1) + RIDGE_FLOOR
    matrix = np.where(free[:, :, None] & free[:, None, :], hessian_neg, 0.0)
    matrix = matrix + np.eye(k) * np.where(free, ridge[:, None], 1.0)[:, None, :]
    newton = solve(matrix, np.where(free, gradient, 0.0))
    scaled_gradient = gradient / (diagonal + ridge[:, None])
    # A pivot lost to rounding, or a Newton direction that does not rise (the system is so
    # nearly singular that rounding flipped a component): a scaled gradient step instead.
    with np.errstate(invalid="ignore"):  # inf * 0 where a system was singular
        slope = np.where(free, gradient * newton, 0.0).sum(axis=1, keepdims=True)
    rises = (slope > 0) | ~free.any(axis=1, keepdims=True)

    usable = np.isfinite(newton).all(axis=1, keepdims=True) & rises
    newton = np.where(usable, newton, scaled_gradient)
    # Where the objective is nearly linear (one path holds the off-demonstration mass at large
    # lambda) the curvature vanishes and the Newton step explodes: no step on the free set need
    # be longer than the box (a step on the active set only meets its bound).
    length = np.abs(np.where(free, newton, 0.0)).max(axis=1, keepdims=True)
    newton = newton * np.minimum(1.0, MAX_STEP / np.maximum(length, 1e-300))
    return np.where(free, newton, scaled_gradient)


def _newton_step(
    theta: FloatArray, gradient: FloatArray, curvature: FloatArray, near_active: NDArray[np.bool_]
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The undamped projected-Newton step ``(B, K)``, ``(B,)`` its size (an estimate of
    :math:`\\max_k |\\theta_k - \\theta^*_k|` at the iterates) and its size on the free set.

    On the free set, the Newton step :math:`H_{FF}^{-1} g_F` (near the optimum Newton converges
    quadratically, so the step is the error to first order, and the error after it is of the
    order of its square); on the epsilon-active set, the move onto the bound the gradient
    pushes against. The size is infinite where :math:`H_{FF}` is singular: the data do not
    determine the estimate there.
    """
    low, high = BOX
    free = ~near_active
    k = gradient.shape[1]
    matrix = np.where(free[:, :, None] & free[:, None, :], curvature, 0.0)
    matrix = matrix + np.eye(k) * np.where(free, 0.0, 1.0)[:, None, :]
    newton = solve(matrix, np.where(free, gradient, 0.0))
    nearest_bound = np.where(high - theta <= theta - low, high, low)
    step = np.where(free, newton, nearest_bound - theta)
    finite = np.isfinite(step).all(axis=1)
    step = np.where(finite[:, None], step, np.inf)
    size = np.abs(step).max(axis=1, initial=0.0)
    free_size = np.abs(np.where(free, step, 0.0)).max(axis=1, initial=0.0)
    return step, size, free_size


@njit(cache=True)
def solve(matrix, rhs):  # pragma: no cover - compiled
    """``x`` with ``matrix[b] @ x[b] = rhs[b]`` for a batch of small systems ``(B, K, K)``.

    Gaussian elimination with partial pivoting, compiled: the same operations in the same
    order on every CPU, whatever BLAS or LAPACK kernels numpy would pick, so an estimate does
    not depend on them. A row whose system is singular (a zero pivot) is all ``inf``.
    """
    batch, k, _ = matrix.shape
    result = np.empty((batch, k))
    a = np.empty((k, k))
    x = np.empty(k)
    for b in range(batch):
        a[:, :] = matrix[b]
        x[:] = rhs[b]
        singular = False
        for col in range(k):
            pivot = col
            for row in range(col + 1, k):
                if abs(a[row, col]) > abs(a[pivot, col]):
                    pivot = row
            if a[pivot, col] == 0.0:
                singular = True
                break
            if pivot != col:
                for j in range(k):
                    a[col, j], a[pivot, j] = a[pivot, j], a[col, j]
                x[col], x[pivot] = x[pivot], x[col]
            for row in range(col + 1, k):
                factor = a[row, col] / a[col, col]
                for j in range(col, k):
                    a[row, j] -= factor * a[col, j]
                x[row] -= factor * x[col]
        if singular:
            result[b, :] = np.inf
            continue
        for row in range(k - 1, -1, -1):
            total = x[row]
            for j in range(row + 1, k):
                total -= a[row, j] * result[b, j]
            result[b, row] = total / a[row, row]
    return result


def _certified(theta: FloatArray, objective: _Objective, tolerance: float) -> NDArray[np.bool_]:
    """Whether ``theta`` is within ``tolerance`` of the MAP, by the KKT conditions there.

    A coordinate on a bound with the gradient pushing out of the box (or zero) is active; on
    the rest, the undamped Newton step must be at most ``tolerance``.
    """
    low, high = BOX
    gradient = objective.gradient
    active = ((theta <= low) & (gradient <= 0)) | ((theta >= high) & (gradient >= 0))
    _, size, _ = _newton_step(theta, gradient, objective.curvature, active)
    return size <= tolerance


def _line_search_step(
    model: MaxEnt,
    classes: DemonstrationClass,
    rows: IntArray,
    theta: FloatArray,
    objective: _Objective,
    near_active: NDArray[np.bool_],
    damping: FloatArray,
    stalls: NDArray[np.int64],
    iterations: NDArray[np.int64],
    max_iterations: int,
) -> _Objective:
    """One damped projected-Newton step with a line search for the trials ``rows``.

    Updates ``theta``, ``damping``, ``stalls`` (consecutive steps that did not raise the
    objective above its rounding) and ``iterations`` (set to ``max_iterations`` where no ascent
    is possible at floating-point resolution, or after :data:`MAX_STALLS` stalls) in place;
    returns the objective at the new points.
    """
    low, high = BOX
    th, gradient = theta[rows], objective.gradient
    direction = _search_direction(gradient, objective.curvature, near_active, damping[rows])
    sub_model, sub_classes = model.take(rows), classes.take(rows)
    # The full step usually succeeds, and its objective is the next iteration's.
    at_full_step = _Objective.at(sub_model, sub_classes, np.clip(th + direction, low, high))
    step, reached, accepted, full, longer = _armijo_search(
        lambda some, point: _Objective.value_at(
            sub_model.take(some), sub_classes.take(some), point
        ),
        th,
        direction,
        gradient,
        near_active,
        objective.value,
        at_full_step.value,
        at_full_step.gradient,
    )
    # An objective that no longer rises above its own rounding: the data cannot place the
    # estimate any closer (it stays uncertified).
    resolution = RESOLUTION * np.maximum(1.0, np.abs(objective.value))
    stalls[rows] = np.where(
        accepted & (reached - objective.value <= resolution), stalls[rows] + 1, 0
    )
    theta[rows] = step
    damping[rows] = np.where(
        full,
        np.maximum(damping[rows] / 10, MIN_DAMPING),
        np.minimum(damping[rows] * 100, MAX_DAMPING),
    )
    iterations[rows[~accepted | (stalls[rows] >= MAX_STALLS)]] = max_iterations
    result = objective.replace(full, at_full_step.take(full))
    elsewhere = accepted & (~full | longer)
    if elsewhere.any():
        moved = rows[elsewhere]
        result = result.replace(
            elsewhere, _Objective.at(model.take(moved), classes.take(moved), theta[moved])
        )
    return result


def map_estimate(
    model: MaxEnt,
    demos: IntArray,
    *,
    tolerance: float = 1e-6,
    max_iterations: int = 200,
) -> Estimate:
    """MAP estimate of :math:`\\theta` in :math:`[-1, 1]^K` for a batch of demonstrations.

    Maximising :math:`L(\\theta) = -\\log(m + R(\\theta))` (``m`` paths share the
    demonstration's counts, :math:`R` is the mass of all others, see
    :class:`cirl_study.core.maxent.OffDemonstration`) is minimising
    :math:`\\log R(\\theta) / \\lambda`, a convex function whose gradient
    :math:`E_q[\\Delta]` and Hessian :math:`\\lambda \\mathrm{Cov}_q[\\Delta]` are computed
    without cancellation at every :math:`\\lambda`: where the demonstration holds all but
    :math:`10^{-300}` of the mass (large :math:`\\lambda`), :math:`\\nabla L` underflows but its
    direction, :math:`-E_q[\\Delta]`, does not. The two problems have the same KKT points,
    since :math:`\\nabla L = -\\lambda \\frac{R}{m + R} E_q[\\Delta]`. As
    :math:`\\lambda \\to \\infty`, :math:`\\log R / \\lambda \\to \\max_\\tau
    \\theta^\\top \\Delta_\\tau`: the max-margin problem.

    Iteration stops on the estimate, not on the gradient: once the undamped Newton step of
    :func:`_newton_step` (the error estimate) is at most ``tolerance``, that last step is taken
    and the estimate is within about ``size^2`` of the MAP; ``converged`` says whether that
    happened within ``max_iterations``.

    Args:
        model: the MaxEnt model of the learning phase for the batch.
        demos: ``(B, T + 1)`` the demonstrations' cells :math:`s_0 .. s_T`.
        tolerance: the bound on :math:`\\max_k |\\hat\\theta_k - \\theta^*_k|` to certify.
        max_iterations: cap on projected-Newton iterations per trial.

    Returns:
        An :class:`Estimate`; ``log_likelihood`` is :math:`L(\\hat\\theta)`. Iteration starts
        at the prior mean :math:`\\theta = 0`.

    Examples:
        >>> import numpy as np
        >>> from cirl_study.core.gridworld import Gridworld, rbf_features
        >>> from cirl_study.core.maxent import MaxEnt, Phase
        >>> grid = Gridworld(4, 4)
        >>> phi = rbf_features(grid, [[0.0, 0.0], [3.0, 3.0]], 1.0)[None]
        >>> demo = [grid.index(1, 0), grid.index(1, 1), grid.index(2, 1), grid.index(2, 2)]
        >>> model = MaxEnt(Phase(grid.successors, grid.index(1, 0), 3), phi, 1.0)
        >>> fit = map_estimate(model, np.array([demo]))
        >>> bool(fit.converged[0]), bool(fit.theta_hat[0, 1] > fit.theta_hat[0, 0])
        (True, True)
    """
    low, high = BOX
    demos = np.asarray(demos, dtype=np.int64)
    classes = model.demonstration_classes(demos)
    batch, k = model.batch, model.features.shape[2]
    theta = np.zeros((batch, k))
    value = np.empty(batch)
    iterations = np.zeros(batch, dtype=np.int64)
    converged = np.zeros(batch, dtype=bool)
    # Every path shares the demonstration's counts: the likelihood is flat, keep the prior mean.
    flat = np.diff(classes.offsets) == 0
    converged[flat] = True
    value[flat] = np.inf  # log R = -inf: no path outside the class
    running = np.flatnonzero(~flat)
    # Relative ridge of each trial: raised when the full step fails, lowered when it succeeds.
    damping = np.full(batch, MIN_DAMPING)
    last_size = np.full(batch, np.inf)
    stalls = np.zeros(batch, dtype=np.int64)
    objective = _Objective.at(model.take(running), classes.take(running), theta[running])
    while running.size:
        gradient, th = objective.gradient, theta[running]
        value[running] = objective.value
        # Projected gradient: zero where a bound blocks the ascent direction.
        projected = np.clip(th + gradient, low, high) - th
        # Epsilon-active set (Bertsekas 1982): near a bound and pushed against it, epsilon
        # shrinking with the distance to the optimum, measured in Newton steps (the previous
        # iteration's) as well as by the gradient, whose size alone means little where the
        # curvature is tiny.
        distance = np.maximum(np.linalg.norm(projected, axis=1), last_size[running])
        epsilon = np.minimum(ACTIVE_EPSILON, distance)[:, None]
        near_active = ((th <= low + epsilon) & (gradient < 0)) | (
            (th >= high - epsilon) & (gradient > 0)
        )
        step, size, free_size = _newton_step(th, gradient, objective.curvature, near_active)
        last_size[running] = free_size
        # The free coordinates are within the tolerance: take the last Newton step unchecked
        # (the line search cannot resolve changes of the objective of order size^2), which
        # also puts the active coordinates on their bounds, and certify the result. A
        # coordinate near a bound whose gradient merely rounds towards it may be at an interior
        # optimum: where the first polish fails, a second one keeps on their bounds only the
        # coordinates already there.
        settled = free_size <= tolerance
        on_bound = ((th <= low) & (gradient <= 0)) | ((th >= high) & (gradient >= 0))
        curvature = objective.curvature
        for active in (near_active, on_bound):
            if active is on_bound:  # the step for near_active is the one computed above
                step, _, free_size = _newton_step(th, gradient, curvature, active)
            trying = settled & ~converged[running] & (free_size <= tolerance)
            if not trying.any():
                continue
            rows = running[trying]
            theta[rows] = np.clip(th[trying] + step[trying], low, high)
            at_polished = _Objective.at(model.take(rows), classes.take(rows), theta[rows])
            value[rows] = at_polished.value
            converged[rows] = _certified(theta[rows], at_polished, tolerance)
            objective = objective.replace(trying, at_polished)
        iterations[running] += 1
        moving = ~settled & (iterations[running] <= max_iterations)
        if moving.any():
            rows = running[moving]
            objective = objective.replace(
                moving,
                _line_search_step(
                    model,
                    classes,
                    rows,
                    theta,
                    objective.take(moving),
                    near_active[moving],
                    damping,
                    stalls,
                    iterations,
                    max_iterations,
                ),
            )
        keep = ~converged[running] & (iterations[running] < max_iterations)
        running, objective = running[keep], objective.take(keep)
    iterations[~flat] = np.minimum(iterations[~flat], max_iterations)
    # L = -log(m + R), with log R = -lambda * value.
    log_likelihood = -np.logaddexp(np.log(classes.members), -model.rationality * value)
    return Estimate(theta, log_likelihood, iterations, converged)


def _armijo_search(
    value_at: Callable[[IntArray, FloatArray], FloatArray],
    theta: FloatArray,
    direction: FloatArray,
    gradient: FloatArray,
    near_active: NDArray[np.bool_],
    current: FloatArray,
    at_full_step: FloatArray,
    gradient_at_full_step: FloatArray,
    *,
    sufficient: float = 1e-4,
    max_halvings: int = 30,
    min_extrapolated: float = 1e-4,
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_], NDArray[np.bool_], NDArray[np.bool_]]:
    """Backtracking along the projection arc :math:`\\theta(\\alpha) = P(\\theta + \\alpha d)`.

    Accepts the first :math:`\\alpha \\in \\{1, 1/2, \\dots\\}` with (Bertsekas 1982)

    .. math::

        g(\\theta(\\alpha)) - g(\\theta) \\ge \\sigma \\Big[\\alpha \\sum_{k \\in F} g_k d_k
        + \\sum_{k \\in A} g_k (\\theta_k(\\alpha) - \\theta_k)\\Big],

    ``F`` the free and ``A`` the epsilon-active coordinates, ``g`` the objective maximised;
    ``value_at(rows, points)`` evaluates it for the trials ``rows``, and ``at_full_step`` is
    :math:`g(\\theta(1))`, already known. Where the increase the test asks for is below the
    rounding of :math:`g` itself (small lambda, where :math:`g = -\\log R / \\lambda` is
    large), the full step is accepted instead when the slope along it, from the gradient
    ``gradient_at_full_step``, has not turned more steeply down than it rose: by concavity
    the step then did not overshoot the maximum along the arc. Where the full step is
    accepted and moved at least ``min_extrapolated``, :math:`\\alpha = 2, 4, \\dots` is
    tried while the objective keeps rising with the same sufficient increase: along a valley
    whose curvature decays exponentially (large lambda, where the MAP lies on the box's
    boundary far down the valley) Newton's steps stay short, and doubling reaches the
    boundary in a few steps.

    Returns the new points (the old ones where no step was accepted), the objective there,
    which trials accepted a step, which accepted the full step, and which went further.
    """
    low, high = BOX
    result = theta.copy()
    accepted = np.zeros(len(theta), dtype=bool)
    searching = np.arange(len(theta))
    free_slope = np.where(near_active, 0.0, gradient * direction).sum(axis=1)

    def increase(rows: IntArray, alpha: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        candidate = np.clip(theta[rows] + alpha * direction[rows], low, high)
        moved = candidate - theta[rows]
        active_slope = np.where(near_active[rows], gradient[rows] * moved, 0.0).sum(1)
        return candidate, moved, alpha * free_slope[rows] + active_slope

    full = np.zeros(len(theta), dtype=bool)
    best = current.copy()
    alpha = 1.0
    for halving in range(max_halvings):
        candidate, moved, predicted = increase(searching, alpha)
        value = at_full_step if halving == 0 else value_at(searching, candidate)
        ok = (value - current[searching] >= sufficient * predicted) & (np.abs(moved).max(1) > 0)
        if halving == 0:
            resolution = RESOLUTION * np.maximum(1.0, np.abs(current))
            slope_before = (gradient * moved).sum(axis=1)
            slope_after = (gradient_at_full_step * moved).sum(axis=1)
            unresolved = (sufficient * predicted <= resolution) & (slope_before > 0)
            ok |= unresolved & (slope_after >= -slope_before) & (np.abs(moved).max(1) > 0)
        result[searching[ok]] = candidate[ok]
        best[searching[ok]] = value[ok]
        accepted[searching[ok]] = True
        if halving == 0:
            full[:] = ok
        searching = searching[~ok]
        if searching.size == 0:
            break
        alpha *= 0.5
    longer = np.zeros(len(theta), dtype=bool)
    growing = np.flatnonzero(full & (np.abs(result - theta).max(axis=1) >= min_extrapolated))
    alpha = 2.0
    while growing.size and alpha <= 2.0**max_halvings:
        candidate, moved, predicted = increase(growing, alpha)
        further = np.abs(candidate - result[growing]).max(axis=1) > 0
        value = value_at(growing, candidate)
        ok = (
            further & (value > best[growing]) & (value - current[growing] >= sufficient * predicted)
        )
        rows = growing[ok]
        result[rows], best[rows], longer[rows] = candidate[ok], value[ok], True
        growing, alpha = rows, 2.0 * alpha
    return result, best, accepted, full, longer
