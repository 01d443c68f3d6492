"""The Bayes-optimal robot ``posterior_mean``: :math:`E[\\theta \\mid \\tau_{demo}]` (design.md §2).

The robot's belief after the demonstration is the posterior under the uniform prior on the box
:math:`[-1, 1]^K` and the MaxEnt likelihood (:class:`cirl_study.core.maxent.MaxEnt`),

.. math::

    p(\\theta \\mid \\tau_{demo}) \\propto e^{L(\\theta)}\\, 1[\\theta \\in [-1, 1]^K], \\qquad
    L(\\theta) = \\lambda\\, \\theta^\\top \\phi(\\tau_{demo}) - \\log Z(\\theta).

With linear rewards, acting optimally for the posterior-mean reward
:math:`\\hat\\theta = E[\\theta \\mid \\tau_{demo}]` is the robot's best deployment policy
given its belief (the paper's Theorem 2), so this robot is the Bayes-optimal counterpart of the
paper's MAP robot (:func:`cirl_study.core.robot.map_estimate`).

**Method: adaptive multiple importance sampling in the probit space, with control variates.**

* *Probit space.* Write :math:`\\theta_k = 2\\Phi(u_k) - 1 = \\mathrm{erf}(u_k/\\sqrt2)`. The
  uniform prior on the box is exactly :math:`u \\sim N(0, I)`, so the target is
  :math:`\\pi(u) \\propto e^{L(\\theta(u))} N(u; 0, I)` on all of :math:`R^K`: no box edges
  to truncate at, and the prior itself is one of the proposals.
* *Proposals.* Round 0 draws ``round_size`` points from the prior. Every later round draws
  from a Gaussian :math:`q_r = N(m_r, c\\, S_r)` (``c`` = ``inflation``) whose mean and
  covariance are the importance-weighted moments of all points drawn so far, for the tempered
  target :math:`\\pi_\\beta \\propto e^{\\beta L} N(0, I)`; the temperature
  :math:`\\beta \\in (0, 1]` is the largest whose weights keep an effective sample size of
  ``min_ess``, so the proposals walk from the prior to the posterior in as many rounds as the
  demonstration's information requires (none at small :math:`\\lambda`, three to ten at
  :math:`\\lambda = 10^3`, K = 10), then keep adapting at :math:`\\beta = 1`. A share
  ``defensive`` of every round comes from the prior, and, when the previous round's weights
  were heavy-tailed (its own ESS fraction below ``wide_below``: the polytope-like posteriors
  of large :math:`\\lambda`), a share ``wide_share`` from the same Gaussian with
  ``wide_scale`` times its covariance, to reach the polytope's corners.
* *Weights.* All points of all rounds are kept and weighted against the mixture of every
  proposal used (the balance heuristic, or deterministic mixture; Veach & Guibas, 1995;
  Owen & Zhou, 2000; AMIS, Cornuet et al., 2012):

  .. math::

      w_i = \\frac{e^{L(\\theta_i)} N(u_i; 0, I)}{Q(u_i)}, \\qquad
      Q = \\sum_c \\frac{n_c}{N} q_c,

  ``n_c`` the points drawn from component ``c`` (prior, fitted, wide) of ``N`` in all.
* *Control variates.* The self-normalised estimate
  :math:`\\bar\\theta = \\sum_i w_i \\theta_i / \\sum_i w_i` is corrected by a regression on
  :math:`h = (u, \\theta)`, whose mean under :math:`Q` is known exactly (under
  :math:`N(m, S)`, :math:`E[\\theta_k] = \\mathrm{erf}(m_k / \\sqrt{2 (1 + S_{kk})})`):

  .. math::

      \\hat\\theta = \\bar\\theta - \\gamma^\\top (\\bar h - E_Q[h]), \\qquad
      z_i = \\frac{w_i (\\theta_i - \\bar\\theta)}{\\bar w},

  :math:`\\gamma` the least-squares regression of :math:`z` on :math:`(1, h)`. Where a
  proposal is close to the posterior (the prior at small :math:`\\lambda`, the fitted
  Gaussian at moderate :math:`\\lambda`) :math:`z` is nearly linear in :math:`h`, and the
  correction removes most of the noise of the wide, weakly identified coordinates.
* *Standard error*, by the delta method: with the residuals :math:`\\rho_{ik}` of that
  regression and ``p = 2K + 1`` regressors,
  :math:`\\mathrm{se}_k^2 = \\sum_i \\rho_{ik}^2 / (N (N - p))` (while the ESS is below
  ``min_ess``, at least Kish's :math:`\\mathrm{sd}_k / \\sqrt{\\mathrm{ESS}}`). Rounds go on
  until every :math:`\\mathrm{se}_k \\le` ``target_se`` with an ESS of at least ``min_ess``
  (``converged``), each sized by :math:`N\\, ((\\mathrm{se}/\\mathrm{target})^2 - 1)` (at most
  doubling ``N``), or until ``max_samples`` likelihood evaluations (``iterations``).

Why this method and not another, and what it costs per trial at each :math:`\\lambda`:
measured in ``benchmarks/README.md`` (*The posterior-mean robot*);
``benchmarks/bench_posterior.py`` measures it again.

**Determinism.** Each trial draws from its own generator,
:func:`cirl_study.core.estimate.robot_generator` of its seed, in an order fixed by its own
data; a trial's points are scored by :meth:`cirl_study.core.maxent.MaxEnt.log_likelihood_at`
point by point, and every other floating-point reduction and solve that feeds its decisions or
its estimate is a compiled loop in a fixed order (the kernels here and
:mod:`cirl_study.core.linalg`, without ``fastmath``, calling the C library's ``exp``,
``log`` and ``log1p``): the draws' transform :math:`m + L x` by the Cholesky factor
:math:`L` of :math:`S`, the components' densities (forward substitution by :math:`L`), the
mixture's log-sums, the weights and their ESS, the weighted moments, the Gram matrix, and the
control-variate regression, whose :math:`\\gamma` is the minimum-norm least-squares solution
of the normal equations with ``np.linalg.lstsq``'s cutoff
(:func:`cirl_study.core.linalg.symmetric_lstsq`). No BLAS or LAPACK kernel and no
SIMD-dispatched numpy loop enters the estimate: numpy's matrix products sum in the order of
the BLAS kernel that the CPU selects, and its ``exp`` and ``log`` have AVX512 variants, and
one last bit there can flip a stopping decision, which moves the estimate by about its
standard error. So an estimate is bitwise the same on every x86-64 CPU, BLAS kernel and
thread count, and does not depend on the other trials of its batch, their order or
``chunk`` (trials that ask for rounds of the same size are scored in one call). The kernels
use numba's numpy error model: every divisor in them is a positive total, scale or pivot, and
without the zero check that Python's model adds to each division their loops vectorise (the
same operations per element, so the same bits).
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from numpy.typing import NDArray
from scipy.special import erf

from cirl_study.core.estimate import Estimate, robot_generator
from cirl_study.core.linalg import cholesky, symmetric_lstsq
from cirl_study.core.maxent import MaxEnt
from cirl_study.core.planning import FloatArray, IntArray

_SQRT2 = math.sqrt(2.0)
_LOG_2PI = math.log(2.0 * math.pi)


def theta_of(u: FloatArray) -> FloatArray:
    """The box point :math:`\\theta = 2\\Phi(u) - 1 = \\mathrm{erf}(u / \\sqrt2)` of ``u``."""
    return erf(u / _SQRT2)


_PDF_BLOCK = 128
"""Points whose densities :func:`_log_pdf` forms together, in its innermost loops."""


@njit(cache=True, error_model="numpy")
def _log_pdf(u, mean, chol, log_norm):  # pragma: no cover - compiled
    """``(N,)`` :math:`\\log N(u_i; m, L L^\\top)`: :math:`z = L^{-1}(u_i - m)` by forward
    substitution, ``log_norm`` :math:`- \\frac12 |z|^2`, each point's sums in the order of
    the coordinates (``_PDF_BLOCK`` points at a time in the innermost loops, free to run in
    SIMD lanes)."""
    n, k = u.shape
    z = np.empty((k, _PDF_BLOCK))
    total = np.empty(_PDF_BLOCK)
    out = np.empty(n)
    for begin in range(0, n, _PDF_BLOCK):
        width = min(_PDF_BLOCK, n - begin)
        for i in range(width):
            total[i] = 0.0
        for j in range(k):
            row = z[j]
            centre = mean[j]
            for i in range(width):
                row[i] = u[begin + i, j] - centre
            for m in range(j):
                factor, previous = chol[j, m], z[m]
                for i in range(width):
                    row[i] -= factor * previous[i]
            pivot = chol[j, j]
            for i in range(width):
                row[i] /= pivot
                total[i] += row[i] * row[i]
        for i in range(width):
            out[begin + i] = log_norm - 0.5 * total[i]
    return out


@njit(cache=True, error_model="numpy")
def _transform(normals, mean, chol):  # pragma: no cover - compiled
    """``(N, K)`` points :math:`m + L x_i` of standard normal draws :math:`x_i`."""
    n, k = normals.shape
    out = np.empty((n, k))
    for i in range(n):
        for j in range(k):
            value = 0.0
            for m in range(j + 1):
                value += chol[j, m] * normals[i, m]
            out[i, j] = mean[j] + value
    return out


@dataclass(frozen=True, eq=False)
class _Gaussian:
    """A proposal component :math:`N(m, S)` in the probit space."""

    mean: FloatArray
    covariance: FloatArray
    _chol: FloatArray = field(init=False, repr=False)
    _log_norm: float = field(init=False, repr=False)

    def __post_init__(self) -> None:
        chol = cholesky(self.covariance)
        object.__setattr__(self, "_chol", chol)
        log_det = 2.0 * math.fsum(math.log(d) for d in np.diag(chol))
        object.__setattr__(self, "_log_norm", -0.5 * (len(self.mean) * _LOG_2PI + log_det))

    def log_pdf(self, u: FloatArray) -> FloatArray:
        return _log_pdf(u, self.mean, self._chol, self._log_norm)

    def draw(self, rng: np.random.Generator, n: int) -> FloatArray:
        return _transform(rng.standard_normal((n, len(self.mean))), self.mean, self._chol)

    def theta_mean(self) -> FloatArray:
        """:math:`E[\\theta]`: :math:`E[2\\Phi(u_k) - 1] = 2\\Phi(m_k / \\sqrt{1 + S_{kk}}) - 1`."""
        return erf(self.mean / np.sqrt(2.0 * (1.0 + np.diag(self.covariance))))


@njit(cache=True, error_model="numpy")
def _ess(weights):  # pragma: no cover - compiled
    """Kish's effective sample size :math:`(\\sum w)^2 / \\sum w^2`."""
    total = 0.0
    square = 0.0
    for w in weights:
        total += w
        square += w * w
    return total * total / square if total > 0.0 else 0.0


