"""Teaching over a finite hypothesis space: the literal and the pedagogic observer, exactly.

Ho, Littman, MacGlashan, Cushman & Austerweil (2016, "Showing versus doing") and Milli &
Dragan (2019, "Literal or pedagogic human?") model teaching on a finite set of reward
hypotheses :math:`\\Theta = \\{\\theta_1, \\dots, \\theta_H\\}` with a uniform prior. With the
MaxEnt model of the learning phase (:class:`cirl_study.core.maxent.MaxEnt`),

* the **literal** likelihood is :math:`P_L(\\tau \\mid \\theta_h) = \\exp(\\lambda\\,
  \\theta_h^\\top \\phi(\\tau) - \\log Z(\\theta_h))`, and a literal observer's posterior is
  :math:`P_L(\\theta_h \\mid \\tau) \\propto P_L(\\tau \\mid \\theta_h)`;
* a **pedagogic** demonstrator with reward :math:`\\theta_h` shows :math:`\\tau` with
  probability :math:`P_P(\\tau \\mid \\theta_h) = P_L(\\theta_h \\mid \\tau)^\\alpha / N_h`,
  :math:`N_h = \\sum_\\tau P_L(\\theta_h \\mid \\tau)^\\alpha`, over every path of the phase;
  a pragmatic observer's posterior is :math:`P_P(\\theta_h \\mid \\tau) \\propto
  P_P(\\tau \\mid \\theta_h)`.

Everything depends on a path only through its feature counts :math:`\\phi(\\tau) = \\sum_{t
\\ge 1} \\phi(s_t)`, i.e. through the multiset of cells it visits. :class:`VisitClasses`
enumerates the phase's paths once per grid, start and horizon (shared by every trial and
every reward draw), groups them by that multiset, and keeps each class's multiplicity; so
:math:`N_h = \\sum_m n_m P_L(\\theta_h \\mid m)^\\alpha` is an exact sum over the classes
``m`` with :math:`n_m` paths each (at the paper's size: 1,910,313 paths in 407,677 classes).
The log-partitions :math:`\\log Z(\\theta_h)` come from the exact backward recursion
(:meth:`cirl_study.core.maxent.MaxEnt.log_partition`), and every sum over classes is taken in
log space by a compiled pass without BLAS (:func:`_pedagogic_pass`), so the same trial gives
the same numbers on every CPU.

:class:`HypothesisSpace` holds a batch's hypotheses; the humans
(:mod:`cirl_study.core.teaching`) and robots that read it share one per batch of trials.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from numba import njit
from numpy.typing import NDArray
from scipy.special import logsumexp

from cirl_study.core.maxent import MaxEnt, Phase
from cirl_study.core.planning import FloatArray, IntArray

MAX_PATHS = 8_000_000
"""Most paths :class:`VisitClasses` enumerates (the paper's phase has 1,910,313); a pipeline
that needs more is refused before its first trial."""

SUM_FLOOR = 1e-280
"""Smallest pedagogic normaliser summed directly; below it the sum is redone in log space."""


BOX = (-1.0, 1.0)
"""Support of the uniform prior each hypothesis is drawn from, per coordinate (the box of the
MAP robot, :data:`cirl_study.core.robot.BOX`, which cannot be imported here: the robots'
game imports this module)."""


def path_count(phase: Phase) -> int:
    """Number of paths of the phase from its start (by counting, not listing): its
    ``horizon``-move paths, or with goals those that reach one in time."""
    counts = np.zeros(phase.successors.shape[0], dtype=object)
    counts[phase.start_cell] = 1
    for t in range(phase.horizon):
        following = np.zeros_like(counts)
        for action in range(phase.successors.shape[1]):
            moves = phase.successors[:, action]
            np.add.at(following, moves[moves >= 0], counts[moves >= 0])
        counts = np.where(phase.reachable[t + 1], following, 0)
    return int(counts.sum())


@dataclass(frozen=True, eq=False)
class VisitClasses:
    """The paths of a phase from its start, grouped by the multiset of cells they visit.

    Attributes:
        paths: ``(N, T + 1)`` every path's cells, in lexicographic order of its moves.
        cells: ``(M, T)`` each class's visited cells :math:`s_1..s_T`, sorted.
        multiplicity: ``(M,)`` number of paths :math:`n_m` in each class.
        members: ``(N,)`` path indices grouped by class: class ``m``'s paths are
            ``members[offsets[m]:offsets[m + 1]]``, in the order of :attr:`paths`.
        offsets: ``(M + 1,)`` see :attr:`members`.
    """

    paths: NDArray[np.int32]
    cells: NDArray[np.int32]
    multiplicity: NDArray[np.int64]
    members: NDArray[np.int64]
    offsets: NDArray[np.int64]

    @classmethod
    def of(cls, phase: Phase) -> VisitClasses:
        """Enumerate ``phase`` (shared: one enumeration per successor table, start, horizon)."""
        key = (
            phase.successors.tobytes(), phase.successors.shape, phase.start_cell, phase.horizon,
            phase.goals,
        )  # fmt: skip
        if key not in _ENUMERATED:
            _ENUMERATED.clear()
            _ENUMERATED[key] = cls._enumerate(phase)
        return _ENUMERATED[key]

    @classmethod
    def _enumerate(cls, phase: Phase) -> VisitClasses:
        total = path_count(phase)
        if total > MAX_PATHS:
            raise ValueError(
                f"the learning phase has {total:,} paths, more than the {MAX_PATHS:,} a "
                "hypothesis space enumerates"
            )
        paths = np.full((1, 1), phase.start_cell, dtype=np.int32)
        live = np.append(phase.reachable, np.zeros((phase.horizon + 1, 1), bool), axis=1)
        for t in range(phase.horizon):
            following = phase.successors[paths[:, -1]]
            rows, moves = np.nonzero(live[t + 1][following])
            paths = np.concatenate([paths[rows], following[rows, moves, None]], axis=1)
            paths = paths.astype(np.int32, copy=False)
        visits = np.sort(paths[:, 1:], axis=1)
        keys = _multiset_keys(visits, phase.successors.shape[0])
        _, first, members_class, multiplicity = np.unique(
            keys, axis=0, return_index=True, return_inverse=True, return_counts=True
        )
        members = np.argsort(members_class.ravel(), kind="stable")
        offsets = np.concatenate([[0], np.cumsum(multiplicity)])
        return cls(
            paths=paths,
            cells=np.ascontiguousarray(visits[first]),
            multiplicity=multiplicity.astype(np.int64),
            members=members.astype(np.int64),
            offsets=offsets.astype(np.int64),
        )

    @property
    def size(self) -> int:
        """Number of classes ``M``."""
        return len(self.multiplicity)

    def representative(self, classes: IntArray) -> NDArray[np.int32]:
        """``(n, T + 1)``: the first path (in move order) of each class in ``classes``."""
        return self.paths[self.members[self.offsets[classes]]]

    def path_in(self, classes: IntArray, uniforms: FloatArray) -> NDArray[np.int32]:
        """``(n, T + 1)``: a path of each class, chosen uniformly by one uniform in ``[0, 1)``."""
        size = self.multiplicity[classes]
        within = np.minimum((uniforms * size).astype(np.int64), size - 1)
        return self.paths[self.members[self.offsets[classes] + within]]


_ENUMERATED: dict[tuple[object, ...], VisitClasses] = {}
"""The last enumeration (a study enumerates one learning phase)."""


def _multiset_keys(visits: NDArray[np.int32], cells: int) -> NDArray[np.generic]:
    """One hashable key per sorted row: an integer when it fits in 63 bits, else the bytes."""
    bits = max(1, int(cells - 1).bit_length())
    if bits * visits.shape[1] <= 63:
        keys = np.zeros(len(visits), dtype=np.int64)
        for column in range(visits.shape[1]):
            keys = (keys << bits) | visits[:, column].astype(np.int64)
        return keys
    return np.ascontiguousarray(visits).view(np.dtype((np.void, visits.shape[1] * 4))).ravel()


def draw_hypotheses(
    theta: FloatArray, seeds: IntArray, count: int, *, includes_truth: bool
) -> FloatArray:
    """``(B, H, K)`` each trial's hypotheses: ``count`` reward weights.

    With ``includes_truth`` the first is the true :math:`\\theta` and the other ``count - 1``
    are draws from the prior, :math:`\\mathrm{Uniform}[-1, 1]^K`; without, all ``count`` are
    draws. The draws come from the subject's ``seeds`` (one per trial, equal for every trial
    of a subject), so every human and robot of a subject sees the same space.
    """
    batch, k = theta.shape
    spaces = np.empty((batch, count, k))
    drawn = count - 1 if includes_truth else count
    for b, seed in enumerate(seeds):
        rng = np.random.default_rng(np.random.SeedSequence(int(seed)))
        spaces[b, count - drawn :] = rng.uniform(*BOX, size=(drawn, k))
    if includes_truth:
        spaces[:, 0] = theta
    return spaces


TEACHING_CACHE_BYTES = 256 * 2**20
"""Most bytes of pedagogic path probabilities a batch keeps for reuse
(:meth:`HypothesisSpace.pedagogic_path_log_probability`): 8 bytes a visit class per subject,
so at the paper's 407,677 classes about 80 subjects, more than a batch holds."""


