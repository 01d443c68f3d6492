"""The MaxEnt trajectory model of one phase of the game (docs/design.md §2): the problem object.

A :class:`Phase` is the part of the game's dynamics that a trajectory model needs: the
grid's moves (the ``(S, A)`` successor table), where paths start and how many steps they
take. A :class:`MaxEnt` model adds a batch of ``B`` trials' cell features
:math:`\\phi` (``(B, S, K)``) and the rationality :math:`\\lambda`; for reward weights
:math:`\\theta` it is the distribution over the ``T``-step paths from :math:`s_0`

.. math::

    P(\\tau \\mid \\theta, \\lambda) = \\frac{\\exp(\\lambda\\, \\theta^\\top \\phi(\\tau))}
    {Z(\\theta)}, \\qquad \\log Z(\\theta) = V_0(s_0),

(Ziebart et al., 2008), with :math:`V_0` the soft value of
:func:`cirl_study.core.planning.soft_backup`. The robot uses it to read a demonstration
(:mod:`cirl_study.core.robot`), the best-response human to predict what the robot expects
(:mod:`cirl_study.core.humans`), and the measures to compare true and estimated rewards
(:mod:`cirl_study.core.measures`), so everyone passes this one object instead of the loose
list (features, successors, start, horizon, rationality).

Its moments are exact: the mean from the state visitation :math:`d_t` and the future counts
:math:`F_t` (:func:`cirl_study.core.planning.backward_future_counts`), the second moment from

.. math::

    E[\\phi(\\tau)\\phi(\\tau)^\\top] = \\sum_{t=1}^{T} \\sum_s d_t(s)\\,
    \\big[\\phi(s)\\phi(s)^\\top + \\phi(s) F_t(s)^\\top + F_t(s) \\phi(s)^\\top\\big],

and the demonstration's log-likelihood and its derivatives are

.. math::

    L(\\theta) = \\lambda\\, \\theta^\\top \\phi(\\tau_{demo}) - \\log Z(\\theta), \\quad
    \\nabla L = \\lambda\\,(\\phi(\\tau_{demo}) - E_\\theta[\\phi(\\tau)]), \\quad
    \\nabla^2 L = -\\lambda^2\\, \\mathrm{Cov}_\\theta[\\phi(\\tau)].

The compiled kernels take plain arrays; this module unpacks the objects at their boundary.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numba import njit
from numpy.typing import NDArray

from cirl_study.core.planning import (
    FloatArray,
    IntArray,
    backward_future_counts,
    backward_future_covariance,
    forward_visitation,
    reachable_cells,
    soft_backup,
)

MAX_CLASS_PATHS = 100_000
"""Most paths a demonstration's count class may hold (see :func:`demonstration_classes`)."""


@dataclass(frozen=True, eq=False)
class Phase:
    """The dynamics of one phase: ``horizon`` moves on the grid's ``successors`` from ``start``.

    Attributes:
        successors: ``(S, A)`` next-cell index of each action, ``-1`` where unavailable.
        start: flat index of the start cell :math:`s_0`; ``None`` when every cell is a start,
            drawn uniformly (the deployment phase, whose measures average over all cells).
        horizon: number of moves ``T >= 0``.
    """

    successors: IntArray
    start: int | None
    horizon: int

    def __post_init__(self) -> None:
        object.__setattr__(
            self, "successors", np.ascontiguousarray(self.successors, dtype=np.int64)
        )
        object.__setattr__(self, "start", None if self.start is None else int(self.start))
        object.__setattr__(self, "horizon", int(self.horizon))

    @property
    def start_cell(self) -> int:
        """:math:`s_0`; an error for a phase that starts anywhere."""
        if self.start is None:
            raise ValueError("this phase starts in every cell; it has no single start")
        return self.start

    @cached_property
    def reachable(self) -> NDArray[np.bool_]:
        """``(T + 1, S)`` mask: ``[t, s]`` is true iff ``s`` is reachable in exactly ``t`` moves."""
        if self.start is None:
            return np.ones((self.horizon + 1, self.successors.shape[0]), dtype=np.bool_)
        return reachable_cells(self.successors, self.start, self.horizon)