@njit(cache=True, error_model="numpy")
def _weights(log_lik, log_base, beta):  # pragma: no cover - compiled
    """:math:`w_i = e^{l_i - \\max_j l_j}` of :math:`l_i = \\beta L_i +` ``log_base[i]``."""
    n = len(log_lik)
    log_w = np.empty(n)
    top = -np.inf
    for i in range(n):
        log_w[i] = beta * log_lik[i] + log_base[i]
        top = max(top, log_w[i])
    for i in range(n):
        log_w[i] = math.exp(log_w[i] - top)
    return log_w


@njit(cache=True, error_model="numpy")
def _temperature(log_lik, log_base, low, min_ess):  # pragma: no cover - compiled
    """The tempering's :math:`\\beta`: from ``low`` (whose weights keep an ESS of
    ``min_ess``) toward 1 by 50 halvings of the interval, the largest found whose weights
    (:func:`_weights`) keep it."""
    high = 1.0
    for _ in range(50):
        middle = 0.5 * (low + high)
        if _ess(_weights(log_lik, log_base, middle)) >= min_ess:
            low = middle
        else:
            high = middle
    return low


@njit(cache=True, error_model="numpy")
def _log_add_exp(a, b):  # pragma: no cover - compiled
    """Elementwise :math:`\\log(e^a + e^b)`."""
    out = np.empty(len(a))
    for i in range(len(a)):
        x, y = a[i], b[i]
        if x == y:
            out[i] = x + math.log(2.0)
        elif x > y:
            out[i] = x + math.log1p(math.exp(y - x))
        else:
            out[i] = y + math.log1p(math.exp(x - y))
    return out