@dataclass(frozen=True, eq=False)
class HypothesisSpace:
    """A batch of trials' hypothesis spaces over the learning phase.

    Attributes:
        model: the MaxEnt model of the learning phase (its :math:`\\lambda` is the literal
            likelihood's); batch ``B``.
        thetas: ``(B, H, K)`` hypotheses :math:`\\theta_h` of each trial (uniform prior).
        includes_truth: whether each space's first hypothesis is the true :math:`\\theta`.
        alpha: the pedagogic exponent :math:`\\alpha > 0`.
    """

    model: MaxEnt
    thetas: FloatArray
    includes_truth: bool
    alpha: float
    _normalisers: dict[bytes, FloatArray] = field(default_factory=dict, repr=False)
    _teaching: dict[bytes, FloatArray] = field(default_factory=dict, repr=False)
    _log_partitions: dict[bytes, FloatArray] = field(default_factory=dict, repr=False)

    def take(self, rows: IntArray) -> HypothesisSpace:
        """The spaces of the trials ``rows`` only; the log-partitions, the normalisers and the
        pedagogic path probabilities computed so far are shared (every human and robot of a
        subject reads them)."""
        return HypothesisSpace(
            self.model.take(rows), self.thetas[rows], self.includes_truth, self.alpha,
            self._normalisers, self._teaching, self._log_partitions,
        )  # fmt: skip

    @property
    def classes(self) -> VisitClasses:
        """The learning phase's paths by visited multiset."""
        return VisitClasses.of(self.model.phase)

    @cached_property
    def log_partition(self) -> FloatArray:
        """``(B, H)`` :math:`\\log Z(\\theta_h)` by the exact backward recursion, once per
        distinct trial features and space (:meth:`_log_partitions_of`)."""
        return self._log_partitions_of(np.arange(self.model.batch), self.thetas)

    def _log_partitions_of(self, rows: IntArray, spaces: FloatArray) -> FloatArray:
        """``(n, H)`` :math:`\\log Z` of the hypotheses ``spaces[i]`` ``(H, K)`` with trial
        ``rows[i]``'s features; those not computed before are computed together (a trial's
        values do not depend on the others computed with it)."""
        keys = [self._key(int(b), space) for b, space in zip(rows, spaces, strict=True)]
        missing = {key: i for i, key in enumerate(keys) if key not in self._log_partitions}
        if missing:
            picked = np.array(list(missing.values()), dtype=np.int64)
            found = set_log_partition(self.model.take(rows[picked]), spaces[picked])
            self._log_partitions.update(zip(missing, found, strict=True))
        return np.array([self._log_partitions[key] for key in keys])

    def literal_log_likelihood(self, counts: FloatArray) -> FloatArray:
        """``(B, H)`` :math:`\\log P_L(\\tau \\mid \\theta_h)` of paths with ``counts``."""
        scores = np.einsum("bhk,bk->bh", self.thetas, counts)
        return self.model.rationality * scores - self.log_partition

    def literal_posterior(self, counts: FloatArray) -> FloatArray:
        """``(B, H)`` the literal observer's :math:`P_L(\\theta_h \\mid \\tau)`."""
        return _normalised(self.literal_log_likelihood(counts))

    def pedagogic_posterior(self, counts: FloatArray) -> FloatArray:
        """``(B, H)`` the pragmatic observer's :math:`P_P(\\theta_h \\mid \\tau)
        \\propto P_L(\\theta_h \\mid \\tau)^\\alpha / N_h`."""
        log_literal = _log_normalised(self.literal_log_likelihood(counts))
        return _normalised(self.alpha * log_literal - self.pedagogic_log_normaliser())

    def pedagogic_log_normaliser(self) -> FloatArray:
        """``(B, H)`` :math:`\\log N_h`, by one pass over the classes per distinct space."""
        return np.array([self._log_normaliser(b, self.thetas[b]) for b in range(self.model.batch)])

    def pedagogic_path_log_probability(self, b: int, theta: FloatArray) -> FloatArray:
        """``(M,)`` :math:`\\log P_P(\\tau \\mid \\theta)` of each path of each class, for trial
        ``b``'s truth ``theta``: :math:`\\alpha \\log P_L(\\theta \\mid m) - \\log N_\\theta`.

        The demonstrator's learner weighs her true reward among the space's hypotheses; when
        the space leaves the truth out she adds it, so she teaches over :math:`\\{\\theta\\}
        \\cup \\Theta`. Classes with equal feature counts get equal values, bit for bit.
        """
        space = self.thetas[b] if self.includes_truth else np.vstack([theta, self.thetas[b]])
        key = self._key(b, space)
        if key in self._teaching:
            return self._teaching[key]
        log_normaliser, per_path = self.pass_over_classes(b, space, 0)
        self._normalisers.setdefault(key, log_normaliser)
        # Kept for the subject's other teaching human (the pedagogic human and the
        # regret-optimal search teach the same truth over the same space), read-only as it is
        # shared, the oldest dropped past TEACHING_CACHE_BYTES.
        per_path.flags.writeable = False
        self._teaching[key] = per_path
        while sum(kept.nbytes for kept in self._teaching.values()) > TEACHING_CACHE_BYTES:
            del self._teaching[next(iter(self._teaching))]
        return per_path

    def teaching_log_weights(self, b: int, theta: FloatArray) -> FloatArray:
        """``(M,)`` :math:`\\log (n_m P_P(m \\mid \\theta))`: the probability that the
        pedagogic demonstrator with trial ``b``'s truth ``theta`` shows a path of class ``m``
        (:meth:`pedagogic_path_log_probability` times the class's paths). They sum (as
        weights) to 1."""
        log_multiplicity = np.log(self.classes.multiplicity.astype(np.float64))
        return log_multiplicity + self.pedagogic_path_log_probability(b, theta)

    def _log_normaliser(self, b: int, space: FloatArray) -> FloatArray:
        """:math:`\\log N_h` over ``space`` for trial ``b``: computed once per distinct trial
        features and space (all the trials of one subject share them)."""
        key = self._key(b, space)
        if key not in self._normalisers:
            self._normalisers[key] = self.pass_over_classes(b, space, None)[0]
        return self._normalisers[key]

    def _key(self, b: int, space: FloatArray) -> bytes:
        """A digest of what a normaliser depends on beyond the shared phase, alpha and lambda."""
        content = np.ascontiguousarray(self.model.features[b]).tobytes() + space.tobytes()
        return hashlib.blake2b(content, digest_size=16).digest()

    def pass_over_classes(
        self, b: int, space: FloatArray, truth: int | None
    ) -> tuple[FloatArray, FloatArray]:
        """:math:`\\log N_h` ``(H,)`` over ``space`` ``(H, K)`` for trial ``b``, and, when
        ``truth`` is an index of ``space``, each class's path log-probability ``(M,)`` of the
        pedagogic demonstrator with that reward (:meth:`pedagogic_path_log_probability`)."""
        log_partition = self._log_partitions_of(np.array([b]), space[None])[0]
        # einsum's own loops, not BLAS: the same sums in the same order on every CPU.
        rewards = self.model.rationality * np.einsum("sk,hk->sh", self.model.features[b], space)
        classes = self.classes
        return _pedagogic_pass(
            classes.cells,
            np.log(classes.multiplicity.astype(np.float64)),
            np.ascontiguousarray(rewards),
            log_partition,
            self.alpha,
            -1 if truth is None else truth,
        )


