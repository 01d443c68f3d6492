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
    forward_visitation,
    reachable_cells,
    soft_backup,
)


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

    def moments(self, theta: FloatArray) -> Moments:
        """The log-partition, mean and covariance of :math:`\\phi(\\tau)` under :math:`\\theta`."""
        phase = self.phase
        scaled = self.rationality * self.cell_rewards(theta)
        log_z, mean, covariance = _trajectory_moments(
            scaled,
            self.features,
            phase.successors,
            phase.start_cell,
            phase.horizon,
            phase.reachable,
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
def _trajectory_moments(scaled, features, successors, start, horizon, needed):  # pragma: no cover
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