@njit(cache=True, error_model="numpy")
def _log_sum_exp(terms):  # pragma: no cover - compiled
    """``(N,)`` :math:`\\log \\sum_c e^{t_{ci}}` of ``terms`` ``(C, N)``, ``C >= 1``."""
    count, n = terms.shape
    out = np.empty(n)
    for i in range(n):
        top = -np.inf
        for c in range(count):
            top = max(top, terms[c, i])
        if top == -np.inf:
            out[i] = top
            continue
        total = 0.0
        for c in range(count):
            total += math.exp(terms[c, i] - top)
        out[i] = top + math.log(total)
    return out


@njit(cache=True, error_model="numpy")
def _weighted_moments(weights, u):  # pragma: no cover - compiled
    """Mean :math:`\\sum_i \\bar w_i u_i` and covariance
    :math:`\\sum_i \\bar w_i (u_i - m)(u_i - m)^\\top`, :math:`\\bar w = w / \\sum w`."""
    n, k = u.shape
    total = 0.0
    for i in range(n):
        total += weights[i]
    mean = np.zeros(k)
    for i in range(n):
        w = weights[i] / total
        for j in range(k):
            mean[j] += w * u[i, j]
    covariance = np.zeros((k, k))
    centered = np.empty(k)
    for i in range(n):
        w = weights[i] / total
        for j in range(k):
            centered[j] = u[i, j] - mean[j]
        for j in range(k):
            scaled = w * centered[j]
            for m in range(j + 1):
                covariance[j, m] += scaled * centered[m]
    for j in range(k):
        for m in range(j):
            covariance[m, j] = covariance[j, m]
    return mean, covariance


