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

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numba import njit
from numpy.typing import NDArray

from cirl_study.core.planning import (
    FloatArray,
    IntArray,
    backward_future_counts,
    finishing_cells,
    forward_visitation,
    reachable_cells,
    soft_backup,
)

MAX_CLASS_PATHS = 100_000
"""Most paths a demonstration's count class may hold (see :func:`demonstration_classes`)."""


@dataclass(frozen=True, eq=False)
class Phase:
    """The dynamics of one phase: at most ``horizon`` moves on a grid's moves from ``start``.

    A phase has a fixed horizon (every path makes ``horizon`` moves: the paper), or ``goals``:
    cells that absorb, a path ending on entering one, and the paths of the phase are those
    that reach a goal within ``horizon`` moves. The second is encoded as the first on one
    more cell, the *sink* (index ``S``, zero features, so zero reward): a goal's one move is
    the first action into the sink, the sink's is into itself, and a path of the phase is a
    ``horizon``-move path padded with the sink after its goal. Every kernel then runs
    unchanged over paths of one length; :attr:`reachable` leaves out the cells from which no
    goal can be reached in the moves left, so no path that misses every goal is counted.

    Attributes:
        successors: ``(S, A)`` next-cell index of each action on the grid, ``-1`` where
            unavailable; ``(S + 1, A)`` with the sink's row once built, for a phase with goals.
        start: flat index of the start cell :math:`s_0`; ``None`` when the phase starts in
            every cell that can end in time, drawn uniformly (the deployment phase, whose
            measures average over :attr:`starts`).
        horizon: number of moves ``T >= 0`` (at most ``T`` with goals).
        goals: flat indices of the absorbing goal cells (none: a fixed horizon).
    """

    successors: IntArray
    start: int | None
    horizon: int
    goals: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        goals = tuple(sorted({int(g) for g in self.goals}))
        moves = np.ascontiguousarray(self.successors, dtype=np.int64)
        if goals:
            moves = absorbing_moves(moves, goals)
        object.__setattr__(self, "successors", moves)
        object.__setattr__(self, "goals", goals)
        object.__setattr__(self, "start", None if self.start is None else int(self.start))
        object.__setattr__(self, "horizon", int(self.horizon))

    @property
    def cells(self) -> int:
        """``S``, the grid's cells (the sink not counted)."""
        return self.successors.shape[0] - (1 if self.goals else 0)

    @property
    def sink(self) -> int | None:
        """The sink's index ``S`` in a phase with goals, else ``None``."""
        return self.cells if self.goals else None

    @property
    def start_cell(self) -> int:
        """:math:`s_0`; an error for a phase that starts anywhere."""
        if self.start is None:
            raise ValueError("this phase starts in every cell; it has no single start")
        return self.start

    @cached_property
    def finishing(self) -> NDArray[np.bool_]:
        """``(T + 1, S)`` mask (``S + 1`` columns with the sink): ``[t, s]`` is true iff a path
        from ``s`` at step ``t`` can still end in time (with goals: be in a goal or the sink
        after ``T`` moves; without, every path can). What a plan from every cell needs."""
        cells = self.successors.shape[0]
        if self.goals:
            ends = np.zeros(cells, dtype=np.bool_)
            ends[list(self.goals)] = True
            ends[self.cells] = True
        else:
            ends = np.ones(cells, dtype=np.bool_)
        return finishing_cells(self.successors, self.horizon, ends)

    @cached_property
    def reachable(self) -> NDArray[np.bool_]:
        """``(T + 1, S)`` mask: ``[t, s]`` is true iff ``s`` is reached in exactly ``t`` moves
        from a start by a path that can still end in time (:attr:`finishing`)."""
        if self.start is None:
            return self.finishing
        return reachable_cells(self.successors, self.start, self.horizon) & self.finishing

    @cached_property
    def starts(self) -> NDArray[np.bool_]:
        """``(S,)`` the cells the phase may start in: ``start`` alone, or every grid cell that
        is not a goal and can end in time (all of them without goals); the measures average
        over these (:func:`cirl_study.core.measures.over_starts`)."""
        starts = np.zeros(self.cells, dtype=np.bool_)
        if self.start is not None:
            starts[self.start] = True
            return starts
        starts[:] = self.reachable[0, : self.cells]
        starts[list(self.goals)] = False
        return starts

    def path_ends(self, paths: IntArray) -> IntArray:
        """``(B,)`` the number of moves of each ``(B, T + 1)`` path before the sink: ``T``
        without goals, else the step at which the path entered its goal."""
        if not self.goals:
            return np.full(len(paths), self.horizon, dtype=np.int64)
        return (paths != self.cells).sum(axis=1) - 1