def set_log_partition(model: MaxEnt, thetas: FloatArray) -> FloatArray:
    """``(B, H)`` :math:`\\log Z(\\theta_h)` of each trial's hypotheses ``thetas``."""
    batch, count, k = thetas.shape
    repeated = MaxEnt(model.phase, np.repeat(model.features, count, axis=0), model.rationality)
    return repeated.log_partition(thetas.reshape(batch * count, k)).reshape(batch, count)


def _log_normalised(log_weights: FloatArray) -> FloatArray:
    """Rows of ``log_weights`` less their log-sum-exp: log probabilities that stay exact where
    the probabilities themselves would underflow (a literal posterior of 1e-400 raised to a
    small alpha is not negligible)."""
    return log_weights - logsumexp(log_weights, axis=-1, keepdims=True)


def _normalised(log_weights: FloatArray) -> FloatArray:
    """Rows of ``exp(log_weights)`` scaled to sum to 1 (shifted by their maximum first)."""
    shifted = np.exp(log_weights - log_weights.max(axis=-1, keepdims=True))
    return shifted / shifted.sum(axis=-1, keepdims=True)


@njit(cache=True)
def _pedagogic_pass(
    cells, log_multiplicity, rewards, log_partition, alpha, truth
):  # pragma: no cover
    """One pass over the classes ``m``: :math:`\\log N_h` and, for ``truth >= 0``,
    :math:`\\alpha \\log P_L(\\theta_{truth} \\mid m) - \\log N_{truth}`.

    ``rewards[s, h]`` is :math:`\\lambda \\theta_h^\\top \\phi(s)`, so a class's log-likelihood
    is :math:`-\\log Z(\\theta_h)` plus its cells' rewards, added in the order of its sorted
    cells. A class that shares its first ``j`` cells with the class before it (mostly long
    prefixes: the classes come sorted by their packed cells, lexicographically wherever the
    key fits in 63 bits) starts from that class's sum after those ``j``: the same additions in
    the same order, so the same number. Each term
    :math:`n_m P_L(\\theta_h \\mid m)^\\alpha` lies in :math:`[0, n_m]`, so the plain sum
    cannot overflow; where it is below :data:`SUM_FLOOR` (its largest terms near underflow)
    that hypothesis is summed again in log space (:func:`_log_space_normaliser`).
    """
    classes, steps = cells.shape
    count = rewards.shape[1]
    total = np.zeros(count)
    # prefix[j]: the log-likelihoods after the class's first j cells (the earlier classes'
    # rows stay valid as far as the current class shares their cells).
    prefix = np.empty((steps + 1, count))
    for h in range(count):
        prefix[0, h] = -log_partition[h]
    score = np.empty(count)
    relative = np.empty(count)
    truth_log = np.empty(classes if truth >= 0 else 0)
    for m in range(classes):
        shared = 0
        if m > 0:
            while shared < steps and cells[m, shared] == cells[m - 1, shared]:
                shared += 1
        for j in range(shared, steps):
            row = cells[m, j]
            for h in range(count):
                prefix[j + 1, h] = prefix[j, h] + rewards[row, h]
        for h in range(count):
            score[h] = prefix[steps, h]
        top = -np.inf
        for h in range(count):
            top = max(top, score[h])
        evidence = 0.0
        for h in range(count):
            relative[h] = np.exp(score[h] - top)
            evidence += relative[h]
        log_evidence = top + np.log(evidence)
        multiplicity = np.exp(log_multiplicity[m])
        if alpha == 1.0:
            for h in range(count):
                total[h] += multiplicity * (relative[h] / evidence)
        else:
            for h in range(count):
                total[h] += multiplicity * np.exp(alpha * (score[h] - log_evidence))
        if truth >= 0:
            truth_log[m] = alpha * (score[truth] - log_evidence)
    log_normaliser = np.log(total)
    for h in range(count):
        if not total[h] > SUM_FLOOR:
            log_normaliser[h] = _log_space_normaliser(
                cells, log_multiplicity, rewards, log_partition, alpha, h
            )
    if truth >= 0:
        truth_log -= log_normaliser[truth]
    return log_normaliser, truth_log


@njit(cache=True)
def _log_space_normaliser(
    cells, log_multiplicity, rewards, log_partition, alpha, h
):  # pragma: no cover
    """:math:`\\log N_h` as a running log-sum-exp (rescaled whenever a larger term arrives),
    for a hypothesis whose every term :math:`n_m P_L(\\theta_h \\mid m)^\\alpha` is tiny."""
    classes, steps = cells.shape
    count = rewards.shape[1]
    score = np.empty(count)
    peak, total = -np.inf, 0.0
    for m in range(classes):
        for g in range(count):
            score[g] = -log_partition[g]
        for j in range(steps):
            for g in range(count):
                score[g] += rewards[cells[m, j], g]
        top = score.max()
        log_evidence = top + np.log(np.exp(score - top).sum())
        term = log_multiplicity[m] + alpha * (score[h] - log_evidence)
        if term > peak:
            total = total * np.exp(peak - term) + 1.0
            peak = term
        else:
            total += np.exp(term - peak)
    return peak + np.log(total)