@dataclass(frozen=True)
class Moments:
    """The model's log-partition and the first two moments of :math:`\\phi(\\tau)`, per trial.

    Attributes:
        log_partition: ``(B,)`` :math:`\\log Z(\\theta)`.
        mean: ``(B, K)`` :math:`E_\\theta[\\phi(\\tau)]`.
        covariance: ``(B, K, K)`` :math:`\\mathrm{Cov}_\\theta[\\phi(\\tau)]`.
    """

    log_partition: FloatArray
    mean: FloatArray
    covariance: FloatArray


@dataclass(frozen=True)
class DemonstrationClass:
    """Each trial's demonstration, as the set of paths that share its feature counts.

    A path :math:`\\tau` with :math:`\\Delta_\\tau = \\phi(\\tau) - \\phi(\\tau_{demo}) = 0`
    (the demonstration, and any path through the same multiset of feature vectors, e.g. its
    cells in another order) has weight :math:`e^{\\lambda \\theta^\\top \\Delta_\\tau} = 1` at
    every :math:`\\theta`. Every other path leaves the prefix tree of these class paths at
    exactly one *exit*: a prefix of a class path followed by a move no class path makes. An
    exit ``e`` at step ``t`` into cell ``s'`` carries :math:`A_e = \\phi(\\text{prefix}, s') -
    \\phi(\\tau_{demo})` (the counts so far, minus the demonstration's), so the paths through it
    have :math:`\\Delta_\\tau = A_e + X` with :math:`X` the counts still to come after ``t``.

    Attributes:
        members: ``(B,)`` number ``m`` of paths in each trial's class.
        offsets: ``(B + 1,)`` trial ``b``'s exits are ``offsets[b]:offsets[b + 1]``.
        step: ``(E,)`` the step ``t`` at which each exit enters its cell.
        cell: ``(E,)`` the cell ``s'`` each exit enters.
        shift: ``(E, K)`` each exit's :math:`A_e`.
    """

    members: IntArray
    offsets: IntArray
    step: IntArray
    cell: IntArray
    shift: FloatArray

    def take(self, rows: IntArray) -> DemonstrationClass:
        """The classes of the trials ``rows`` only (an index array), in that order."""
        rows = np.asarray(rows)
        starts, ends = self.offsets[rows], self.offsets[rows + 1]
        picked = np.concatenate(
            [np.arange(a, b) for a, b in zip(starts, ends, strict=True)] or [np.arange(0)]
        ).astype(np.int64)
        return DemonstrationClass(
            members=self.members[rows],
            offsets=np.concatenate([[0], np.cumsum(ends - starts)]).astype(np.int64),
            step=self.step[picked],
            cell=self.cell[picked],
            shift=self.shift[picked],
        )


@dataclass(frozen=True)
class OffDemonstration:
    """The paths outside the demonstration's class, :math:`\\Delta_\\tau \\ne 0`, per trial.

    With :math:`R(\\theta) = \\sum_{\\Delta_\\tau \\ne 0}
    e^{\\lambda\\theta^\\top\\Delta_\\tau}` and :math:`q(\\tau) \\propto
    e^{\\lambda\\theta^\\top\\Delta_\\tau}` on those paths,

    Attributes:
        log_mass: ``(B,)`` :math:`\\log R(\\theta)`.
        mean: ``(B, K)`` :math:`E_q[\\Delta]`.
        covariance: ``(B, K, K)`` :math:`\\mathrm{Cov}_q[\\Delta]` (zeros when not asked for).
    """

    log_mass: FloatArray
    mean: FloatArray
    covariance: FloatArray