def absorbing_moves(successors: IntArray, goals: tuple[int, ...]) -> IntArray:
    """``(S + 1, A)`` moves of a grid whose ``goals`` absorb (see :class:`Phase`): the grid's
    ``successors``, but a goal's only move and the sink's is the first action, into the sink
    (index ``S``).

    Examples:
        >>> absorbing_moves(np.array([[0, 1], [1, 0]]), (1,)).tolist()
        [[0, 1], [2, -1], [2, -1]]
    """
    cells, actions = successors.shape
    moves = np.full((cells + 1, actions), -1, dtype=np.int64)
    moves[:cells] = successors
    moves[list(goals)] = -1
    moves[list(goals), 0] = cells
    moves[cells, 0] = cells
    return moves


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
        rows = np.asarray(rows, dtype=np.int64)
        starts, ends = self.offsets[rows], self.offsets[rows + 1]
        offsets = np.concatenate([[0], np.cumsum(ends - starts)]).astype(np.int64)
        # Exit j of the result is exit j - offsets[r] of row r's range, r the row it falls in.
        picked = np.arange(offsets[-1]) + np.repeat(starts - offsets[:-1], ends - starts)
        return DemonstrationClass(
            members=self.members[rows],
            offsets=offsets,
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
        features: ``(B, S, K)`` cell features :math:`\\phi` of each trial (given for the
            grid's cells; a phase with goals adds the sink's row of zeros).
        rationality: :math:`\\lambda > 0`.
    """

    phase: Phase
    features: FloatArray
    rationality: float

    def __post_init__(self) -> None:
        features = np.ascontiguousarray(self.features, dtype=np.float64)
        if self.phase.sink is not None and features.shape[1] == self.phase.cells:
            features = np.concatenate([features, np.zeros_like(features[:, :1])], axis=1)
        object.__setattr__(self, "features", features)
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
        demonstration's ``demo_counts[b]`` is scored (e.g. samples of a posterior). The
        log-partitions come from :func:`_log_likelihoods`, which agrees with
        :meth:`log_partition` to the rounding of :math:`\\lambda r(s)` (about
        :math:`\\lambda \\max_s |\\theta^\\top \\phi(s)|` times the machine epsilon), and
        scores each point on its own with additions, multiplications and divisions only: a
        point's value does not depend on the others scored with it, nor on the CPU.
        """
        phase = self.phase
        return _log_likelihoods(
            self.rationality,
            np.ascontiguousarray(thetas, dtype=np.float64),
            np.ascontiguousarray(demo_counts, dtype=np.float64),
            self.features,
            phase.successors,
            phase.start_cell,
            phase.horizon,
            phase.reachable,
        )

    def demonstration_classes(self, demos: IntArray) -> DemonstrationClass:
        """The count class of each trial's demonstration path ``demos[b]`` ``(B, T + 1)``.

        Cells whose feature vectors are equal are interchangeable in a path's counts; the
        class of a demonstration is every path from :math:`s_0` through the same multiset of
        feature vectors. Its paths are enumerated depth-first in lexicographic order of their
        cells, and the exits listed prefix by prefix in that order, each prefix's in action
        order (:func:`_class_exits`).

        Raises:
            ValueError: a class holds more than :data:`MAX_CLASS_PATHS` paths.
        """
        phase = self.phase
        demos = np.ascontiguousarray(demos, dtype=np.int64)
        members, offsets, steps, cells, shifts = [], [0], [], [], []
        for b in range(len(demos)):
            paths = _class_paths(phase.successors, phase.start_cell, demos[b], self.features[b])
            if len(paths) > MAX_CLASS_PATHS:
                raise ValueError(
                    f"the demonstration's count class holds more than {MAX_CLASS_PATHS} paths"
                )
            step, cell, shift = _class_exits(phase.successors, paths, demos[b], self.features[b])
            members.append(len(paths))
            steps.append(step)
            cells.append(cell)
            shifts.append(shift)
            offsets.append(offsets[-1] + len(step))
        k = self.features.shape[2]
        return DemonstrationClass(
            members=np.asarray(members, dtype=np.int64),
            offsets=np.asarray(offsets, dtype=np.int64),
            step=np.concatenate(steps or [np.zeros(0, np.int64)]),
            cell=np.concatenate(cells or [np.zeros(0, np.int64)]),
            shift=np.concatenate(shifts or [np.zeros((0, k))]).reshape(-1, k),
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
        E_q\\Delta)^\\top]` (:func:`~cirl_study.core.planning.backward_future_counts`), where
        :math:`C_t(s')`, the covariance of the counts still to come, is never formed: the
        mixture :math:`\\sum_e q_e C_t(s')` is the sum of the squared martingale increments
        of the conditional mean :math:`M_u = \\phi(s_1..s_u) + F_u(s_u)`,

        .. math::

            \\sum_e q_e C_{t_e}(s'_e) = \\sum_{u, s} D_u(s) \\sum_a \\pi_u(a \\mid s)\\,
            \\epsilon\\epsilon^\\top, \\qquad
            \\epsilon = \\phi(s') + F_{u+1}(s') - F_u(s),

        with :math:`D_u(s)` the mass of the paths through the exits that are in ``s`` at step
        ``u``, carried forward from the exits in one pass: ``O(T S A K^2)`` like the backward
        recursion for every :math:`C_t(s)`, without its ``(T, S, K, K)`` table. Every term is
        a sum of non-negative weights (the mass in log space) or of positive semi-definite
        matrices: nothing cancels when the demonstration's own class holds all but
        :math:`10^{-300}` of the mass, which is where
        :math:`\\lambda(\\phi_{demo} - E_\\theta[\\phi])` is lost to rounding. What bounds the
        covariance's precision is the rounding of the mean in the deviations
        :math:`\\mu_e - E_q\\Delta`: its entries are exact relative to the variances down to
        about :math:`(\\epsilon_{mach} |E_q\\Delta|)^2` (checked against 50 digits).
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


LN2_HIGH = 6.93147180369123816490e-01
"""The leading 32 bits of :math:`\\ln 2`: ``E * LN2_HIGH`` is exact for integers
``|E| < 2^21``."""

LN2_LOW = 1.90821492927058770002e-10
""":math:`\\ln 2 -` ``LN2_HIGH``, to double precision."""

EXP_TABLE_STEPS = 32
"""Entries per unit of the table of :math:`e^{j / 32}` behind :func:`_split_exp`."""

_EXP_TABLE = np.array(
    [
        float.fromhex(value)
        for value in (
            "0x1.0000000000000p+0",
            "0x1.08205601127edp+0",
            "0x1.1082b577d34edp+0",
            "0x1.192937074e0cdp+0",
            "0x1.2216045b6f5cdp+0",
            "0x1.2b4b58b372c79p+0",
            "0x1.34cb8170b5835p+0",
            "0x1.3e98deaa11dccp+0",
            "0x1.48b5e3c3e8186p+0",
            "0x1.5325180cfacf7p+0",
            "0x1.5de9176045ff5p+0",
            "0x1.690492cbf9433p+0",
            "0x1.747a513dbef6ap+0",
            "0x1.804d30347b546p+0",
            "0x1.8c802477b0010p+0",
            "0x1.99163ad4b1dccp+0",
            "0x1.a61298e1e069cp+0",
            "0x1.b3787dc80f95fp+0",
            "0x1.c14b431256446p+0",
            "0x1.cf8e5d84758a9p+0",
            "0x1.de455df80e3c0p+0",
            "0x1.ed73f240dc142p+0",
            "0x1.fd1de6182f8c9p+0",
        )
    ]
)
"""The correctly rounded :math:`e^{j / 32}`, ``j = 0..22`` (50-digit mpmath), written out so
that no C library's ``exp`` enters them: :func:`_split_exp` reads ``j = floor(32 r)`` with
:math:`r < \\ln 2 (1 + 2^{-40})`, so :math:`j \\le 22`."""

FARTHEST_EXPONENT = 1000
"""A term more than this many binary orders below a sum's largest is scaled by
``2^-FARTHEST_EXPONENT`` instead of its own power of two: the masses stay below ``2^61``
(:data:`_RENORMALISE_BITS`), so it is below ``2^-939`` of the sum either way and the rounded
sum is the same, and every scaled term is a normal double."""

_RENORMALISE_BITS = 60
"""The masses of :func:`_log_likelihoods` grow by at most a factor ``2A`` a step from
``[1, 2)``; they are brought back to ``[1, 2)`` once their growth could pass ``2^60``."""

LIKELIHOOD_LANES = 128
"""Points scored together by :func:`_log_likelihoods`, in the innermost loops (SIMD lanes);
a point's value does not depend on the others."""


@njit(cache=True, inline="always", error_model="numpy")
def _split_exp(x):  # pragma: no cover - compiled
    """``(m, E)`` with :math:`e^x = m\\, 2^E`, ``E`` an integer (a float) and
    :math:`1 \\le m < 2 (1 + 2^{-40})`, for finite ``x`` with :math:`|E| < 2^{31}`; the
    reduction is exact while :math:`|x| < 2^{21} \\ln 2`, and beyond it :math:`r` carries a
    rounding of about :math:`|x|\\, 2^{-53}`, that of ``x`` itself.

    :math:`E = \\lfloor x / \\ln 2 \\rfloor`, :math:`r = x - E \\ln 2` (Cody and Waite's
    two-part :math:`\\ln 2`, clamped at 0), :math:`j = \\lfloor 32 r \\rfloor`,
    :math:`m = e^{j/32} \\cdot p(r - j/32)` with :math:`p` the degree-7 Taylor polynomial of
    :math:`e^f` on :math:`[0, 1/32)` (remainder below :math:`2^{-55}`): additions,
    multiplications and one table read, so the loop that calls it runs in SIMD lanes and
    gives the same bits on every CPU; within 2 ulp of :math:`e^r` (tests: against mpmath).
    """
    e = np.floor(x * (1.0 / math.log(2.0)))
    r = (x - e * LN2_HIGH) - e * LN2_LOW
    r = r if r > 0.0 else 0.0
    j = int(r * EXP_TABLE_STEPS)
    f = r - j * (1.0 / EXP_TABLE_STEPS)
    p = 1.0 / 5040.0
    p = p * f + 1.0 / 720.0
    p = p * f + 1.0 / 120.0
    p = p * f + 1.0 / 24.0
    p = p * f + 1.0 / 6.0
    p = p * f + 0.5
    p = p * f + 1.0
    p = p * f + 1.0
    return _EXP_TABLE[j] * p, e


@njit(cache=True, inline="always", error_model="numpy")
def _split_log(m, e):  # pragma: no cover - compiled
    """:math:`\\log(m\\, 2^E)` for finite :math:`m > 0` and an integer ``E`` (a float).

    :math:`m = x\\, 2^j` with :math:`x \\in [1/\\sqrt2, \\sqrt2)` (exactly, by ``frexp``),
    :math:`\\log x = 2 \\operatorname{artanh} z = 2 \\sum_{i \\ge 0} z^{2i+1} / (2i + 1)`,
    :math:`z = (x - 1)/(x + 1)`, :math:`|z| < 0.172`, to :math:`i = 11` (remainder below
    :math:`2^{-60}` of the sum), plus :math:`(E + j) \\ln 2` in two parts: additions,
    multiplications and one division, the same bits on every CPU; within 2 ulp of the
    logarithm (tests: against mpmath).
    """
    x, j = math.frexp(m)
    x = 2.0 * x
    e = e + (j - 1)
    if x > math.sqrt(2.0):
        x = 0.5 * x
        e = e + 1.0
    z = (x - 1.0) / (x + 1.0)
    z2 = z * z
    s = 1.0 / 23.0
    s = s * z2 + 1.0 / 21.0
    s = s * z2 + 1.0 / 19.0
    s = s * z2 + 1.0 / 17.0
    s = s * z2 + 1.0 / 15.0
    s = s * z2 + 1.0 / 13.0
    s = s * z2 + 1.0 / 11.0
    s = s * z2 + 1.0 / 9.0
    s = s * z2 + 1.0 / 7.0
    s = s * z2 + 1.0 / 5.0
    s = s * z2 + 1.0 / 3.0
    return e * LN2_HIGH + (2.0 * z + 2.0 * z * (z2 * s) + e * LN2_LOW)


@njit(cache=True, error_model="numpy")
def _log_likelihoods(
    rationality, thetas, demo_counts, features, successors, start, horizon, needed
):  # pragma: no cover - compiled
    """``(B, N)`` :math:`L = \\lambda \\theta^\\top \\phi(\\tau_{demo}) - \\log Z(\\theta)` of
    the ``N`` points ``thetas[b]`` of each trial, each scored on its own, every sum a loop in
    a fixed order.

    :math:`Z_t(s) = \\sum_a w(s') Z_{t+1}(s')`, :math:`Z_T = 1`, with
    :math:`w(s) = e^{\\lambda r(s)}`, is computed in linear space with a binary exponent per
    cell: :math:`w = m_w 2^{E_w}` (:func:`_split_exp`, once per cell) and
    :math:`Z_t(s) = m_t(s)\\, 2^{E_t(s)}`. With :math:`G(s') = E_w(s') + E_{t+1}(s')` and
    :math:`G^* = \\max_a G(s')`,

    .. math::

        E_t(s) = G^*, \\qquad
        m_t(s) = \\sum_a m_w(s')\\, m_{t+1}(s')\\, 2^{G(s') - G^*},

    each power of two exact (written as its IEEE exponent bits; see ``FARTHEST_EXPONENT``),
    so every operation is a rounded product or sum of normal doubles at every
    :math:`\\lambda`: nothing underflows or overflows, and no exponential or logarithm is
    taken per move. The largest term is at least 1, so :math:`m \\ge 1`; every
    :math:`R = \\lfloor 60 / \\log_2 2A \\rfloor` steps the masses are brought back to
    ``[1, 2)`` (exactly, by powers of two). Finally
    :math:`\\log Z = \\log m_0(s_0) + E_0(s_0) \\ln 2` (:func:`_split_log`). Each step adds
    a relative rounding of a few ulp to the masses, so the error of :math:`\\log Z` is a few
    :math:`T` times :math:`2^{-53}` plus that of the scaled rewards :math:`\\lambda r(s)`
    (relative :math:`2^{-53}` each) and of :math:`E \\ln 2`. The points run in the innermost
    loops, ``LIKELIHOOD_LANES`` at a time (each lane does the same operations in the same
    order as it would alone).
    """
    batch, points, k = thetas.shape
    cells = features.shape[1]
    actions = successors.shape[1]
    renormalise = max(1, int(_RENORMALISE_BITS // math.log2(2.0 * actions)))
    entered = np.zeros(cells, dtype=np.bool_)
    for t in range(1, horizon + 1):
        for s in range(cells):
            entered[s] |= needed[t, s]
    lanes = LIKELIHOOD_LANES
    theta = np.empty((k, lanes))
    weight = np.ones((cells, lanes))
    weight_exponent = np.zeros((cells, lanes))
    mass = np.ones((cells, lanes))
    exponent = np.zeros((cells, lanes))
    combined = np.zeros((cells, lanes))
    product = np.zeros((cells, lanes))
    top = np.empty(lanes)
    total = np.empty(lanes)
    power_bits = np.empty(lanes, dtype=np.int64)
    power = power_bits.view(np.float64)  # 2^-gap, built from its exponent bits
    log_likelihood = np.empty((batch, points))
    for b in range(batch):
        phi = features[b]
        for begin in range(0, points, lanes):
            width = min(lanes, points - begin)
            for p in range(width):
                for i in range(k):
                    theta[i, p] = thetas[b, begin + p, i]
            for s in range(cells):
                if not entered[s]:
                    continue
                for p in range(width):
                    total[p] = 0.0
                for i in range(k):
                    f = phi[s, i]
                    for p in range(width):
                        total[p] += f * theta[i, p]
                for p in range(width):
                    m, e = _split_exp(rationality * total[p])
                    weight[s, p] = m
                    weight_exponent[s, p] = e
            for s in range(cells):
                if needed[horizon, s]:
                    for p in range(width):
                        mass[s, p] = 1.0
                        exponent[s, p] = 0.0
            for t in range(horizon - 1, -1, -1):
                for s in range(cells):
                    if needed[t + 1, s]:
                        for p in range(width):
                            combined[s, p] = weight_exponent[s, p] + exponent[s, p]
                            product[s, p] = weight[s, p] * mass[s, p]
                for s in range(cells):
                    if not needed[t, s]:
                        continue
                    for p in range(width):
                        top[p] = -np.inf
                    for a in range(actions):
                        nxt = successors[s, a]
                        if nxt >= 0 and needed[t + 1, nxt]:
                            for p in range(width):
                                g = combined[nxt, p]
                                top[p] = g if g > top[p] else top[p]
                    for p in range(width):
                        total[p] = 0.0
                    for a in range(actions):
                        nxt = successors[s, a]
                        if nxt >= 0 and needed[t + 1, nxt]:
                            for p in range(width):
                                gap = top[p] - combined[nxt, p]
                                gap = gap if gap < FARTHEST_EXPONENT else FARTHEST_EXPONENT
                                power_bits[p] = (1023 - np.int64(gap)) << 52
                            for p in range(width):
                                total[p] += product[nxt, p] * power[p]
                    for p in range(width):
                        mass[s, p] = total[p]
                        exponent[s, p] = top[p]
                if t > 0 and (horizon - t) % renormalise == 0:
                    for s in range(cells):
                        if needed[t, s]:
                            for p in range(width):
                                m, e = math.frexp(mass[s, p])
                                mass[s, p] = 2.0 * m
                                exponent[s, p] += e - 1
            for p in range(width):
                demo = 0.0
                for i in range(k):
                    demo += theta[i, p] * demo_counts[b, i]
                log_z = _split_log(mass[start, p], exponent[start, p])
                log_likelihood[b, begin + p] = rationality * demo - log_z
    return log_likelihood


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
        for j in range(k):
            mean[b, j] = future[0, start, j]
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


@njit(cache=True)
def _class_paths(successors, start, demo, phi):  # pragma: no cover - compiled
    """``(m, T + 1)`` every path from ``start`` whose cells ``s_1..s_T`` carry the multiset of
    feature vectors of ``demo``'s, in lexicographic order; stops after ``MAX_CLASS_PATHS + 1``.

    Cells are of one kind when their feature rows are equal; a kind is the first such cell.
    """
    cells, actions = successors.shape
    k = phi.shape[1]
    horizon = demo.shape[0] - 1
    kind = np.empty(cells, dtype=np.int64)
    for s in range(cells):
        kind[s] = s
        for r in range(s):
            if kind[r] != r:
                continue
            same = True
            for i in range(k):
                if phi[r, i] != phi[s, i]:
                    same = False
                    break
            if same:
                kind[s] = r
                break
    left = np.zeros(cells, dtype=np.int64)  # moves still to make onto each kind
    for t in range(1, horizon + 1):
        left[kind[demo[t]]] += 1
    found = np.empty((4, horizon + 1), dtype=np.int64)
    path = np.empty(horizon + 1, dtype=np.int64)
    path[0] = start
    if horizon == 0:
        found[0, 0] = start
        return found[:1]
    options = np.empty((horizon, actions), dtype=np.int64)
    count = np.zeros(horizon, dtype=np.int64)
    position = np.zeros(horizon, dtype=np.int64)
    members = 0
    depth = 0  # choosing path[depth + 1]
    fresh = True
    while depth >= 0:
        if fresh:  # the moves from path[depth] onto a kind still to visit, by cell index
            listed = 0
            for a in range(actions):
                nxt = successors[path[depth], a]
                if nxt < 0 or left[kind[nxt]] == 0:
                    continue
                at = listed
                while at > 0 and options[depth, at - 1] > nxt:
                    options[depth, at] = options[depth, at - 1]
                    at -= 1
                options[depth, at] = nxt
                listed += 1
            count[depth], position[depth], fresh = listed, 0, False
        if position[depth] == count[depth]:
            depth -= 1
            if depth >= 0:
                left[kind[path[depth + 1]]] += 1
            continue
        nxt = options[depth, position[depth]]
        position[depth] += 1
        path[depth + 1] = nxt
        if depth + 1 == horizon:
            if members == found.shape[0]:
                grown = np.empty((2 * members, horizon + 1), dtype=np.int64)
                for m in range(members):
                    for t in range(horizon + 1):
                        grown[m, t] = found[m, t]
                found = grown
            for t in range(horizon + 1):
                found[members, t] = path[t]
            members += 1
            if members > MAX_CLASS_PATHS:
                break
            continue
        left[kind[nxt]] -= 1
        depth += 1
        fresh = True
    return found[:members]


@njit(cache=True)
def _class_exits(successors, paths, demo, phi):  # pragma: no cover - compiled
    """``(step, cell, shift)`` of every exit of the class ``paths`` (lexicographic, as from
    :func:`_class_paths`): each prefix ``(s_0..s_{t-1})`` of a class path, in lexicographic
    order, and each move from it, in action order, onto a cell ``s'`` that no class path
    takes next; ``shift`` is :math:`\\phi(s_1..s_{t-1}, s') - \\phi(\\tau_{demo})`, summed
    in path order."""
    members, width = paths.shape
    horizon = width - 1
    actions = successors.shape[1]
    k = phi.shape[1]
    demo_counts = np.zeros(k)
    for t in range(1, horizon + 1):
        for i in range(k):
            demo_counts[i] += phi[demo[t], i]
    # common[j]: length of the prefix path j shares with path j - 1.
    common = np.zeros(members, dtype=np.int64)
    for j in range(1, members):
        while common[j] <= horizon and paths[j, common[j]] == paths[j - 1, common[j]]:
            common[j] += 1
    capacity = members * horizon * actions
    step = np.empty(capacity, dtype=np.int64)
    cell = np.empty(capacity, dtype=np.int64)
    shift = np.empty((capacity, k))
    prefix = np.empty(k)
    exits = 0
    for j in range(members):
        for length in range(common[j] + 1, horizon + 1):
            # The class paths through this prefix are j..last - 1; their next cells, sorted.
            last = j + 1
            while last < members and common[last] >= length:
                last += 1
            prefix[:] = 0.0
            for u in range(1, length):
                for i in range(k):
                    prefix[i] += phi[paths[j, u], i]
            for a in range(actions):
                nxt = successors[paths[j, length - 1], a]
                if nxt < 0:
                    continue
                low, high = j, last  # binary search for nxt among paths[j:last, length]
                while low < high:
                    middle = (low + high) // 2
                    if paths[middle, length] < nxt:
                        low = middle + 1
                    else:
                        high = middle
                if low < last and paths[low, length] == nxt:
                    continue
                step[exits], cell[exits] = length, nxt
                for i in range(k):
                    shift[exits, i] = (prefix[i] + phi[nxt, i]) - demo_counts[i]
                exits += 1
    return step[:exits], cell[:exits], shift[:exits]


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
    reach = np.empty((horizon + 1, cells))
    gap = np.empty(k)
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
        # Between the exits: sum_e q_e (mu_e - E_q Delta)(mu_e - E_q Delta)^T.
        reach[:, :] = 0.0
        for e in range(first, last):
            q = np.exp(exit_scaled[e] + values[step[e], cell[e]] - log_mass[b])
            if q == 0.0:
                continue
            t, c = step[e], cell[e]
            reach[t, c] += q
            for i in range(k):
                gap[i] = shift[e, i] + future[t, c, i] - mean[b, i]
            for i in range(k):
                for j in range(i, k):
                    covariance[b, i, j] += q * (gap[i] * gap[j])
        # Within them: sum_e q_e C_{t_e}(s_e), by the martingale increments forward from the
        # exits, sum_t sum_s D_t(s) sum_a pi_t(a|s) e e^T (see _within_exits).
        _within_exits(policy, successors, phi, future, reach, covariance[b])
        for i in range(k):
            for j in range(i):
                covariance[b, i, j] = covariance[b, j, i]
    return log_mass, mean, covariance


@njit(cache=True)
def _within_exits(policy, successors, phi, future, reach, upper):  # pragma: no cover - compiled
    # reach[t] holds the exits' weight entering at step t; it becomes D_t, the mass of the
    # paths through the exits that are in cell s at step t. Adds to ``upper`` the martingale
    # increments' second moments sum_{t, s} D_t(s) sum_a pi_t(a|s) e e^T,
    # e = phi(s') + F_{t+1}(s') - F_t(s), four moves at a time: the K x K sum is read and
    # written once per four rank-one terms, which halves the time of one at a time.
    horizon, cells, actions = policy.shape
    k = phi.shape[1]
    gaps = np.empty((4, k))
    scaled = np.empty((4, k))
    held = 0
    for t in range(horizon):
        for s in range(cells):
            mass = reach[t, s]
            if mass == 0.0:
                continue
            for a in range(actions):
                nxt = successors[s, a]
                if nxt < 0:
                    continue
                p = policy[t, s, a]
                if p == 0.0:
                    continue
                weight = mass * p
                reach[t + 1, nxt] += weight
                for i in range(k):
                    gaps[held, i] = phi[nxt, i] + future[t + 1, nxt, i] - future[t, s, i]
                    scaled[held, i] = weight * gaps[held, i]
                held += 1
                if held < 4:
                    continue
                g0, g1, g2, g3 = gaps[0], gaps[1], gaps[2], gaps[3]
                for i in range(k):
                    c0, c1, c2, c3 = scaled[0, i], scaled[1, i], scaled[2, i], scaled[3, i]
                    row = upper[i]
                    for j in range(k):
                        row[j] += (c0 * g0[j] + c1 * g1[j]) + (c2 * g2[j] + c3 * g3[j])
                held = 0
    for h in range(held):
        for i in range(k):
            c = scaled[h, i]
            row = upper[i]
            for j in range(k):
                row[j] += c * gaps[h, j]