@njit(cache=True, inline="always", error_model="numpy")
def _regressors(u, theta, i, row):  # pragma: no cover - compiled
    """Point ``i``'s regressors :math:`(1, u_i, \\theta_i)`, written into ``row``."""
    k = u.shape[1]
    row[0] = 1.0
    for j in range(k):
        row[1 + j] = u[i, j]
        row[1 + k + j] = theta[i, j]


@njit(cache=True, error_model="numpy")
def _gram(u, theta):  # pragma: no cover - compiled
    """``(P, P)`` :math:`X^\\top X` of the regressors :math:`X_i = (1, u_i, \\theta_i)`,
    ``P = 2K + 1``, summed over the points in order."""
    n, k = u.shape
    p = 1 + 2 * k
    row = np.empty(p)
    out = np.zeros((p, p))
    for i in range(n):
        _regressors(u, theta, i, row)
        for j in range(p):
            x = row[j]
            for m in range(j + 1):
                out[j, m] += x * row[m]
    for j in range(p):
        for m in range(j):
            out[m, j] = out[j, m]
    return out


@njit(cache=True, error_model="numpy")
def _control_variate_fit(weights, u, theta, gram, control_means):  # pragma: no cover - compiled
    """The control-variate regression of the module docstring at weights ``weights``.

    The regressors of point ``i`` are :math:`X_i = (1, u_i, \\theta_i)` and ``gram`` is
    :math:`X^\\top X`. Returns Kish's ESS; :math:`\\bar\\theta - \\gamma^\\top(\\bar h -
    E_Q[h])` (unclipped); :math:`\\sum_i \\rho_{ik}^2`, the residuals' sums of squares; and the
    weighted standard deviation :math:`\\mathrm{sd}_k` of :math:`\\theta_k`.
    :math:`\\gamma` solves the normal equations ``gram`` :math:`\\gamma = X^\\top z` by
    :func:`symmetric_lstsq`.
    """
    n, k = theta.shape
    p = 1 + 2 * k
    ess = _ess(weights)
    total = 0.0
    for i in range(n):
        total += weights[i]
    mean = np.zeros(k)
    for i in range(n):
        for j in range(k):
            mean[j] += weights[i] * theta[i, j]
    for j in range(k):
        mean[j] /= total
    scale = total / n
    row = np.empty(p)
    z = np.empty(k)
    spread = np.zeros(k)
    square = np.zeros(k)  # z^T z
    moment = np.zeros((p, k))  # X^T z
    shift = np.zeros(p)  # the regressors' sums
    for i in range(n):
        for j in range(k):
            deviation = theta[i, j] - mean[j]
            z[j] = (weights[i] / scale) * deviation
            spread[j] += weights[i] * deviation * deviation
            square[j] += z[j] * z[j]
        _regressors(u, theta, i, row)
        for m in range(p):
            x = row[m]
            shift[m] += x
            for j in range(k):
                moment[m, j] += x * z[j]
    for j in range(k):
        spread[j] = math.sqrt(spread[j] / total)
    coef = symmetric_lstsq(gram, moment)
    # |z - X gamma|^2 = z^T z - 2 gamma^T X^T z + gamma^T (X^T X) gamma, without a pass over
    # the points; clamped at 0 against the rounding of the difference.
    squares = np.empty(k)
    for j in range(k):
        fitted = 0.0
        for m in range(p):
            projected = 0.0
            for q in range(p):
                projected += gram[m, q] * coef[q, j]
            fitted += coef[m, j] * (projected - 2.0 * moment[m, j])
        squares[j] = max(square[j] + fitted, 0.0)
    corrected = mean.copy()
    for m in range(1, p):
        difference = shift[m] / n - control_means[m]
        for j in range(k):
            corrected[j] -= difference * coef[m, j]
    return ess, corrected, squares, spread