@dataclass(frozen=True, eq=False)
class MaxEnt:
    """The MaxEnt trajectory model of a :class:`Phase` for a batch of trials.

    Attributes:
        phase: the dynamics.
        features: ``(B, S, K)`` cell features :math:`\\phi` of each trial.
        rationality: :math:`\\lambda > 0`.
    """

    phase: Phase
    features: FloatArray
    rationality: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "features", np.ascontiguousarray(self.features, dtype=np.float64))
        object.__setattr__(self, "rationality", float(self.rationality))

    @property
    def batch(self) -> int:
        """Number of trials ``B``."""
        return self.features.shape[0]

    def take(self, rows: NDArray[np.bool_] | IntArray) -> MaxEnt:
        """The model of the trials ``rows`` only (same phase and rationality)."""
        return MaxEnt(self.phase, self.features[rows], self.rationality)

    def cell_rewards(self, theta: FloatArray) -> FloatArray:
        """``(B, S)`` rewards :math:`r_\\theta(s) = \\theta^\\top \\phi(s)` of every cell."""
        return np.einsum("bsk,bk->bs", self.features, theta)

    def path_counts(self, paths: IntArray) -> FloatArray:
        """``(B, K)`` feature counts :math:`\\phi(\\tau) = \\sum_{t \\ge 1} \\phi(s_t)` of paths."""
        rows = np.arange(len(paths))[:, None]
        return self.features[rows, paths[:, 1:]].sum(axis=1)

    def log_partition(self, theta: FloatArray) -> FloatArray:
        """``(B,)`` :math:`\\log Z(\\theta)` over the paths from :math:`s_0`."""
        phase = self.phase
        scaled = self.rationality * self.cell_rewards(theta)
        return _log_partition(
            scaled, phase.successors, phase.start_cell, phase.horizon, phase.reachable
        )

    def log_likelihood(self, theta: FloatArray, demo_counts: FloatArray) -> FloatArray:
        """``(B,)`` log-likelihood of the demonstrations' counts.

        :math:`L(\\theta) = \\lambda\\,\\theta^\\top\\phi(\\tau_{demo}) - \\log Z(\\theta)`.
        """
        return self.rationality * np.einsum("bk,bk->b", theta, demo_counts) - self.log_partition(
            theta
        )

    def log_likelihood_at(self, thetas: FloatArray, demo_counts: FloatArray) -> FloatArray:
        """``(B, N)`` log-likelihoods :math:`L(\\theta_{b,n})` of ``N`` weight vectors per trial.

        ``thetas`` is ``(B, N, K)``: for trial ``b``, the points ``thetas[b]`` at which its
        demonstration's ``demo_counts[b]`` is scored (e.g. samples of a posterior).
        """
        phase = self.phase
        batch, points, _ = thetas.shape
        scaled = self.rationality * np.einsum("bsk,bnk->bns", self.features, thetas)
        log_z = _log_partition(
            np.ascontiguousarray(scaled.reshape(batch * points, -1)),
            phase.successors,
            phase.start_cell,
            phase.horizon,
            phase.reachable,
        ).reshape(batch, points)
        return self.rationality * np.einsum("bnk,bk->bn", thetas, demo_counts) - log_z

    def demonstration_classes(self, demos: IntArray) -> DemonstrationClass:
        """The count class of each trial's demonstration path ``demos[b]`` ``(B, T + 1)``.

        Cells whose feature vectors are equal (bit for bit) are interchangeable in a path's
        counts; the class of a demonstration is every path from :math:`s_0` through the same
        multiset of feature vectors, enumerated depth-first over those cells only.

        Raises:
            ValueError: a class holds more than :data:`MAX_CLASS_PATHS` paths.
        """
        phase = self.phase
        members, offsets, steps, cells, shifts = [], [0], [], [], []
        for b, demo in enumerate(np.asarray(demos)):
            features = self.features[b]
            _, kind = np.unique(features, axis=0, return_inverse=True)
            paths = _class_paths(phase.successors, phase.start_cell, demo, kind.ravel())
            members.append(len(paths))
            demo_counts = features[demo[1:]].sum(axis=0)
            for step, prefix, cell in _exits(phase.successors, paths):
                steps.append(step)
                cells.append(cell)
                shifts.append(features[[*prefix[1:], cell]].sum(axis=0) - demo_counts)
            offsets.append(len(steps))
        k = self.features.shape[2]
        return DemonstrationClass(
            members=np.asarray(members, dtype=np.int64),
            offsets=np.asarray(offsets, dtype=np.int64),
            step=np.asarray(steps, dtype=np.int64),
            cell=np.asarray(cells, dtype=np.int64),
            shift=np.asarray(shifts, dtype=np.float64).reshape(-1, k),
        )

    def off_demonstration(
        self, theta: FloatArray, demos: DemonstrationClass, *, moments: int = 2
    ) -> OffDemonstration:
        """:math:`\\log R`, :math:`E_q[\\Delta]` and :math:`\\mathrm{Cov}_q[\\Delta]` (see
        :class:`OffDemonstration`), summed over the exits of :class:`DemonstrationClass`.

        ``moments``: 0 computes :math:`\\log R` only, 1 also the mean, 2 also the covariance
        (what is not computed is zero); a line search needs only the first.

        An exit ``e`` (step ``t``, cell ``s'``) carries the mass
        :math:`w_e = e^{\\lambda\\theta^\\top A_e + V_t(s')}` of every path through it, with
        :math:`V_t` the soft value of the steps after ``t``; so
        :math:`\\log R = \\operatorname{logsumexp}_e \\log w_e`, and with
        :math:`q_e = w_e / R`, :math:`\\mu_e = A_e + F_t(s')`,
        :math:`E_q[\\Delta] = \\sum_e q_e \\mu_e` and
        :math:`\\mathrm{Cov}_q[\\Delta] = \\sum_e q_e [C_t(s') + (\\mu_e - E_q\\Delta)(\\mu_e -
        E_q\\Delta)^\\top]` (:func:`~cirl_study.core.planning.backward_future_counts`,
        :func:`~cirl_study.core.planning.backward_future_covariance`). Every term is a sum of
        non-negative weights in log space: nothing cancels when the demonstration's own class
        holds all but :math:`10^{-300}` of the mass, which is where
        :math:`\\lambda(\\phi_{demo} - E_\\theta[\\phi])` is lost to rounding.
        """
        phase = self.phase
        log_mass, mean, cov = _off_demonstration(
            self.rationality,
            np.ascontiguousarray(theta, dtype=np.float64),
            self.features,
            phase.successors,
            phase.horizon,
            phase.reachable,
            demos.offsets,
            demos.step,
            demos.cell,
            demos.shift,
            moments,
        )
        return OffDemonstration(log_mass, mean, cov)

    def moments(self, theta: FloatArray, *, covariance: bool = True) -> Moments:
        """The log-partition, mean and covariance of :math:`\\phi(\\tau)` under :math:`\\theta`.

        Without ``covariance`` (what the best response needs) the covariance is left zero
        and its forward pass is skipped.
        """
        phase = self.phase
        scaled = self.rationality * self.cell_rewards(theta)
        log_z, mean, covariance = _trajectory_moments(
            scaled,
            self.features,
            phase.successors,
            phase.start_cell,
            phase.horizon,
            phase.reachable,
            covariance,
        )
        return Moments(log_z, mean, covariance)


