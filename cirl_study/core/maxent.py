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

    def path_faults(self, paths: object) -> list[str]:
        """What makes ``paths`` not ``B`` paths of this phase, each fault once with its first
        path (empty when they are): an integer array ``(B, T + 1)`` of cell indices, each row
        starting at :attr:`start`, each step one available move (a goal's only move is into
        the sink, and the sink's into itself), each cell one from which a goal can still be
        reached in the moves left (:attr:`reachable`). A phase that starts anywhere checks
        every start.

        Examples:
            >>> phase = Phase(np.array([[0, 1], [1, 0]]), start=0, horizon=2)
            >>> phase.path_faults(np.array([[0, 1, 0]]))
            []
            >>> phase.path_faults(np.array([[1, 1, 0], [0, 1]], dtype=object))
            ['not an integer array of shape (B, 3): shape (2,), dtype object']
            >>> phase.path_faults(np.array([[1, 1, 0]]))
            ['path 0 starts in cell 1, not in the start 0']
        """
        array = np.asarray(paths)
        width = self.horizon + 1
        if array.ndim != 2 or array.shape[1] != width or array.dtype.kind not in "iu":
            return [
                f"not an integer array of shape (B, {width}): shape {array.shape}, "
                f"dtype {array.dtype}"
            ]
        cells = self.successors.shape[0]
        outside = (array < 0) | (array >= cells)
        if outside.any():
            b, t = np.argwhere(outside)[0]
            return [f"path {b} has cell {array[b, t]} at step {t}, outside the {cells} cells"]
        faults = []
        if self.start is not None and (array[:, 0] != self.start).any():
            b = int(np.flatnonzero(array[:, 0] != self.start)[0])
            faults.append(f"path {b} starts in cell {array[b, 0]}, not in the start {self.start}")
        moves = (self.successors[array[:, :-1]] == array[:, 1:, None]).any(axis=2)
        if not moves.all():
            b, t = np.argwhere(~moves)[0]
            faults.append(
                f"path {b} goes from cell {array[b, t]} to cell {array[b, t + 1]} at step "
                f"{t + 1}: not one available move"
            )
        if faults:
            return faults
        live = self.reachable[np.arange(width), array]
        if not live.all():
            b, t = np.argwhere(~live)[0]
            faults.append(
                f"path {b} is in cell {array[b, t]} at step {t}, from which no goal is reached "
                "in the moves left"
            )
        return faults

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
    The moves into one cell at one step from prefixes that took the same multiset of feature
    vectors are one exit here, their number of prefixes its *multiplicity*: the paths through
    them have the same :math:`A_e` and the same futures (:meth:`MaxEnt.demonstration_classes`).

    Attributes:
        members: ``(B,)`` number ``m`` of paths in each trial's class, a float. Each count
            is a sum of non-negative counts, so it is exact while below :math:`2^{53}` and
            beyond within a relative :math:`(T (P - 1) + N - 1)\\, 2^{-53}` (to first order;
            ``P`` the most cells with a move into one cell, ``N`` the cells the class paths
            end in); it overflows only for a class of :math:`2^{1024}` paths or more, which
            needs :math:`A^T \\ge 2^{1024}` (``T > 440`` with five moves).
        offsets: ``(B + 1,)`` trial ``b``'s exits are ``offsets[b]:offsets[b + 1]``.
        step: ``(E,)`` the step ``t`` at which each exit enters its cell.
        cell: ``(E,)`` the cell ``s'`` each exit enters.
        shift: ``(E, K)`` each exit's :math:`A_e`.
        log_multiplicity: ``(E,)`` the logarithm of each exit's multiplicity, the number of
            class prefixes it follows, counted as ``members`` is (the logarithm of the count
            within 2 ulp, :func:`_split_log`; 0 exactly for one prefix).
    """

    members: FloatArray
    offsets: IntArray
    step: IntArray
    cell: IntArray
    shift: FloatArray
    log_multiplicity: FloatArray

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
            log_multiplicity=self.log_multiplicity[picked],
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

        Cells whose feature vectors are equal are of one *kind*, interchangeable in a path's
        counts; the class of a demonstration is every path from :math:`s_0` through the same
        multiset of kinds. It is counted, never listed, by a dynamic programme over its
        prefixes (:func:`_demonstration_classes`): a prefix of ``t`` moves that took only
        kinds of the demonstration, no more of each than it did, is summarised by its *node*,
        its last cell and the multiset of kinds it took (``t`` is the multiset's size). The
        prefixes of one node have the same counts and the same continuations, so the
        programme carries how many reach each node, forward from :math:`s_0` (a move from
        ``s`` at step ``t`` onto ``s'`` exists when the successor table has it and ``s'`` is
        true in ``phase.reachable`` at ``t + 1``); backward from step ``T``, it keeps the
        *live* nodes, those from which a class path can be completed. A move from a live node
        that leads to no live node (onto a kind of which the prefix has no more, or into a node
        from which no class path can be completed) is an exit, of the node's prefix count.

        Exits into the same cell at the same step from the same multiset are merged into one,
        their counts summed: their shifts are the same number, computed once as
        :math:`A_e = \\phi(s') - \\sum_j (n_j - u_j) \\phi_j` (:math:`n_j` the demonstration's
        moves onto kind ``j``, :math:`u_j` the prefix's; no counts cancel). Exits whose shifts
        merely coincide are kept apart. There are at most :math:`S \\prod_j (n_j + 1)` nodes,
        at most :math:`S (T / D + 1)^D` with ``D`` kinds: polynomial in ``T`` for a bounded
        number of kinds whatever the number of paths (a 30-move class of :math:`6 \\cdot
        10^{14}` paths on a 6 x 5 grid of five kinds has about :math:`10^5` nodes and takes
        20 ms), and a handful for the paper's demonstrations (distinct features, nine moves).
        Time and memory are of the order of the nodes times ``A + D`` plus the exits times
        ``K``.

        The exits of a trial are listed by step, and within a step in the order of their first
        move: the nodes in the order they were reached (each node's moves in action order);
        every count is a sum in that order, so the result is a function of the inputs alone,
        the same for a trial alone as in any batch.
        """
        phase = self.phase
        members, offsets, step, cell, shift, log_multiplicity = _demonstration_classes(
            phase.successors,
            phase.start_cell,
            phase.reachable,
            np.ascontiguousarray(demos, dtype=np.int64),
            self.features,
        )
        return DemonstrationClass(members, offsets, step, cell, shift, log_multiplicity)

    def off_demonstration(
        self, theta: FloatArray, demos: DemonstrationClass, *, moments: int = 2
    ) -> OffDemonstration:
        """:math:`\\log R`, :math:`E_q[\\Delta]` and :math:`\\mathrm{Cov}_q[\\Delta]` (see
        :class:`OffDemonstration`), summed over the exits of :class:`DemonstrationClass`.

        ``moments``: 0 computes :math:`\\log R` only, 1 also the mean, 2 also the covariance
        (what is not computed is zero); a line search needs only the first.

        An exit ``e`` (step ``t``, cell ``s'``, multiplicity :math:`n_e`) carries the mass
        :math:`w_e = n_e\\, e^{\\lambda\\theta^\\top A_e + V_t(s')}` of every path through it,
        with :math:`V_t` the soft value of the steps after ``t`` (its logarithm is a sum:
        ``log_multiplicity`` enters as the scaled shift does); so
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
            demos.log_multiplicity,
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


_EMPTY_SLOT = -1
"""An unused slot of the hash tables of :func:`_demonstration_classes`."""

_HASH_MULTIPLIER = -7046029254386353131
"""``0x9E3779B97F4A7C15`` (Fibonacci hashing) as a signed 64-bit integer."""


@njit(cache=True, inline="always")
def _slot(code, cell, cells, bits):  # pragma: no cover - compiled
    """The first slot of the ``2^bits``-slot table for the key ``(code, cell)``, in wrapping
    64-bit arithmetic: the key spreads the entries, it never identifies them."""
    h = (code * cells + cell) * _HASH_MULTIPLIER
    return (h >> (64 - bits)) & ((1 << bits) - 1)


@njit(cache=True)
def _grown_rows(array, rows):  # pragma: no cover - compiled
    """A copy of the 2-D ``array`` with ``rows`` rows (at least its own), by element loops."""
    grown = np.empty((rows, array.shape[1]), dtype=array.dtype)
    for r in range(array.shape[0]):
        for c in range(array.shape[1]):
            grown[r, c] = array[r, c]
    return grown


@njit(cache=True)
def _grown(array, length):  # pragma: no cover - compiled
    """A copy of the 1-D ``array`` with ``length`` entries (at least its own)."""
    grown = np.empty(length, dtype=array.dtype)
    for r in range(array.shape[0]):
        grown[r] = array[r]
    return grown


@njit(cache=True)
def _demonstration_kinds(phi, demo, sample, need, kind_of):  # pragma: no cover - compiled
    """The number ``D`` of kinds of ``demo[1:]`` (its distinct feature rows, in order of first
    appearance); fills ``sample[j]`` (a cell of kind ``j``), ``need[j]`` (the moves onto it)
    and ``kind_of[s]`` (the kind of each cell, ``-1`` for none of the demonstration's)."""
    cells, k = phi.shape
    kinds = 0
    for t in range(1, demo.shape[0]):
        found = -1
        for j in range(kinds):
            same = True
            for i in range(k):
                if phi[sample[j], i] != phi[demo[t], i]:
                    same = False
                    break
            if same:
                found = j
                break
        if found < 0:
            found = kinds
            sample[found], need[found] = demo[t], 0
            kinds += 1
        need[found] += 1
    for s in range(cells):
        kind_of[s] = -1
        for j in range(kinds):
            same = True
            for i in range(k):
                if phi[sample[j], i] != phi[s, i]:
                    same = False
                    break
            if same:
                kind_of[s] = j
                break
    return kinds


@njit(cache=True)
def _demonstration_classes(successors, start, needed, demos, features):  # pragma: no cover
    """``(members, offsets, step, cell, shift, log_multiplicity)`` of each trial's count class
    (:meth:`MaxEnt.demonstration_classes`), by a dynamic programme over its prefixes.

    The demonstration's kinds ``j = 0..D-1`` (:func:`_demonstration_kinds`) are taken
    ``n_j`` times. A node is ``(cell, used)``, ``used[j] <= n_j`` the moves its prefixes made
    onto kind ``j``; the nodes are numbered in the order they are first reached (step by
    step, each step's by their parents' numbers, then by action), and ``layer[t]:layer[t +
    1]`` are those of step ``t``. A node's cell and its ``code`` :math:`\\sum_j used_j R_j`, in
    the mixed radix :math:`R_j = \\prod_{i<j} (n_i + 1)` (wrapping past :math:`2^{64}`, where
    two multisets may share one), place it in the step's hash table; two nodes are one when
    their cells and ``used`` are equal (compared in full: a shared code only costs a probe).

    Forward, a node's prefix count is the sum of its parents' (in their order), and
    ``child[node, a]`` is the node move ``a`` leads to (``-1``: no move, or one onto a kind
    with none left). Backward, a node is live when it is at step ``T`` or a move leads to a
    live node; the parents of a live node are live, so its count is of class prefixes. Then
    each live node's moves that lead to no live node are the exits, found again in a hash
    table per step under ``(cell, code)`` of the node they leave: the shift
    :math:`A_e = \\phi(s') - \\sum_j (n_j - used_j) \\phi_j` (a sum in the kinds' order) is
    computed once, when the exit is first met. Each node and exit is written once and read a
    bounded number of times: ``O((nodes + exits) (A + D) + S D K)`` time for a trial, and
    ``O(nodes (A + D) + exits K)`` memory.
    """
    batch, cells, k = features.shape
    actions = successors.shape[1]
    horizon = demos.shape[1] - 1
    members = np.zeros(batch)
    offsets = np.zeros(batch + 1, dtype=np.int64)
    # The exits of every trial, grown as they come.
    capacity = max(16, batch * horizon * actions)
    step = np.empty(capacity, dtype=np.int64)
    cell = np.empty(capacity, dtype=np.int64)
    shift = np.empty((capacity, k))
    multiplicity = np.empty(capacity)
    exit_code = np.empty(capacity, dtype=np.int64)
    exit_node = np.empty(capacity, dtype=np.int64)  # a node each exit leaves, for its ``used``
    exits = 0
    kind_of = np.empty(cells, dtype=np.int64)
    sample = np.empty(max(horizon, 1), dtype=np.int64)
    need = np.zeros(max(horizon, 1), dtype=np.int64)
    radix = np.empty(max(horizon, 1), dtype=np.int64)
    remaining = np.empty(k)
    # The nodes, grown as they come.
    room = 64
    node_cell = np.empty(room, dtype=np.int64)
    node_code = np.empty(room, dtype=np.int64)
    node_count = np.empty(room)
    child = np.empty((room, actions), dtype=np.int64)
    live = np.empty(room, dtype=np.bool_)
    layer = np.empty(horizon + 2, dtype=np.int64)
    bits = 6
    table = np.full(1 << bits, _EMPTY_SLOT, dtype=np.int64)
    taken = np.empty(1 << bits, dtype=np.int64)  # the slots in use, to empty them
    for b in range(batch):
        phi = features[b]
        kinds = _demonstration_kinds(phi, demos[b], sample, need, kind_of)
        for j in range(kinds):
            radix[j] = 1 if j == 0 else radix[j - 1] * (need[j - 1] + 1)
        used = np.empty((room, kinds), dtype=np.int32)
        # Forward: the nodes of each step and their prefix counts.
        nodes = 0
        layer[0] = 0
        if needed[0, start]:
            node_cell[0], node_code[0], node_count[0] = start, 0, 1.0
            for j in range(kinds):
                used[0, j] = 0
            nodes = 1
        layer[1] = nodes
        for t in range(horizon):
            first, last = layer[t], layer[t + 1]
            most = (last - first) * actions
            if nodes + most > room:
                room = max(2 * room, nodes + most)
                node_cell = _grown(node_cell, room)
                node_code = _grown(node_code, room)
                node_count = _grown(node_count, room)
                child = _grown_rows(child, room)
                used = _grown_rows(used, room)
                live = _grown(live, room)
            while (1 << bits) < 2 * most:
                bits += 1
                table = np.full(1 << bits, _EMPTY_SLOT, dtype=np.int64)
                taken = np.empty(1 << bits, dtype=np.int64)
            held = 0
            for p in range(first, last):
                here = node_cell[p]
                for a in range(actions):
                    child[p, a] = -1
                    nxt = successors[here, a]
                    if nxt < 0 or not needed[t + 1, nxt]:
                        continue
                    j = kind_of[nxt]
                    if j < 0 or used[p, j] == need[j]:
                        continue
                    code = node_code[p] + radix[j]
                    at = _slot(code, nxt, cells, bits)
                    while True:
                        q = table[at]
                        if q == _EMPTY_SLOT:
                            q = nodes
                            nodes += 1
                            table[at] = q
                            taken[held] = at
                            held += 1
                            node_cell[q], node_code[q], node_count[q] = nxt, code, 0.0
                            for i in range(kinds):
                                used[q, i] = used[p, i]
                            used[q, j] += 1
                            break
                        if node_cell[q] == nxt and node_code[q] == code:
                            same = True
                            for i in range(kinds):
                                if used[q, i] != used[p, i] + (1 if i == j else 0):
                                    same = False
                                    break
                            if same:
                                break
                        at = (at + 1) & ((1 << bits) - 1)
                    node_count[q] += node_count[p]
                    child[p, a] = q
            for h in range(held):
                table[taken[h]] = _EMPTY_SLOT
            layer[t + 2] = nodes
        # Backward: the nodes from which the moves complete a class path.
        for p in range(nodes - 1, -1, -1):
            live[p] = p >= layer[horizon]
            if not live[p]:
                for a in range(actions):
                    q = child[p, a]
                    if q >= 0 and live[q]:
                        live[p] = True
                        break
        total = 0.0
        for p in range(layer[horizon], nodes):
            total += node_count[p]
        members[b] = total
        # The exits: the moves of each live node that lead to no live node.
        for t in range(horizon):
            first, last = layer[t], layer[t + 1]
            most = (last - first) * actions
            while (1 << bits) < 2 * most:
                bits += 1
                table = np.full(1 << bits, _EMPTY_SLOT, dtype=np.int64)
                taken = np.empty(1 << bits, dtype=np.int64)
            if exits + most > capacity:
                capacity = max(2 * capacity, exits + most)
                step = _grown(step, capacity)
                cell = _grown(cell, capacity)
                shift = _grown_rows(shift, capacity)
                multiplicity = _grown(multiplicity, capacity)
                exit_code = _grown(exit_code, capacity)
                exit_node = _grown(exit_node, capacity)
            held = 0
            for p in range(first, last):
                if not live[p]:
                    continue
                here = node_cell[p]
                for a in range(actions):
                    nxt = successors[here, a]
                    if nxt < 0 or not needed[t + 1, nxt]:
                        continue
                    q = child[p, a]
                    if q >= 0 and live[q]:
                        continue
                    code = node_code[p]
                    at = _slot(code, nxt, cells, bits)
                    while True:
                        e = table[at]
                        if e == _EMPTY_SLOT:
                            e = exits
                            exits += 1
                            table[at] = e
                            taken[held] = at
                            held += 1
                            step[e], cell[e], multiplicity[e] = t + 1, nxt, 0.0
                            exit_code[e], exit_node[e] = code, p
                            for i in range(k):
                                remaining[i] = 0.0
                            for j in range(kinds):
                                left = need[j] - used[p, j]
                                if left != 0:
                                    for i in range(k):
                                        remaining[i] += left * phi[sample[j], i]
                            for i in range(k):
                                shift[e, i] = phi[nxt, i] - remaining[i]
                            break
                        if cell[e] == nxt and exit_code[e] == code:
                            same = True
                            for i in range(kinds):
                                if used[exit_node[e], i] != used[p, i]:
                                    same = False
                                    break
                            if same:
                                break
                        at = (at + 1) & ((1 << bits) - 1)
                    multiplicity[e] += node_count[p]
            for h in range(held):
                table[taken[h]] = _EMPTY_SLOT
        offsets[b + 1] = exits
    log_multiplicity = np.empty(exits)
    for e in range(exits):
        log_multiplicity[e] = _split_log(multiplicity[e], 0.0)
    return (
        members,
        offsets,
        step[:exits].copy(),
        cell[:exits].copy(),
        shift[:exits].copy(),
        log_multiplicity,
    )


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
    log_multiplicity,
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
            exit_scaled[e] = rationality * total + log_multiplicity[e]
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