@dataclass(frozen=True)
class _Options:
    target_se: float
    round_size: int
    max_samples: int
    min_ess: float
    inflation: float
    defensive: float
    wide_share: float
    wide_scale: float
    wide_below: float


@dataclass(frozen=True)
class _Result:
    theta_hat: FloatArray
    se: FloatArray
    ess: float
    samples: int
    converged: bool


class _Sampler:
    """The adaptive importance sampler of one trial (see the module docstring)."""

    def __init__(self, rng: np.random.Generator, k: int, options: _Options) -> None:
        self.rng = rng
        self.k = k
        self.options = options
        self.prior = _Gaussian(np.zeros(k), np.eye(k))
        self.u = np.empty((0, k))
        self.log_lik = np.empty(0)
        self.log_prior = np.empty(0)
        # Per component: its draws so far; component 0 is the prior. At every point, the log
        # of sum_c n_c q_c over the fitted components c >= 1 (the prior's share changes
        # every round, theirs is fixed when they are drawn from).
        self.components: list[_Gaussian] = [self.prior]
        self.counts: list[int] = [0]
        self.log_fitted = np.empty(0)
        self.beta = 0.0
        self.pending: tuple[FloatArray, FloatArray] | None = None  # next round's (u, theta)
        self.result: _Result | None = None
        self.finished = False
        self.round_quality = 1.0  # ESS fraction of the last round's own points
        self.log_mixture = np.empty(0)  # log Q at every point, refreshed by ingest
        # The regressors' Gram matrix X^T X, X_i = (1, u_i, theta_i), over every point.
        self.theta = np.empty((0, k))
        self.gram = np.zeros((1 + 2 * k, 1 + 2 * k))

    # -- the rounds --------------------------------------------------------------------------

    def propose(self) -> FloatArray:
        """Draw the next round's points and record the proposal; returns them in the box."""
        n_total = len(self.u)
        options = self.options
        if n_total == 0:
            draws = {0: min(options.round_size, options.max_samples)}
        else:
            fitted = self._fit()
            size = self._next_round_size()
            n_prior = int(round(options.defensive * size))
            # Heavy-tailed weights (few points carry the round): add the wide component.
            wide_share = options.wide_share if self.round_quality < options.wide_below else 0.0
            n_wide = int(round(wide_share * size))
            n_fitted = size - n_prior - n_wide
            draws = {0: n_prior, self._component_index(fitted, n_fitted): n_fitted}
            if n_wide > 0:
                wide = _Gaussian(fitted.mean, options.wide_scale * fitted.covariance)
                draws[self._component_index(wide, n_wide)] = n_wide
        new = np.concatenate(
            [self.components[c].draw(self.rng, n) for c, n in draws.items() if n > 0]
        )
        for c, n in draws.items():
            self.counts[c] += n
        self.pending = (new, theta_of(new))
        return self.pending[1]

    def _component_index(self, component: _Gaussian, draws: int) -> int:
        """Add a fitted component that ``draws`` points of the next round come from."""
        self.components.append(component)
        self.counts.append(0)
        self.log_fitted = _log_add_exp(self.log_fitted, math.log(draws) + component.log_pdf(self.u))
        return len(self.components) - 1

    def _next_round_size(self) -> int:
        options = self.options
        n_total = len(self.u)
        room = options.max_samples - n_total
        if self.beta < 1.0 or not np.isfinite(self.result.se).all():
            return min(options.round_size, room)
        # The standard error falls like 1 / sqrt(N): ask for what the target needs (+10%), in
        # whole rounds, at most doubling the points.
        worst = float(np.max(self.result.se))
        if options.target_se > 0:
            need = n_total * ((worst / options.target_se) ** 2 - 1.0) * 1.1
            size = options.round_size * int(np.ceil(max(need, 1.0) / options.round_size))
        else:
            size = n_total
        return int(min(size, max(n_total, options.round_size), room))

    def ingest(self, log_lik: FloatArray) -> None:
        """Add the scored round and re-estimate; :attr:`finished` says whether to stop."""
        assert self.pending is not None
        new, theta = self.pending
        self.pending = None
        fitted = [
            math.log(n) + component.log_pdf(new)
            for component, n in zip(self.components[1:], self.counts[1:], strict=True)
        ]
        log_fitted = _log_sum_exp(np.stack(fitted)) if fitted else np.full(len(new), -np.inf)
        self.u = np.concatenate([self.u, new])
        self.theta = np.concatenate([self.theta, theta])
        self.log_lik = np.concatenate([self.log_lik, log_lik])
        self.log_prior = np.concatenate([self.log_prior, self.prior.log_pdf(new)])
        self.log_fitted = np.concatenate([self.log_fitted, log_fitted])
        self.gram = self.gram + _gram(new, theta)
        self.log_mixture = self._log_mixture()
        self.result = self._estimate()
        self.round_quality = _ess(self._weights(1.0)[-len(new) :]) / len(new)
        self.finished = self.result.converged or len(self.u) >= self.options.max_samples

    # -- weights, tempering and fitting ------------------------------------------------------

    def _log_mixture(self) -> FloatArray:
        """:math:`\\log Q` at every point, :math:`Q = \\sum_c (n_c / N) q_c`."""
        prior = math.log(self.counts[0]) + self.log_prior
        return _log_add_exp(prior, self.log_fitted) - math.log(len(self.u))

    def _weights(self, beta: float) -> FloatArray:
        """Weights for the tempered target :math:`\\pi_\\beta`, up to a common factor."""
        return _weights(self.log_lik, self.log_prior - self.log_mixture, beta)

    def _fit(self) -> _Gaussian:
        """The next proposal: tempered weighted moments, covariance inflated."""
        options = self.options
        if _ess(self._weights(1.0)) >= options.min_ess:
            self.beta = 1.0
        else:
            log_base = self.log_prior - self.log_mixture
            self.beta = _temperature(self.log_lik, log_base, self.beta, options.min_ess)
        mean, covariance = _weighted_moments(self._weights(self.beta), self.u)
        covariance = options.inflation * covariance + 1e-6 * np.eye(self.k)
        return _Gaussian(mean, covariance)

    # -- the estimate ------------------------------------------------------------------------

    def _control_means(self) -> FloatArray:
        """Exact :math:`E_Q[h]` of the regressors under the mixture of proposals."""
        k = self.k
        shares = np.asarray(self.counts, dtype=np.float64) / len(self.u)
        u_mean, theta_mean = np.zeros(k), np.zeros(k)
        for share, component in zip(shares, self.components, strict=True):
            if share > 0:
                u_mean += share * component.mean
                theta_mean += share * component.theta_mean()
        return np.concatenate([np.ones(1), u_mean, theta_mean])

    def _estimate(self) -> _Result:
        """The control-variate estimate and its delta-method standard error."""
        options = self.options
        n_total = len(self.u)
        ess, corrected, squares, spread = _control_variate_fit(
            self._weights(1.0), self.u, self.theta, self.gram, self._control_means()
        )
        dof = max(n_total - len(self.gram), 1)
        se = np.sqrt(squares / dof / n_total)
        if ess < options.min_ess:
            # Too few effective points for the delta method (with one dominant weight it
            # reports zero): fall back to Kish's sd / sqrt(ESS), and do not converge.
            se = np.maximum(se, spread / math.sqrt(max(ess, 1.0)))
        theta_hat = np.clip(corrected, -1.0, 1.0)
        converged = bool(ess >= options.min_ess and np.max(se) <= options.target_se)
        return _Result(theta_hat, se, ess, n_total, converged)