@njit(cache=True)
def _log_partition(scaled, successors, start, horizon, needed):  # pragma: no cover - compiled
    batch, cells = scaled.shape
    actions = successors.shape[1]
    values = np.empty((horizon + 1, cells))
    log_policy = np.empty((horizon, cells, actions))
    policy = np.empty((horizon, cells, actions))
    log_z = np.empty(batch)
    for b in range(batch):
        soft_backup(scaled[b], successors, horizon, values, log_policy, policy, needed)
        log_z[b] = values[0, start]
    return log_z


@njit(cache=True)
def _trajectory_moments(
    scaled, features, successors, start, horizon, needed, with_covariance
):  # pragma: no cover - compiled
    batch, cells, k = features.shape
    actions = successors.shape[1]
    values = np.empty((horizon + 1, cells))
    log_policy = np.empty((horizon, cells, actions))
    policy = np.empty((horizon, cells, actions))
    visitation = np.empty((horizon + 1, cells))
    future = np.empty((horizon + 1, cells, k))
    log_z = np.empty(batch)
    mean = np.empty((batch, k))
    covariance = np.zeros((batch, k, k))
    for b in range(batch):
        phi = features[b]
        soft_backup(scaled[b], successors, horizon, values, log_policy, policy, needed)
        backward_future_counts(policy, successors, phi, future, needed)
        log_z[b] = values[0, start]
        mean[b] = future[0, start]
        if not with_covariance:
            continue
        visitation[0, :] = 0.0
        visitation[0, start] = 1.0
        forward_visitation(policy, successors, visitation)
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


