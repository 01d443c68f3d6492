"""High-precision reference for the ``map`` robot's estimate (docs/design.md §2).

No code is shared with ``cirl_study``: the paths and their feature counts come from the
brute-force helpers of ``path_enumeration``; everything else is here, in ``mpmath``.

The maths
---------
A path ``tau`` of ``T`` moves from ``s_0`` has feature counts ``phi(tau) = sum_{t=1..T} phi(s_t)``.
The MaxEnt model is ``P(tau | theta, lambda) ∝ exp(lambda theta . phi(tau))``, so a
demonstration with counts ``phi_d`` has the log-likelihood

    L(theta) = lambda theta . phi_d - log sum_tau exp(lambda theta . phi(tau))
             = -log sum_j m_j exp(lambda theta . Delta_j),     Delta_j = c_j - phi_d,

where ``c_j`` are the *distinct* count vectors of the paths and ``m_j`` how many paths have
them. ``L`` is concave, with gradient ``lambda (phi_d - E[phi]) = -lambda E[Delta]`` and
Hessian ``-lambda^2 Cov[phi]`` (``E`` and ``Cov`` under the weights ``m_j exp(lambda theta .
Delta_j)``, normalised). The MAP under the uniform prior on ``[-1, 1]^K`` is the maximiser of
``L`` over the box; it is unique when ``L`` is strictly concave there (the differences
``Delta_j`` span ``R^K``), and :func:`reference_map` certifies that it has found it.

Paths whose counts equal the demonstration's (the same multiset of cells in another order, say)
have ``Delta = 0``: they weigh ``exp(0)`` at every ``theta``. Writing ``S(theta) = sum over
the other groups of m_j exp(lambda theta . Delta_j)`` and ``m_0`` for the demonstration's own
group, ``L = -log(m_0 + S)``: the MAP minimises ``S``, that is the soft maximum
``(1 / lambda) log S = max_j theta . Delta_j + O(log P / lambda)``. So as ``lambda -> inf``
the MAP tends to the solutions of the max-margin linear programme

    v* = min over theta in the box of max over j with Delta_j != 0 of theta . Delta_j,

and, exactly, ``0 <= max_j theta_hat . Delta_j - v* <= log(P - m_0) / lambda`` for every
``lambda`` (:func:`max_margin_limit` solves the LP with ``scipy.optimize.linprog``).

Why mpmath
----------
At ``lambda`` of 100 and more the weights span thousands of orders of magnitude: at
``lambda = 1e4`` a path ``0.1`` worse than the best weighs ``exp(-1000)`` relative to it,
below the smallest double (``exp(-745)``). In double precision the gradient and Hessian then
underflow to exactly zero long before the estimate is pinned down, and the MAP cannot be
located, let alone converged. ``mpmath`` numbers carry an unbounded exponent, so
``exp(-1e4)`` is an ordinary number; with ``dps`` (default 60) significant digits every
weight, gradient and Hessian entry keeps its relative accuracy. The evaluation is written
so that it does: all weights are taken relative to a reference group (the heaviest at the
current iterate), the mean and covariance are sums of differences from that group, and the
log-partition is ``lambda theta . Delta_r + log m_r + log1p(sum of the others)``, so that a
change of ``exp(-1000)`` in ``L`` is still seen by the line search.

The optimiser
-------------
Since ``L = -log(m_0 + S)`` is decreasing in ``S``, the reference minimises the log-sum-exp
``G = log S`` over the box (``G = -L`` when no path has the demonstration's counts): at large
``lambda`` it is nearly piecewise linear, where Newton's method moves quickly, whereas on
``-L ~ S / m_0`` (the demonstration dominating) a Newton step would advance only ``1/lambda``.
Each step is a projected Newton step: the quadratic model of ``G`` is minimised exactly over
the box (every face of the box is tried, ``3^K`` of them, so ``K`` should stay small), which
picks the active bounds at once, followed by an Armijo backtracking search on ``G`` along the
step (and, after a full step, a doubling search along the projected ray). Where values of
``G`` cannot resolve the decrease (a change of ``1e-700`` on top of ``O(1)``), a search on
slopes, which keep their relative accuracy, takes over. Started at ``theta = 0``.

It stops only on a certificate (:class:`Certificate`), checked on ``L`` itself at the end:
on the coordinates not held at a bound by an outward gradient, the free block of the Hessian
is positive definite beyond what the working precision can resolve, the Newton step there has
max-norm ``<= tol``, and every coordinate at a bound keeps an outward-pushing gradient after
that step (so the answer is within about ``tol`` of the maximiser, coordinate by coordinate).
Otherwise it raises :class:`MapNotDetermined`: a singular free Hessian means the MAP is not
determined (or not at this precision) and the reference says so rather than guess.

Inputs, and what double precision can ask of the answer
-------------------------------------------------------
Counts are taken as given in double precision (they are inputs): each multiset of visited
cells gets one exactly rounded count vector, and count vectors equal to ``1e-12`` (relative)
are merged, so that reorderings of the demonstration's cells get ``Delta = 0`` exactly.
Some instances have a unique, converged MAP that double-precision inputs nevertheless do not
pin down: when the LP limit is not unique, ``L`` can be flat to ``1e-18`` along a direction
at ``lambda = 1e4``, and two ulps in the counts move the MAP by ``1e-3``.
``Certificate.input_sensitivity`` estimates that motion; the cases of
:func:`reference_cases` all have it below ``1e-9``.

API
---
:func:`reference_map` (the MAP as float64), :func:`reference_map_details` (also the mpmath
answer, ``L`` there and the certificate), :func:`max_margin_limit` (the ``lambda -> inf``
LP), :func:`log_likelihood_mp`, :func:`count_groups`, and :func:`reference_cases` /
:func:`reference_theta` (small games with their reference MAP, computed lazily and cached).
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import mpmath
import numpy as np
import path_enumeration as bf
from scipy.optimize import linprog

__all__ = [
    "Certificate",
    "CountGroups",
    "MapNotDetermined",
    "MaxMarginLimit",
    "ReferenceResult",
    "count_groups",
    "log_likelihood_mp",
    "max_margin_limit",
    "reference_case_details",
    "reference_cases",
    "reference_map",
    "reference_map_details",
    "reference_theta",
]

# Counts are sums of at most a few doubles in [0, 1]: two count vectors this close (relative
# to the largest count) are the same vector up to rounding.
COUNT_RTOL = 1e-12
# Each Newton step tries the 3^K faces of the box.
MAX_FEATURES = 8


class MapNotDetermined(ArithmeticError):
    """The MAP could not be converged: not unique, or not resolvable at this precision."""


# --------------------------------------------------------------------------------------------
# The distinct count vectors
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class CountGroups:
    """The paths' distinct feature-count vectors, their multiplicities and the demo's group.

    ``counts`` (G, K) and ``multiplicity`` (G,) list every distinct count vector once;
    ``demo`` is the index of the group whose counts equal ``demo_counts`` (to
    :data:`COUNT_RTOL`), or ``None`` when no path has the demonstration's counts.
    """

    counts: np.ndarray
    multiplicity: np.ndarray
    demo: int | None
    demo_counts: np.ndarray
    num_paths: int


def count_groups(
    features: np.ndarray,
    width: int,
    height: int,
    start: int,
    horizon: int,
    demo_counts: Sequence[float],
) -> CountGroups:
    """Enumerate every path once and group them by feature-count vector.

    Paths visiting the same multiset of cells have the same counts; each multiset's counts are
    an exactly rounded sum over its sorted cells, so they agree bit for bit. Distinct multisets
    whose counts agree to :data:`COUNT_RTOL` (symmetric features) are merged as well.
    """
    features = np.asarray(features, dtype=float)
    demo_counts = np.asarray(demo_counts, dtype=float).reshape(-1)
    if features.shape != (width * height, demo_counts.size):
        raise ValueError(
            f"features {features.shape} do not fit a {width}x{height} grid, K={demo_counts.size}"
        )
    paths = np.asarray(bf.enumerate_paths_array(width, height, start, horizon))
    cells = np.sort(paths[:, 1:], axis=1)
    multisets, per_multiset = np.unique(cells, axis=0, return_counts=True)
    k = features.shape[1]
    counts = np.array([[math.fsum(features[ms, i]) for i in range(k)] for ms in multisets]).reshape(
        len(multisets), k
    )
    atol = COUNT_RTOL * max(1.0, float(np.abs(counts).max(initial=0.0)))
    order = np.lexsort(counts.T[::-1])
    label = np.full(len(counts), -1)
    reps: list[int] = []
    for i in order:
        if label[i] >= 0:
            continue
        close = (np.abs(counts - counts[i]).max(axis=1) <= atol) & (label < 0)
        label[close] = len(reps)
        reps.append(int(i))
    group_counts = counts[reps]
    multiplicity = np.bincount(label, weights=per_multiset, minlength=len(reps)).astype(np.int64)
    gap = np.abs(group_counts - demo_counts).max(axis=1)
    demo = int(np.argmin(gap)) if gap.min() <= atol else None
    return CountGroups(group_counts, multiplicity, demo, demo_counts, int(len(paths)))


# --------------------------------------------------------------------------------------------
# The log-likelihood, its gradient and Hessian in mpmath
# --------------------------------------------------------------------------------------------


class _LogSumExp:
    """``F(theta) = log sum_{j in J} m_j exp(lambda theta . Delta_j)`` at the context's dps.

    ``J`` is a list of count groups (``deltas``, ``logm``). Every quantity is taken relative to
    a reference group ``r``: with ``a_j = lambda theta . (Delta_j - Delta_r) + log(m_j / m_r)``
    and ``S = sum_{j != r} e^{a_j}``, ``F = lambda theta . Delta_r + log m_r + log1p(S)``. The
    weights ``e^{a_j}`` keep their relative accuracy whatever their size, and differences of
    ``F`` at two points are taken with one ``r``, so that the constant parts cancel exactly.
    """

    def __init__(self, deltas: list[list[mpmath.mpf]], logm: list[mpmath.mpf], lam: mpmath.mpf):
        mp = mpmath.mp
        self.delta = deltas
        self.logm = logm
        self.lam = lam
        self.g = len(deltas)
        self.k = len(deltas[0])
        self._rel: dict[int, list[list[mpmath.mpf]]] = {}
        dmax = max(abs(v) for row in deltas for v in row)
        # Relative accuracy of a weight e^{a_j} (|a_j| <= 2 lambda K dmax + log P) and so of
        # every sum of weighted terms: a few units in the last place of the exponent's size.
        self.eps = mp.mpf(10) ** (2 - mp.dps) * (10 + 2 * lam * self.k * dmax + max(logm))
        # A few ulps of a double feature count (for Certificate.input_sensitivity).
        self.input_unit = mp.mpf(2) ** -50 * (1 + dmax)

    def relative(self, r: int) -> list[list[mpmath.mpf]]:
        """``Delta_j - Delta_r`` for every ``j`` (exact: differences of doubles)."""
        if r not in self._rel:
            dr = self.delta[r]
            self._rel[r] = [[a - b for a, b in zip(d, dr, strict=True)] for d in self.delta]
        return self._rel[r]

    def heaviest(self, theta) -> int:
        """Index of the group of largest weight ``m_j exp(lambda theta . Delta_j)``."""
        mp = mpmath.mp
        s = [mp.fdot(theta, d) * self.lam + lm for d, lm in zip(self.delta, self.logm, strict=True)]
        return max(range(self.g), key=s.__getitem__)

    def _weights(self, theta, r: int, prune: bool = False) -> list[mpmath.mpf]:
        """``e^{a_j}`` for ``j != r`` and ``0`` for ``r``.

        With ``prune``, weights below ``10^(-1.5 dps - 20)`` times the largest are left at ``0``
        (they cannot change a sum of them at the working precision): for values only.
        """
        mp = mpmath.mp
        rel = self.relative(r)
        lr = self.logm[r]
        expo = [
            self.lam * mp.fdot(theta, rel[j]) + self.logm[j] - lr if j != r else None
            for j in range(self.g)
        ]
        cut = None
        if prune and self.g > 1:
            cut = max(a for a in expo if a is not None) - (mp.dps * 3.5 + 46)
        return [mp.zero if a is None or (cut is not None and a < cut) else mp.exp(a) for a in expo]

    def log1p_rest(self, theta, r: int) -> mpmath.mpf:
        """``log1p(S)``: ``F(theta) - lambda theta . Delta_r - log m_r``."""
        mp = mpmath.mp
        return mp.log1p(mp.fsum(self._weights(theta, r, prune=True)))

    def value(self, theta) -> mpmath.mpf:
        """``F(theta)``."""
        mp = mpmath.mp
        r = self.heaviest(theta)
        return self.lam * mp.fdot(theta, self.delta[r]) + self.logm[r] + self.log1p_rest(theta, r)

    def difference(self, new, old, r: int, old_rest: mpmath.mpf | None = None) -> mpmath.mpf:
        """``F(new) - F(old)`` with the reference group ``r``, to the working precision.

        ``old_rest`` is ``log1p_rest(old, r)`` if already known.
        """
        mp = mpmath.mp
        if old_rest is None:
            old_rest = self.log1p_rest(old, r)
        step = [a - b for a, b in zip(new, old, strict=True)]
        return self.lam * mp.fdot(step, self.delta[r]) + (self.log1p_rest(new, r) - old_rest)

    def gradient(self, theta) -> list[mpmath.mpf]:
        """``grad F = lambda E[Delta]`` at ``theta`` (relative to the heaviest group)."""
        mp = mpmath.mp
        r = self.heaviest(theta)
        rel = self.relative(r)
        e = self._weights(theta, r)
        norm = 1 + mp.fsum(e)
        return [
            self.lam * (self.delta[r][i] + mp.fsum(e[j] * rel[j][i] for j in range(self.g)) / norm)
            for i in range(self.k)
        ]

    def derivatives(self, theta, r: int):
        """``(grad F, Hess F, spread)`` at ``theta``.

        ``grad F = lambda E[Delta]``, ``Hess F = lambda^2 Cov[Delta]``, both under the weights
        normalised over ``J``, and both as sums of differences from ``Delta_r``. ``spread_i``
        is the sum of the absolute values of the terms of ``grad_i``: a relative error ``u``
        in the terms moves ``grad_i`` by at most ``u spread_i``.
        """
        mp = mpmath.mp
        rel = self.relative(r)
        e = self._weights(theta, r)
        norm = 1 + mp.fsum(e)
        w = [x / norm for x in e]
        w[r] = 1 / norm
        k, g = self.k, self.g
        others = [j for j in range(g) if j != r]
        mean = [mp.fsum(w[j] * rel[j][i] for j in others) for i in range(k)]
        grad = [self.lam * (self.delta[r][i] + mean[i]) for i in range(k)]
        spread = [
            self.lam * (abs(self.delta[r][i]) + mp.fsum(w[j] * abs(rel[j][i]) for j in others))
            for i in range(k)
        ]
        centered = [[x - m for x, m in zip(row, mean, strict=True)] for row in rel]
        hess = mp.matrix(k, k)
        for a in range(k):
            for b in range(a, k):
                c = mp.fsum(w[j] * centered[j][a] * centered[j][b] for j in range(g))
                hess[a, b] = hess[b, a] = self.lam**2 * c
        return grad, hess, spread


def _objectives(groups: CountGroups, rationality: float) -> tuple[_LogSumExp, _LogSumExp]:
    """``(-L, G)`` as log-sum-exps: ``-L`` over every group; ``G`` without the demo's group.

    ``-L = log(m_0 + e^G)`` is increasing in ``G``, so both have the same minimiser over the box;
    ``G`` is the one to minimise: a log-sum-exp of affine functions, nearly piecewise linear at
    large ``lambda``, where Newton's method is quick (on ``e^G`` it would advance ``1/lambda`` a
    step). Without a demo group (counts no path has) the two are the same function.
    """
    mp = mpmath.mp
    lam = mp.mpf(float(rationality))
    demo = [mp.mpf(float(v)) for v in groups.demo_counts]
    deltas, logm = [], []
    for j, row in enumerate(groups.counts):
        if j == groups.demo:
            deltas.append([mp.zero] * len(demo))  # the demo's own counts, exactly
        else:
            deltas.append([mp.mpf(float(v)) - d for v, d in zip(row, demo, strict=True)])
        logm.append(mp.log(int(groups.multiplicity[j])))
    full = _LogSumExp(deltas, logm, lam)
    if groups.demo is None:
        return full, full
    keep = [j for j in range(len(deltas)) if j != groups.demo]
    if not keep:
        raise MapNotDetermined("every path has the demonstration's counts: L is constant")
    return full, _LogSumExp([deltas[j] for j in keep], [logm[j] for j in keep], lam)


def log_likelihood_mp(
    features: np.ndarray,
    width: int,
    height: int,
    start: int,
    horizon: int,
    demo_counts: Sequence[float],
    rationality: float,
    theta: Sequence[float],
    *,
    dps: int = 60,
) -> mpmath.mpf:
    """``L(theta)`` in mpmath, at ``dps`` digits."""
    groups = count_groups(features, width, height, start, horizon, demo_counts)
    with mpmath.workdps(dps):
        full, _ = _objectives(groups, rationality)
        return -full.value([mpmath.mpf(float(v)) for v in theta])


# --------------------------------------------------------------------------------------------
# The projected Newton method and its certificate
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Certificate:
    """What the reference checked at its answer (in mpmath at the working precision).

    ``bound``: coordinates at ``-1`` or ``+1`` whose gradient of ``L`` pushes outward, both at
    the answer and after the free Newton step (``multipliers``: that outward slope in count
    units ``|dL/dtheta_k| / lambda``, each above its rounding noise). ``free``: the others;
    ``newton_step`` is the max-norm of the Newton step of ``L`` on them, ``min_eigenvalue``
    the smallest eigenvalue of the free block of ``-Hess L``, ``resolution`` the smallest
    eigenvalue for which the gradient's rounding noise moves the step by less than ``tol/100``.

    ``input_sensitivity`` is not part of the certificate but a warning about the *problem*:
    an estimate of how far the MAP moves when the feature counts are perturbed by a few
    units in the last place of a double (``inf`` if that may flip a bound coordinate). A
    double-precision robot cannot be expected to match the MAP more closely than this.
    """

    ok: bool
    resolvable: bool
    bound: tuple[int, ...]
    free: tuple[int, ...]
    newton_step: mpmath.mpf
    min_eigenvalue: mpmath.mpf | None
    resolution: mpmath.mpf
    multipliers: tuple[mpmath.mpf, ...]
    free_gradient: mpmath.mpf
    stationary: bool
    input_sensitivity: float


def _submatrix(hess, idx):
    mp = mpmath.mp
    sub = mp.matrix(len(idx), len(idx))
    for a, i in enumerate(idx):
        for b, j in enumerate(idx):
            sub[a, b] = hess[i, j]
    return sub


def _solve_spd(sub, rhs):
    """Solve ``sub x = rhs`` by Cholesky; ``None`` if not numerically positive definite.

    The matrix is first scaled to unit diagonal (mpmath's Cholesky tests pivots against an
    absolute epsilon, and a Hessian here may be ``1e-400`` as a whole).
    """
    mp = mpmath.mp
    n = sub.rows
    diag = [sub[a, a] for a in range(n)]
    if any(d <= 0 for d in diag):
        return None
    scale = [1 / mp.sqrt(d) for d in diag]
    unit = mp.matrix(n, n)
    for a in range(n):
        for b in range(n):
            unit[a, b] = sub[a, b] * scale[a] * scale[b]
    try:
        sol = mp.cholesky_solve(unit, mp.matrix([rhs[a] * scale[a] for a in range(n)]))
    except (ValueError, ZeroDivisionError):
        return None
    return [sol[a] * scale[a] for a in range(n)]


def _certify(obj: _LogSumExp, theta, grad, hess, spread, tol) -> Certificate:
    """The stopping certificate of ``min F`` over the box at ``theta`` (:class:`Certificate`)."""
    mp = mpmath.mp
    k = obj.k
    noise = [obj.eps * s for s in spread]
    # F = -L: at +1 an outward-pushing dL > 0 is dF < 0; at -1 it is dF > 0.
    bound = tuple(
        i for i in range(k) if (theta[i] >= 1 and grad[i] < 0) or (theta[i] <= -1 and grad[i] > 0)
    )
    free = tuple(i for i in range(k) if i not in bound)
    resolution = 100 * mp.sqrt(mp.fsum((noise[i] for i in free), squared=True)) / tol
    free_gradient = max((abs(grad[i]) for i in free), default=mp.zero)
    stationary = all(abs(grad[i]) <= 1000 * noise[i] for i in free)
    step: list = []
    min_eig = None
    resolvable = True
    if free:
        sub = _submatrix(hess, free)
        # Eigenvalues of sub / s, times s: the block may be 1e-400 as a whole.
        size = max(abs(sub[a, b]) for a in range(len(free)) for b in range(len(free)))
        size = size if size > 0 else mp.one
        eig = mp.eigsy(sub / size, eigvals_only=True)
        min_eig = min(eig[a] for a in range(len(free))) * size
        max_eig = max(eig[a] for a in range(len(free))) * size
        resolvable = min_eig > resolution and min_eig > max_eig * mp.mpf(10) ** (10 - mp.dps)
        if resolvable:
            step = _solve_spd(sub, [-grad[i] for i in free]) or []
            resolvable = bool(step)
    newton = max((abs(s) for s in step), default=mp.zero)
    multipliers = []
    for i in bound:
        after = grad[i] + mp.fsum(hess[i, j] * s for j, s in zip(free, step, strict=False))
        multipliers.append((-after if theta[i] >= 1 else after) / obj.lam)
    ok = (
        resolvable
        and newton <= tol
        and all(m * obj.lam > noise[i] for i, m in zip(bound, multipliers, strict=True))
    )
    # How far a few double-precision ulps in the counts move the answer.
    shift = [obj.input_unit * s for s in spread]
    if any(m * obj.lam <= shift[i] for i, m in zip(bound, multipliers, strict=True)):
        sensitivity = math.inf
    elif not free:
        sensitivity = 0.0
    elif min_eig is None or min_eig <= 0:
        sensitivity = math.inf
    else:
        sensitivity = float(mp.sqrt(mp.fsum((shift[i] for i in free), squared=True)) / min_eig)
    return Certificate(
        ok,
        resolvable,
        bound,
        free,
        newton,
        min_eig,
        resolution,
        tuple(multipliers),
        free_gradient / obj.lam,
        stationary,
        sensitivity,
    )


@dataclass(frozen=True)
class ReferenceResult:
    """The reference MAP (float64 and mpmath), ``L`` there and its certificate.

    ``certificate`` is that of ``L`` itself; ``iterations`` counts the Newton steps.
    """

    theta: np.ndarray
    theta_mp: tuple[mpmath.mpf, ...]
    log_likelihood: mpmath.mpf
    certificate: Certificate
    iterations: int
    dps: int
    num_groups: int


def _clip(v):
    return max(-1, min(1, v))


def _fmt(theta) -> str:
    return "[" + ", ".join(mpmath.nstr(t, 17) for t in theta) + "]"


def _not_determined(what: str, theta, cert: Certificate) -> MapNotDetermined:
    mp = mpmath.mp
    eig = "-" if cert.min_eigenvalue is None else mp.nstr(cert.min_eigenvalue, 5)
    return MapNotDetermined(
        f"{what} at theta={_fmt(theta)} ({mp.dps} digits): free coordinates {cert.free}, "
        f"free Hessian min eigenvalue {eig} (resolution {mp.nstr(cert.resolution, 5)}), "
        f"free slope {mp.nstr(cert.free_gradient, 5)}: the MAP is not determined at this "
        "precision (a larger dps may settle it, unless the MAP is not unique)"
    )


def _box_newton_step(theta, grad, hess):
    """The exact minimiser ``d`` of the model ``g . d + d' H d / 2`` over ``theta + d`` in the box.

    Every face of the box is tried (each coordinate at ``-1``, free or at ``+1``: ``3^K``
    faces); on a face the model's stationary point solves ``H_FF d_F = -(g_F + H_FB d_B)``.
    The feasible candidate of least model value is the minimiser (the model is convex; a face
    whose block ``H_FF`` is numerically singular is skipped, its minima being reached on a
    smaller face). Also returns the face's bound coordinates.
    """
    mp = mpmath.mp
    k = len(theta)
    best = None
    for face in itertools.product((-1, 0, 1), repeat=k):
        d = [mp.zero] * k
        bound = [i for i in range(k) if face[i]]
        for i in bound:
            d[i] = face[i] - theta[i]
        free = [i for i in range(k) if not face[i]]
        if free:
            rhs = [-(grad[i] + mp.fsum(hess[i, j] * d[j] for j in bound)) for i in free]
            sol = _solve_spd(_submatrix(hess, free), rhs)
            if sol is None:
                continue
            if any(abs(theta[i] + s) > 1 for i, s in zip(free, sol, strict=True)):
                continue
            for i, s in zip(free, sol, strict=True):
                d[i] = s
        hd = [mp.fsum(hess[i, j] * d[j] for j in range(k)) for i in range(k)]
        model = mp.fdot(grad, d) + mp.fdot(d, hd) / 2
        if best is None or model < best[0]:
            best = (model, d, face)
    return best[1], best[2]


def _armijo(obj: _LogSumExp, theta, r: int, direction, face, slope):
    """Backtrack (Armijo) on values of ``F`` along ``theta + alpha d``; expand if ``alpha = 1``.

    ``face`` (or ``None``) marks the coordinates that ``theta + d`` puts on a bound. Far from
    the answer a few groups may dominate and ``F`` is nearly a sum of exponentials, on which a
    Newton step advances only ``~1/lambda``: after a full step the search goes on along the
    projected ray while ``F`` keeps decreasing. Returns the new point or ``None``.
    """
    mp = mpmath.mp
    sigma = mp.mpf("1e-4")
    rest = obj.log1p_rest(theta, r)
    alpha = mp.one
    for _ in range(mp.prec):
        trial = [_clip(t + alpha * d) for t, d in zip(theta, direction, strict=True)]
        if alpha == 1 and face is not None:  # land exactly on the face's bounds
            trial = [mp.mpf(f) if f else t for t, f in zip(trial, face, strict=True)]
        if trial == theta:
            return None
        value = obj.difference(trial, theta, r, rest)
        if value <= sigma * alpha * slope:
            break
        alpha /= 2
    else:
        return None
    if alpha == 1:
        for _ in range(60):
            alpha *= 2
            further = [_clip(t + alpha * d) for t, d in zip(theta, direction, strict=True)]
            if further == trial:
                break
            further_value = obj.difference(further, theta, r, rest)
            if not further_value < value:
                break
            trial, value = further, further_value
    return trial


def _slope_search(obj: _LogSumExp, theta, direction, slope):
    """A line search on slopes only, for when values of ``F`` cannot see the decrease.

    Along the feasible ray ``theta + alpha d`` (up to the box's boundary, ``alpha_max >= 1``)
    ``F`` is convex, so its slope ``phi'(alpha) = grad F . d`` increases. First ``alpha0``
    with ``phi'(alpha0) <= 0.1 phi'(0)``: ``1`` if that holds there, else by bisection on
    ``[0, 1]`` into ``0.9 phi'(0) <= phi'(alpha0) <= 0.1 phi'(0)``; this drops ``F`` by at least
    ``0.1 alpha0 |phi'(0)|``, as ``F(alpha0) - F(0) <= alpha0 phi'(alpha0)``. Then ``alpha``
    doubles (up to ``alpha_max``) while ``phi'(alpha) <= 0``: ``F`` only decreases further.
    Slopes keep their relative accuracy when values (``O(1)`` plus a change of ``1e-700``) do
    not; and doubling matters where ``F`` is nearly a sum of exponentials, on which a Newton
    step advances only ``~1/lambda``.
    """
    mp = mpmath.mp

    def phi(alpha):
        point = [_clip(t + alpha * d) for t, d in zip(theta, direction, strict=True)]
        return point, mp.fdot(obj.gradient(point), direction)

    alpha = mp.one
    point, s = phi(alpha)
    if s > slope / 10:
        lo, hi = mp.zero, mp.one
        for _ in range(mp.prec):
            alpha = (lo + hi) / 2
            point, s = phi(alpha)
            if s > slope / 10:
                hi = alpha
            elif s < slope * mp.mpf("0.9"):
                lo = alpha
            else:
                break
        else:
            return None
        if point == theta:
            return None
    alpha_max = min(
        ((1 if d > 0 else -1) - t) / d for t, d in zip(theta, direction, strict=True) if d
    )
    while alpha < alpha_max:
        further = min(2 * alpha, alpha_max)
        p, s = phi(further)
        if s > 0:
            break
        alpha, point = further, p
    return point


def _projected_newton(obj: _LogSumExp, tol, max_iter: int):
    """Minimise ``obj`` over the box from ``theta = 0``; return the converged point.

    Each step minimises the quadratic model exactly over the box (:func:`_box_newton_step`),
    which finds the optimal face at once, then backtracks (Armijo) along that step, which
    stays in the box. Near the answer the steps are Newton steps on the optimal face. Should
    the model's step not descend (rounding, a singular model), a scaled projected-gradient
    step is tried; should values not see the decrease, a search on slopes.
    """
    mp = mpmath.mp
    k = obj.k
    theta = [mp.zero] * k
    for it in range(max_iter):
        r = obj.heaviest(theta)
        grad, hess, spread = obj.derivatives(theta, r)
        cert = _certify(obj, theta, grad, hess, spread, tol)
        if cert.ok:
            return theta, it
        if not cert.resolvable and cert.stationary:
            raise _not_determined("stationary", theta, cert)
        newton, face = _box_newton_step(theta, grad, hess)
        gmax = max(abs(g) for g in grad)
        steepest = [_clip(t - 2 * g / gmax) - t for t, g in zip(theta, grad, strict=True)]
        accepted = None
        for direction, on_face in ((newton, face), (steepest, None)):
            slope = mp.fdot(grad, direction)
            if not slope < 0:
                continue
            accepted = _armijo(obj, theta, r, direction, on_face, slope)
            if accepted is None:
                accepted = _slope_search(obj, theta, direction, slope)
            if accepted is not None:
                break
        if accepted is None:
            raise _not_determined("no descent", theta, cert)
        theta = accepted
    raise MapNotDetermined(f"not converged after {max_iter} Newton steps, at {_fmt(theta)}")


def reference_map_details(
    features: np.ndarray,
    width: int,
    height: int,
    start: int,
    horizon: int,
    demo_counts: Sequence[float],
    rationality: float,
    *,
    dps: int = 60,
    tol: float = 1e-12,
    max_iter: int = 200,
) -> ReferenceResult:
    """:func:`reference_map` with the mpmath answer, ``L`` there and the certificate."""
    if not rationality > 0:
        raise ValueError("rationality must be positive")
    if not 1 <= len(demo_counts) <= MAX_FEATURES:
        raise ValueError(f"the reference tries all 3^K faces of the box: K <= {MAX_FEATURES}")
    groups = count_groups(features, width, height, start, horizon, demo_counts)
    with mpmath.workdps(dps):
        full, opt = _objectives(groups, rationality)
        tol_mp = mpmath.mpf(tol)
        theta, iterations = _projected_newton(opt, tol_mp / 10, max_iter)
        # The certificate of L itself (same minimiser as G; checked on L as promised).
        r = full.heaviest(theta)
        grad, hess, spread = full.derivatives(theta, r)
        cert = _certify(full, theta, grad, hess, spread, tol_mp)
        if not cert.ok:
            raise _not_determined("not converged on L", theta, cert)
        log_lik = -full.value(theta)
    return ReferenceResult(
        theta=np.array([float(t) for t in theta]),
        theta_mp=tuple(theta),
        log_likelihood=log_lik,
        certificate=cert,
        iterations=iterations,
        dps=dps,
        num_groups=full.g,
    )


def reference_map(
    features: np.ndarray,
    width: int,
    height: int,
    start: int,
    horizon: int,
    demo_counts: Sequence[float],
    rationality: float,
    *,
    dps: int = 60,
    tol: float = 1e-12,
) -> np.ndarray:
    """The converged MAP ``argmax_{theta in [-1, 1]^K} L(theta)`` as a float64 ``(K,)`` array.

    Accurate to about ``tol`` in every coordinate (plus the final rounding to double). Raises
    :class:`MapNotDetermined` when the maximiser cannot be converged to be unique at ``dps``
    digits.
    """
    return reference_map_details(
        features, width, height, start, horizon, demo_counts, rationality, dps=dps, tol=tol
    ).theta


# --------------------------------------------------------------------------------------------
# The lambda -> infinity limit: the max-margin LP
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MaxMarginLimit:
    """``v* = min_{theta in box} max_{j: Delta_j != 0} theta . Delta_j`` and a minimiser.

    ``theta_range`` (K, 2) is the smallest and largest value of each coordinate over the LP's
    optimal set (within ``1e-9`` of ``v*``); ``unique`` when every range is shorter than 1e-6.
    ``deltas`` (J, K) are the count differences in the max, ``num_excluded`` the paths with the
    demonstration's counts.
    """

    value: float
    theta: np.ndarray
    unique: bool
    theta_range: np.ndarray
    deltas: np.ndarray
    num_excluded: int


_HIGHS = {"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10}


def max_margin_limit(
    features: np.ndarray,
    width: int,
    height: int,
    start: int,
    horizon: int,
    demo_counts: Sequence[float],
) -> MaxMarginLimit:
    """Solve the max-margin LP that the MAP tends to as ``lambda -> inf`` (variables theta, t)."""
    groups = count_groups(features, width, height, start, horizon, demo_counts)
    keep = np.arange(len(groups.counts)) != (-1 if groups.demo is None else groups.demo)
    deltas = groups.counts[keep] - groups.demo_counts
    k = deltas.shape[1]
    a_ub = np.hstack([deltas, -np.ones((len(deltas), 1))])
    b_ub = np.zeros(len(deltas))
    bounds = [(-1.0, 1.0)] * k + [(None, None)]
    cost = np.zeros(k + 1)
    cost[-1] = 1.0
    res = linprog(cost, A_ub=a_ub, b_ub=b_ub, bounds=bounds, method="highs", options=_HIGHS)
    if res.status != 0:
        raise RuntimeError(f"max-margin LP failed: {res.message}")
    value = float(res.x[-1])
    # The optimal set: the box points with max_j theta . Delta_j <= v* + slack.
    slack = 1e-9 * max(1.0, abs(value))
    a_opt = np.vstack([a_ub, np.eye(1, k + 1, k)])
    b_opt = np.append(b_ub, value + slack)
    ranges = np.zeros((k, 2))
    for i in range(k):
        for side, sign in enumerate((1.0, -1.0)):
            c = np.zeros(k + 1)
            c[i] = sign
            sub = linprog(c, A_ub=a_opt, b_ub=b_opt, bounds=bounds, method="highs", options=_HIGHS)
            if sub.status != 0:
                raise RuntimeError(f"max-margin range LP failed: {sub.message}")
            ranges[i, side] = sub.x[i]
    unique = bool(np.all(ranges[:, 1] - ranges[:, 0] <= 1e-6))
    excluded = 0 if groups.demo is None else int(groups.multiplicity[groups.demo])
    return MaxMarginLimit(value, res.x[:k].copy(), unique, ranges, deltas, excluded)


# --------------------------------------------------------------------------------------------
# Reference cases for the fast robot's tests
# --------------------------------------------------------------------------------------------


class _Case(dict):
    """A plain dict whose ``"theta_hat"`` is the reference MAP, computed on first ``[]`` use."""

    def __missing__(self, key):
        if key == "theta_hat":
            return reference_theta(self["name"])
        raise KeyError(key)


# name: (width, height, start, horizon, num_features, seed, demo kind, rationality)
_CASES: dict[str, tuple[int, int, int, int, int, int, str, float]] = {
    "4x4-T4-K2-expert-1e4": (4, 4, 5, 4, 2, 11, "expert", 1e4),
    "4x4-T4-K3-expert-1e4": (4, 4, 6, 4, 3, 22, "expert", 1e4),
    "3x4-T5-K4-expert-1e4": (3, 4, 7, 5, 4, 21, "expert", 1e4),
    "4x4-T4-K3-random-1e4": (4, 4, 5, 4, 3, 20, "random", 1e4),
    "4x4-T4-K3-expert-1e3": (4, 4, 6, 4, 3, 13, "expert", 1e3),
    "3x4-T5-K2-random-1e3": (3, 4, 4, 5, 2, 14, "random", 1e3),
    "4x4-T4-K4-expert-1e2": (4, 4, 5, 4, 4, 15, "expert", 1e2),
    "4x4-T5-K3-random-1e2": (4, 4, 9, 5, 3, 16, "random", 1e2),
    "3x4-T4-K4-random-1e0": (3, 4, 4, 4, 4, 17, "random", 1.0),
    "4x4-T4-K2-expert-1e-2": (4, 4, 10, 4, 2, 18, "expert", 1e-2),
}


def _build_case(name: str) -> _Case:
    width, height, start, horizon, k, seed, kind, rationality = _CASES[name]
    rng = np.random.default_rng(seed)
    centers = rng.uniform([0, 0], [width - 1, height - 1], size=(k, 2))
    sigma = float(rng.uniform(0.8, 2.0))
    features = bf.rbf_features(width, height, centers, sigma)
    paths = np.asarray(bf.enumerate_paths_array(width, height, start, horizon))
    counts = bf.feature_counts(paths, features)
    theta = rng.uniform(-1, 1, size=k)
    expert = bf.expert_fast(counts, theta)[0]
    index = expert if kind == "expert" else int(rng.integers(len(paths)))
    for arr in (features, centers):
        arr.setflags(write=False)
    return _Case(
        name=name,
        width=width,
        height=height,
        start=start,
        horizon=horizon,
        centers=centers,
        sigma=sigma,
        features=features,
        theta=theta,
        demo_kind=kind,
        demo_states=tuple(int(s) for s in paths[index]),
        demo_counts=counts[index].copy(),
        rationality=rationality,
    )


@functools.cache
def reference_case_details(name: str) -> ReferenceResult:
    """:func:`reference_map_details` of the named case (computed once, then cached)."""
    case = _build_case(name)
    return reference_map_details(
        case["features"],
        case["width"],
        case["height"],
        case["start"],
        case["horizon"],
        case["demo_counts"],
        case["rationality"],
    )


@functools.cache
def reference_theta(name: str) -> np.ndarray:
    """The converged reference MAP of the named case, read-only (computed once, then cached)."""
    theta = reference_case_details(name).theta.copy()
    theta.setflags(write=False)
    return theta


def reference_cases() -> list[tuple[str, _Case]]:
    """``(name, case)`` pairs: small games with the reference MAP as ``case["theta_hat"]``.

    A case is a dict with ``width, height, start, horizon, centers, sigma, features (S, K),
    theta`` (the reward that drew the demonstration), ``demo_kind`` (``"expert"``: the reward-
    maximising path for ``theta``; ``"random"``: a uniformly drawn path), ``demo_states``,
    ``demo_counts (K,)`` and ``rationality``. ``case["theta_hat"]`` is computed lazily on first
    use (:func:`reference_theta`, cached); building the list is cheap, so it can parametrise
    tests at collection time. Use ``case["theta_hat"]``, not ``case.get``.
    """
    return [(name, _build_case(name)) for name in _CASES]