def posterior_mean_estimate(
    model: MaxEnt,
    demos: IntArray,
    seeds: NDArray[np.int64],
    *,
    target_se: float = 0.01,
    round_size: int = 256,
    max_samples: int = 65536,
    min_ess: float = 100.0,
    inflation: float = 1.15,
    defensive: float = 0.05,
    wide_share: float = 0.2,
    wide_scale: float = 2.5,
    wide_below: float = 0.3,
    chunk: int = 8,
) -> Estimate:
    """Posterior mean :math:`E[\\theta \\mid \\tau_{demo}]` under the uniform prior on the box.

    Args:
        model: the MaxEnt model of the learning phase for the batch of ``B`` trials.
        demos: ``(B, T + 1)`` the demonstrations' cells.
        seeds: ``(B,)`` the trials' seeds; trial ``b`` draws from ``robot_generator(seeds[b])``.
        target_se: stop a trial once every coordinate's Monte-Carlo standard error is below it.
        round_size: points per adaptation round (later rounds are multiples of it).
        max_samples: cap on likelihood evaluations per trial.
        min_ess: effective sample size the tempering keeps, and that a converged trial needs.
        inflation: factor on the fitted covariance of each proposal.
        defensive: share of every later round drawn from the prior.
        wide_share: share of a round drawn from the fitted Gaussian with ``wide_scale``
            times its covariance, when the previous round's own ESS fraction was below
            ``wide_below`` (heavy-tailed weights: a polytope-like posterior).
        wide_scale: see ``wide_share``.
        wide_below: see ``wide_share``.
        chunk: trials sampled at a time (bounds memory; results do not depend on it).

    Returns:
        An :class:`cirl_study.core.estimate.Estimate`: ``theta_hat`` the estimate (clipped to the
        box), ``theta_hat_se`` its standard error per coordinate, ``effective_sample_size``
        Kish's ESS of the final weights, ``iterations`` the likelihood evaluations used,
        ``converged`` whether the target standard error was met, ``log_likelihood``
        :math:`L(\\hat\\theta)`.
    """
    demos = np.asarray(demos)
    expected = (model.batch, model.phase.horizon + 1)
    if demos.shape != expected:
        raise ValueError(f"demonstration paths must be {expected}, got {demos.shape}")
    demo_counts = np.ascontiguousarray(model.path_counts(demos), dtype=np.float64)
    seeds = np.asarray(seeds, dtype=np.int64)
    batch, k = demo_counts.shape
    if seeds.shape != (batch,):
        raise ValueError(f"need one seed per trial: {seeds.shape} seeds for {batch} trials")
    options = _Options(
        target_se=float(target_se),
        round_size=int(round_size),
        max_samples=int(max_samples),
        min_ess=float(min_ess),
        inflation=float(inflation),
        defensive=float(defensive),
        wide_share=float(wide_share),
        wide_scale=float(wide_scale),
        wide_below=float(wide_below),
    )
    theta_hat = np.empty((batch, k))
    se = np.empty((batch, k))
    ess = np.empty(batch)
    samples = np.empty(batch, dtype=np.int64)
    converged = np.empty(batch, dtype=bool)
    for begin in range(0, batch, chunk):
        rows = np.arange(begin, min(begin + chunk, batch))
        samplers = {int(b): _Sampler(robot_generator(int(seeds[b])), k, options) for b in rows}
        running = list(samplers)
        while running:
            by_size: dict[int, list[int]] = defaultdict(list)
            for b in running:
                by_size[len(samplers[b].propose())].append(b)
            for size, group in by_size.items():
                points = np.stack([samplers[b].pending[1] for b in group])
                log_lik = model.take(np.asarray(group)).log_likelihood_at(
                    points.reshape(len(group), size, k), demo_counts[group]
                )
                for row, b in enumerate(group):
                    samplers[b].ingest(log_lik[row])
            running = [b for b in running if not samplers[b].finished]
        for b, sampler in samplers.items():
            result = sampler.result
            theta_hat[b], se[b], ess[b] = result.theta_hat, result.se, result.ess
            samples[b], converged[b] = result.samples, result.converged
    # Fields in Estimate's order: iterations are the likelihood evaluations.
    log_likelihood = model.log_likelihood(theta_hat, demo_counts)
    return Estimate(theta_hat, log_likelihood, samples, converged, se, ess)
