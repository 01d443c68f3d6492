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

The box-constrained problem is solved for a whole batch at once by Newton's method on the
box: each step maximises the objective's quadratic model exactly over the box
(:func:`box_step`, a compiled active-set method warm-started on the coordinates already on a
bound), so the step lands on the face of the box the model prefers (a projected Newton step
meets the bounds one at a time, and took more iterations: ``benchmarks/README.md``). An
Armijo backtracking search follows the step (and doubles along the projection arc where
Newton's steps stay short in exponentially flat valleys), and a Levenberg-Marquardt ridge
keeps it robust where the covariance is nearly singular. It stops
on the estimate, not on the gradient: once the undamped step is within the tolerance, that
step is taken and the result converged by the same step at the new point (``converged``).
Every linear solve is compiled, so no BLAS or LAPACK kernel enters the estimate: it is the
same on every CPU.
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

MIN_DAMPING, MAX_DAMPING = 1e-16, 1e10
"""Range of the Levenberg-Marquardt ridge, relative to the mean curvature: from machine
precision (the Hessian at large lambda can have a condition number of 1e13) to plain
gradient steps."""

RESOLUTION = 16 * np.finfo(float).eps
"""Relative rounding of the objective: changes below it are not resolved."""

DAMPING_FACTOR = 10.0
"""Factor by which the ridge falls after a full step the line search accepts, and rises after
one it cuts short (its tuning: ``benchmarks/README.md``)."""

PROBE_RATIO = 0.01
"""Least ratio of the objective's slope at the full step to its slope at the start, both
towards twice the step, at which the line search probes twice the step. A quadratic along
the ray is higher there only above 1/3, but along the exponentially flat valleys of large
lambda the objective is closer to an exponential, which rises all the way, so the threshold
is far below 1/3 (its tuning: ``benchmarks/README.md``)."""

MAX_STALLS = 8
"""Steps in a row that leave the objective unchanged at its rounding before a fit gives up."""

MAX_FACE_CHANGES = 4
"""Bounds held or freed per coordinate before :func:`box_step` gives up on a trial (it
starts on the coordinates already on a bound, so a step usually changes a few faces)."""

RIDGE_FLOOR = 1e-30
"""Absolute floor of the search's ridge, where the curvature vanishes (a single path outside
the demonstration's class holds the mass): the step is then a gradient step, cut to the box."""


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


def _search_direction(theta: FloatArray, objective: _Objective, damping: FloatArray) -> FloatArray:
    """The damped Newton step on the box for a batch: :func:`box_step` with the
    Levenberg-Marquardt ridge ``mu = damping * mean(diag H) + RIDGE_FLOOR``.

    The ridge keeps the model strictly concave where the covariance is singular and, when
    large, turns the step towards a (scaled) gradient step. Where the step fails (a pivot
    lost to rounding, or a system so nearly singular that rounding left the step not rising)
    the scaled projected gradient step :math:`P(\\theta + g / (\\mathrm{diag}\\,H + \\mu)) -
    \\theta` is taken instead: both rise, which is what the line search needs.
    """
    low, high = BOX
    gradient, curvature = objective.gradient, objective.curvature
    diagonal = np.diagonal(curvature, axis1=1, axis2=2)
    ridge = damping * diagonal.mean(axis=1) + RIDGE_FLOOR
    direction = box_step(curvature, gradient, theta, ridge)
    rises = (gradient * direction).sum(axis=1) > 0  # false where nan
    scaled_gradient = np.clip(theta + gradient / (diagonal + ridge[:, None]), low, high) - theta
    return np.where(rises[:, None], direction, scaled_gradient)


def _undamped_step(theta: FloatArray, objective: _Objective) -> tuple[FloatArray, FloatArray]:
    """The undamped Newton step on the box ``(B, K)`` and its size ``(B,)``, an estimate of
    :math:`\\max_k |\\theta_k - \\theta^*_k|` at the iterates.

    Near the optimum the step lands on the optimum's face and Newton converges quadratically
    there, so the step is the error to first order, and the error after it of the order of
    its square. The size is infinite where the free block of the Hessian is singular: the
    data do not determine the estimate there.
    """
    step = box_step(objective.curvature, objective.gradient, theta, np.zeros(len(theta)))
    size = np.abs(step).max(axis=1, initial=0.0)
    return step, np.where(np.isnan(size), np.inf, size)


@njit(cache=True)
def box_step(curvature, gradient, theta, ridge):  # pragma: no cover - compiled
    """The Newton step on the box: for each trial ``b``, the ``d`` that maximises the model

    .. math::

        m(d) = g^\\top d - \\tfrac12\\, d^\\top (H + \\rho I)\\, d
        \\quad \\text{subject to} \\quad -1 \\le \\theta_k + d_k \\le 1,

    with ``g = gradient[b]``, ``H = curvature[b]`` (positive semi-definite), ``rho =
    ridge[b]``. By a primal active-set method (Nocedal & Wright, 2006, §16.5): from ``d = 0``
    with the coordinates already on a bound held there, a Newton step on the free ones, cut
    at the first bound it meets (which then holds); once no bound is met, the bound whose
    multiplier :math:`r_k = (g - (H + \\rho I) d)_k` has the wrong sign (it pulls into the
    box) by the most is freed; it ends when none has, the model's KKT conditions. Each step
    raises ``m``, so even a cut-short result rises (:math:`g^\\top d > 0` unless ``d = 0``).

    Compiled Gaussian elimination with partial pivoting on the free block: the same
    operations in the same order on every CPU, whatever BLAS or LAPACK kernels numpy would
    pick, so an estimate does not depend on them. A trial whose free block is singular (a
    zero pivot), or that changes faces more than :data:`MAX_FACE_CHANGES` times per
    coordinate (the method can cycle where the problem is degenerate), gets an all-``nan``
    step.
    """
    low, high = BOX
    batch, k = gradient.shape
    result = np.zeros((batch, k))
    side = np.empty(k, dtype=np.int64)  # -1 held at the lower bound, +1 at the upper, 0 free
    free = np.empty(k, dtype=np.int64)
    block = np.empty((k, k))
    newton = np.empty(k)
    for b in range(batch):
        h, g, d, rho = curvature[b], gradient[b], result[b], ridge[b]
        for i in range(k):
            side[i] = -1 if theta[b, i] <= low else (1 if theta[b, i] >= high else 0)
        on_face = False  # whether d maximises the model with the held bounds fixed
        solved = False
        changes = 0  # bounds held or freed
        while changes <= MAX_FACE_CHANGES * k:
            if on_face:
                worst, most = -1, 0.0
                for i in range(k):
                    if side[i] == 0:
                        continue
                    r = _model_slope(h, g, d, rho, i)
                    if -side[i] * r > most:
                        worst, most = i, -side[i] * r
                if worst < 0:
                    solved = True
                    break
                side[worst], on_face = 0, False
                changes += 1
                continue
            n = 0
            for i in range(k):
                if side[i] == 0:
                    free[n] = i
                    n += 1
            if n == 0:
                on_face = True
                continue
            for p in range(n):
                i = free[p]
                newton[p] = _model_slope(h, g, d, rho, i)
                for q in range(n):
                    block[p, q] = h[i, free[q]]
                block[p, p] += rho
            if not _eliminate(block, newton, n):
                break
            alpha, stop, stop_side = 1.0, -1, 0
            for p in range(n):
                i, s = free[p], newton[p]
                if s > 0.0 and (high - theta[b, i]) - d[i] < alpha * s:
                    alpha, stop, stop_side = ((high - theta[b, i]) - d[i]) / s, i, 1
                elif s < 0.0 and (low - theta[b, i]) - d[i] > alpha * s:
                    alpha, stop, stop_side = ((low - theta[b, i]) - d[i]) / s, i, -1
            for p in range(n):
                i = free[p]
                d[i] = min(max(d[i] + alpha * newton[p], low - theta[b, i]), high - theta[b, i])
            if stop >= 0:
                d[stop] = (high if stop_side > 0 else low) - theta[b, stop]
                side[stop] = stop_side
                changes += 1
            else:
                on_face = True
        if not solved:
            d[:] = np.nan
    return result


@njit(cache=True)
def _model_slope(h, g, d, rho, i):  # pragma: no cover - compiled
    """:math:`r_i = (g - (H + \\rho I) d)_i`, the model's slope in coordinate ``i`` at ``d``."""
    r = g[i] - rho * d[i]
    for j in range(len(d)):
        r -= h[i, j] * d[j]
    return r


@njit(cache=True)
def _eliminate(matrix, rhs, n):  # pragma: no cover - compiled
    """Solve ``matrix[:n, :n] x = rhs[:n]`` in place (``rhs`` becomes ``x``; ``matrix`` is
    overwritten) by Gaussian elimination with partial pivoting; false if a pivot is zero."""
    for col in range(n):
        pivot = col
        for row in range(col + 1, n):
            if abs(matrix[row, col]) > abs(matrix[pivot, col]):
                pivot = row
        if matrix[pivot, col] == 0.0:
            return False
        if pivot != col:
            for j in range(n):
                matrix[col, j], matrix[pivot, j] = matrix[pivot, j], matrix[col, j]
            rhs[col], rhs[pivot] = rhs[pivot], rhs[col]
        for row in range(col + 1, n):
            factor = matrix[row, col] / matrix[col, col]
            for j in range(col, n):
                matrix[row, j] -= factor * matrix[col, j]
            rhs[row] -= factor * rhs[col]
    for row in range(n - 1, -1, -1):
        total = rhs[row]
        for j in range(row + 1, n):
            total -= matrix[row, j] * rhs[j]
        rhs[row] = total / matrix[row, row]
    return True


def _certified(theta: FloatArray, objective: _Objective, tolerance: float) -> NDArray[np.bool_]:
    """Whether ``theta`` is within ``tolerance`` of the MAP: the undamped Newton step on the
    box from there (:func:`_undamped_step`) is at most ``tolerance``."""
    _, size = _undamped_step(theta, objective)
    return size <= tolerance


def _line_search_step(
    model: MaxEnt,
    classes: DemonstrationClass,
    rows: IntArray,
    theta: FloatArray,
    objective: _Objective,
    damping: FloatArray,
    stalls: NDArray[np.int64],
    stuck: NDArray[np.bool_],
) -> _Objective:
    """One damped Newton step on the box with a line search for the trials ``rows``.

    Updates ``theta``, ``damping``, ``stalls`` (consecutive steps that did not raise the
    objective above its rounding) and ``stuck`` (set where no ascent is possible at
    floating-point resolution, or after :data:`MAX_STALLS` stalls) in place; returns the
    objective at the new points.
    """
    low, high = BOX
    th = theta[rows]
    direction = _search_direction(th, objective, damping[rows])
    sub_model, sub_classes = model.take(rows), classes.take(rows)
    # The full step usually succeeds, and its objective is the next iteration's.
    at_full_step = _Objective.at(sub_model, sub_classes, np.clip(th + direction, low, high))
    step, reached, accepted, full, longer = _armijo_search(
        lambda some, point: _Objective.value_at(
            sub_model.take(some), sub_classes.take(some), point
        ),
        th,
        direction,
        objective.gradient,
        objective.value,
        at_full_step.value,
        at_full_step.gradient,
    )
    # An objective that no longer rises above its own rounding: the data cannot place the
    # estimate any closer, and the fit stops where it is (converged only if it passes there).
    resolution = RESOLUTION * np.maximum(1.0, np.abs(objective.value))
    stalls[rows] = np.where(
        accepted & (reached - objective.value <= resolution), stalls[rows] + 1, 0
    )
    theta[rows] = step
    damping[rows] = np.where(
        full,
        np.maximum(damping[rows] / DAMPING_FACTOR, MIN_DAMPING),
        np.minimum(damping[rows] * DAMPING_FACTOR, MAX_DAMPING),
    )
    stuck[rows] = ~accepted | (stalls[rows] >= MAX_STALLS)
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

    Iteration stops on the estimate, not on the gradient: once the undamped Newton step on
    the box of :func:`_undamped_step` (the error estimate) is at most ``tolerance``, that last
    step is taken and the estimate is within about ``size^2`` of the MAP. ``converged`` says
    whether the returned point is converged, by the same step from there, however the fit
    stopped (converged, out of ``max_iterations``, or with no ascent left at the objective's
    rounding).

    Args:
        model: the MaxEnt model of the learning phase for the batch.
        demos: ``(B, T + 1)`` the demonstrations' cells :math:`s_0 .. s_T`.
        tolerance: the bound on :math:`\\max_k |\\hat\\theta_k - \\theta^*_k|` to certify.
        max_iterations: cap on Newton iterations per trial.

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
    stalls = np.zeros(batch, dtype=np.int64)
    stuck = np.zeros(batch, dtype=bool)
    objective = _Objective.at(model.take(running), classes.take(running), theta[running])
    while running.size:
        th = theta[running]
        value[running] = objective.value
        step, size = _undamped_step(th, objective)
        # The step is within the tolerance: take it unchecked (the line search cannot resolve
        # changes of the objective of order size^2) and certify the result.
        settled = size <= tolerance
        if settled.any():
            rows = running[settled]
            theta[rows] = np.clip(th[settled] + step[settled], low, high)
            at_polished = _Objective.at(model.take(rows), classes.take(rows), theta[rows])
            value[rows] = at_polished.value
            converged[rows] = _certified(theta[rows], at_polished, tolerance)
            objective = objective.replace(settled, at_polished)
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
                    damping,
                    stalls,
                    stuck,
                ),
            )
        # A fit that stops uncertified (out of iterations, or no ascent left at the objective's
        # rounding) may still have stopped within the tolerance: its last point is converged
        # as any other.
        done = converged[running] | stuck[running] | (iterations[running] >= max_iterations)
        stopped = done & ~converged[running]
        if stopped.any():
            rows = running[stopped]
            converged[rows] = _certified(theta[rows], objective.take(stopped), tolerance)
        value[running[done]] = objective.value[done]
        running, objective = running[~done], objective.take(~done)
    iterations[~flat] = np.minimum(iterations[~flat], max_iterations)
    # L = -log(m + R), with log R = -lambda * value.
    log_likelihood = -np.logaddexp(np.log(classes.members), -model.rationality * value)
    return Estimate(theta, log_likelihood, iterations, converged)