def _class_paths(
    successors: IntArray, start: int, demo: IntArray, kind: IntArray
) -> list[tuple[int, ...]]:
    """Every path from ``start`` whose cells ``s_1..s_T`` have the multiset of kinds of ``demo``."""
    remaining: dict[int, int] = {}
    for cell in demo[1:]:
        remaining[int(kind[cell])] = remaining.get(int(kind[cell]), 0) + 1
    horizon = len(demo) - 1
    paths: list[tuple[int, ...]] = []
    stack = [(int(start),)]
    counts: list[dict[int, int]] = [remaining]
    while stack:
        prefix, left = stack.pop(), counts.pop()
        if len(prefix) == horizon + 1:
            paths.append(prefix)
            if len(paths) > MAX_CLASS_PATHS:
                raise ValueError(
                    f"the demonstration's count class holds more than {MAX_CLASS_PATHS} paths"
                )
            continue
        for nxt in successors[prefix[-1]]:
            if nxt < 0 or left.get(int(kind[nxt]), 0) == 0:
                continue
            after = dict(left)
            after[int(kind[nxt])] -= 1
            stack.append((*prefix, int(nxt)))
            counts.append(after)
    return paths


def _exits(
    successors: IntArray, paths: list[tuple[int, ...]]
) -> list[tuple[int, tuple[int, ...], int]]:
    """``(t, prefix, s')``: every move from a class-path prefix ``(s_0..s_{t-1})`` to a cell
    ``s'`` at step ``t`` that no class path makes, in a deterministic order."""
    children: dict[tuple[int, ...], set[int]] = {}
    for path in paths:
        for t in range(1, len(path)):
            children.setdefault(path[:t], set()).add(path[t])
    exits = []
    for prefix in sorted(children):
        for nxt in successors[prefix[-1]]:
            if nxt >= 0 and int(nxt) not in children[prefix]:
                exits.append((len(prefix), prefix, int(nxt)))
    return exits


@njit(cache=True)
def _off_demonstration(
    rationality,
    theta,
    features,
    successors,
    horizon,
    needed,
    offsets,
    step,
    cell,
    shift,
    moments,
):  # pragma: no cover - compiled
    # Every sum is a plain loop in a fixed order: the result is the same on every CPU.
    batch, cells, k = features.shape
    actions = successors.shape[1]
    scaled = np.empty(cells)
    exit_scaled = np.empty(shift.shape[0])
    values = np.empty((horizon + 1, cells))
    log_policy = np.empty((horizon, cells, actions))
    policy = np.empty((horizon, cells, actions))
    future = np.empty((horizon + 1, cells, k))
    future_cov = np.zeros((horizon + 1, cells, k, k))
    log_mass = np.full(batch, -np.inf)
    mean = np.zeros((batch, k))
    covariance = np.zeros((batch, k, k))
    for b in range(batch):
        first, last = offsets[b], offsets[b + 1]
        if first == last:
            continue
        phi = features[b]
        for s in range(cells):
            total = 0.0
            for i in range(k):
                total += phi[s, i] * theta[b, i]
            scaled[s] = rationality * total
        for e in range(first, last):
            total = 0.0
            for i in range(k):
                total += theta[b, i] * shift[e, i]
            exit_scaled[e] = rationality * total
        soft_backup(scaled, successors, horizon, values, log_policy, policy, needed)
        if moments >= 1:
            backward_future_counts(policy, successors, phi, future, needed)
        if moments >= 2:
            backward_future_covariance(policy, successors, phi, future, future_cov, needed)
        top = -np.inf
        for e in range(first, last):
            top = max(top, exit_scaled[e] + values[step[e], cell[e]])
        total = 0.0
        for e in range(first, last):
            total += np.exp(exit_scaled[e] + values[step[e], cell[e]] - top)
        log_mass[b] = top + np.log(total)
        if moments < 1:
            continue
        for e in range(first, last):
            q = np.exp(exit_scaled[e] + values[step[e], cell[e]] - log_mass[b])
            for i in range(k):
                mean[b, i] += q * (shift[e, i] + future[step[e], cell[e], i])
        if moments < 2:
            continue
        for e in range(first, last):
            q = np.exp(exit_scaled[e] + values[step[e], cell[e]] - log_mass[b])
            if q == 0.0:
                continue
            t, c = step[e], cell[e]
            for i in range(k):
                gi = shift[e, i] + future[t, c, i] - mean[b, i]
                for j in range(k):
                    gj = shift[e, j] + future[t, c, j] - mean[b, j]
                    covariance[b, i, j] += q * (future_cov[t, c, i, j] + gi * gj)
    return log_mass, mean, covariance