def _armijo_search(
    value_at: Callable[[IntArray, FloatArray], FloatArray],
    theta: FloatArray,
    direction: FloatArray,
    gradient: FloatArray,
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

        g(\\theta(\\alpha)) - g(\\theta) \\ge \\sigma\\,
        \\nabla g(\\theta)^\\top (\\theta(\\alpha) - \\theta),

    ``g`` the objective maximised (for :math:`\\alpha \\le 1` the arc is the segment to
    :math:`\\theta + d`, which :func:`box_step` keeps in the box);
    ``value_at(rows, points)`` evaluates it for the trials ``rows``, and ``at_full_step`` is
    :math:`g(\\theta(1))`, already known. Where the increase the test asks for is below the
    rounding of :math:`g` itself (small lambda, where :math:`g = -\\log R / \\lambda` is
    large), the full step is accepted instead when the slope along it, from the gradient
    ``gradient_at_full_step``, has not turned more steeply down than it rose: by concavity
    the step then did not overshoot the maximum along the arc. Where the full step is
    accepted, moved at least ``min_extrapolated`` and still rises towards :math:`\\theta(2)`
    by at least :data:`PROBE_RATIO` of the slope it started with, :math:`\\alpha = 2, 4,
    \\dots` is tried while the objective keeps rising with the same sufficient increase:
    along a valley whose curvature decays exponentially (large lambda, where the MAP lies on
    the box's boundary far down the valley) Newton's steps stay short, and doubling reaches
    the boundary in a few steps.

    Returns the new points (the old ones where no step was accepted), the objective there,
    which trials accepted a step, which accepted the full step, and which went further.
    """
    low, high = BOX
    result = theta.copy()
    accepted = np.zeros(len(theta), dtype=bool)
    searching = np.arange(len(theta))

    def increase(rows: IntArray, alpha: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        candidate = np.clip(theta[rows] + alpha * direction[rows], low, high)
        moved = candidate - theta[rows]
        return candidate, moved, (gradient[rows] * moved).sum(axis=1)

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
    # Probe theta(2) only where the objective still rises at theta(1) towards it (else, by
    # concavity, no point of that straight segment is higher), and by more than a sliver of
    # the slope it started with (a Newton step near the optimum lands on the maximum along
    # the ray: a probe beyond it fails).
    beyond = np.clip(theta + 2.0 * direction, low, high) - np.clip(theta + direction, low, high)
    slope_there = (gradient_at_full_step * beyond).sum(axis=1)
    rising = (slope_there > 0) & (slope_there > PROBE_RATIO * (gradient * beyond).sum(axis=1))
    moved_enough = np.abs(result - theta).max(axis=1) >= min_extrapolated
    growing = np.flatnonzero(full & moved_enough & rising)
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
