"""Teaching humans and the robots that read them, on a finite hypothesis space.

Humans (levels of ``human``):

* ``pedagogic`` (Ho, Littman, MacGlashan, Cushman & Austerweil 2016, "Showing versus
  doing"): she shows :math:`\\tau` with probability :math:`P_P(\\tau \\mid \\theta) \\propto
  P_L(\\theta \\mid \\tau)^\\alpha`, the literal observer's posterior of her true reward raised
  to :math:`\\alpha` (:class:`cirl_study.core.hypotheses.HypothesisSpace`). She either draws
  her path from that distribution or shows its most likely path (``Teaching.demonstration``).
* ``regret_optimal``: the demonstration that minimises the MAP robot's regret
  (:func:`cirl_study.core.robot.map_estimate`, :func:`cirl_study.core.measures.regret`); the
  paper calls the true best response "too expensive" and approximates it by feature
  matching. Searched, not solved: see :func:`regret_optimal_paths` for the candidate set.

Robots (levels of ``robot``), each acting on its posterior-mean reward
:math:`\\hat\\theta = \\sum_h P(\\theta_h \\mid \\tau)\\, \\theta_h`, which is optimal for its
belief with linear rewards (the paper's Theorem 2):

* ``literal_observer``: Bayes over the hypotheses with the literal likelihood,
  :math:`P(\\theta_h \\mid \\tau) \\propto P_L(\\tau \\mid \\theta_h)`;
* ``pragmatic`` (Fisac et al. 2017, "Pragmatic-pedagogic value alignment"): Bayes assuming
  the pedagogic human, :math:`P(\\theta_h \\mid \\tau) \\propto P_P(\\tau \\mid \\theta_h)`,
  whichever way the human picks her path (with the mode the likelihood would be 0 or 1;
  the robot keeps the smooth model of which the mode is the limit).

Milli & Dragan (2019, "Literal or pedagogic human?") compare the last two under both humans.
"""

from __future__ import annotations

import numpy as np

from cirl_study.core.apprenticeship import Apprenticeship
from cirl_study.core.estimate import Estimate
from cirl_study.core.humans import best_response_paths, expert_paths, human_generator
from cirl_study.core.hypotheses import MAX_PATHS, VisitClasses, path_count
from cirl_study.core.maxent import Phase
from cirl_study.core.measures import regret
from cirl_study.core.planning import FloatArray, IntArray
from cirl_study.core.robot import map_estimate

PEDAGOGIC_CANDIDATES = 16
"""The pedagogic human's most likely classes the regret-optimal search starts from."""

SEARCH_ROUNDS = 4
"""Rounds of single-move improvement in the regret-optimal search."""

EXHAUSTIVE_CLASSES = 2048
"""A learning phase with at most this many visit classes is searched exhaustively."""

FIT_CHUNK = 2048
"""Candidate demonstrations fitted at once by the regret-optimal search (bounds memory)."""


def pedagogic_paths(game: Apprenticeship, theta: FloatArray, seeds: IntArray) -> IntArray:
    """Pedagogic demonstrations ``(B, T + 1)``: drawn from :math:`P_P(\\tau \\mid \\theta)` or
    its most likely path.

    A draw picks a visit class ``m`` with probability :math:`n_m P_P(m \\mid \\theta)` by
    inverting the cumulative weights at one uniform, then one of the class's :math:`n_m`
    paths at a second (both from the trial's :func:`cirl_study.core.humans.human_generator`).
    The most likely path is the first path, in move order, among those with the largest
    :math:`P_L(\\theta \\mid \\tau)`.
    """
    space, settings = game.space(), game.settings()
    classes = space.classes
    log_multiplicity = np.log(classes.multiplicity.astype(np.float64))
    first_path = classes.members[classes.offsets[:-1]]
    chosen = np.empty(len(theta), dtype=np.int64)
    within = np.zeros(len(theta))
    for b, seed in enumerate(seeds):
        per_path = space.pedagogic_path_log_probability(b, theta[b])
        if settings.demonstration == "mode":
            tied = np.flatnonzero(per_path == per_path.max())
            chosen[b] = tied[np.argmin(first_path[tied])]
            continue
        first, second = human_generator(seed).random(2)
        cumulative = np.cumsum(np.exp(per_path + log_multiplicity))
        chosen[b] = min(
            int(np.searchsorted(cumulative, first * cumulative[-1], side="right")),
            classes.size - 1,
        )
        within[b] = second
    if settings.demonstration == "mode":
        return classes.representative(chosen).astype(np.int64)
    return classes.path_in(chosen, within).astype(np.int64)


def regret_optimal_paths(game: Apprenticeship, theta: FloatArray, seeds: IntArray) -> IntArray:
    """The demonstration with the lowest MAP-robot regret found, ``(B, T + 1)``.

    The MAP estimate, hence the regret, depends on a path only through its visit class, so
    the search is over classes. A learning phase with at most :data:`EXHAUSTIVE_CLASSES`
    classes is searched exhaustively (the first path of every class). Otherwise the
    candidates are the expert's path; the paper's best response
    (:func:`cirl_study.core.humans.best_response_paths`) at every trade-off of
    ``Teaching.search_etas``; with a hypothesis space, the :data:`PEDAGOGIC_CANDIDATES`
    classes the pedagogic human finds most telling (largest :math:`P_L(\\theta \\mid m)`,
    ties to the lower class);
    then up to :data:`SEARCH_ROUNDS` rounds of local moves from the best so far (each path
    that differs in one move, kept when it lowers the regret). Ties go to the earlier
    candidate. So the result's regret is never above the expert's or the best response's
    at any searched :math:`\\eta`.
    """
    learning = game.learning
    batch = len(theta)
    classes_total = _visit_classes(game)
    if classes_total is not None and classes_total.size <= EXHAUSTIVE_CLASSES:
        every = classes_total.representative(np.arange(classes_total.size)).astype(np.int64)
        candidates = [every] * batch
        best, _ = _best_of(game, theta, candidates)
        return best
    settings = game.settings()
    starts = [expert_paths(learning, theta)]
    for eta in settings.search_etas:
        starts.append(best_response_paths(learning, theta, np.full(batch, eta)))
    candidates = [np.stack([paths[b] for paths in starts]) for b in range(batch)]
    if game.hypotheses is not None:
        space = game.hypotheses
        for b in range(batch):
            telling = space.pedagogic_path_log_probability(b, theta[b])
            top = _largest_first(telling, PEDAGOGIC_CANDIDATES)
            shown = space.classes.representative(top).astype(np.int64)
            candidates[b] = np.concatenate([candidates[b], shown])
    known: list[dict[bytes, float]] = [{} for _ in range(batch)]
    best, best_regret = _best_of(game, theta, candidates, known)
    for _ in range(SEARCH_ROUNDS):
        moved = [_single_moves(learning.phase, path) for path in best]
        found, found_regret = _best_of(game, theta, moved, known)
        better = found_regret < best_regret
        if not better.any():
            break
        best[better], best_regret[better] = found[better], found_regret[better]
    return best


def _largest_first(values: FloatArray, count: int) -> IntArray:
    """The indices of the ``count`` largest ``values``, largest first, ties to the lower
    index: ``np.argsort(-values, kind="stable")[:count]``, sorting only the values at least
    as large as the ``count``-th largest (a partition finds it) instead of all of them."""
    size = len(values)
    if count >= size or np.isnan(values).any():
        return np.argsort(-values, kind="stable")[:count]
    threshold = np.partition(values, size - count)[size - count]
    contenders = np.flatnonzero(values >= threshold)
    return contenders[np.argsort(-values[contenders], kind="stable")[:count]]


def _visit_classes(game: Apprenticeship) -> VisitClasses | None:
    """The learning phase's visit classes, or ``None`` when it has too many paths to list."""
    if path_count(game.learning.phase) > MAX_PATHS:
        return None
    return VisitClasses.of(game.learning.phase)


def _single_moves(phase: Phase, path: IntArray) -> IntArray:
    """Every path of ``phase`` that makes one move differently from ``path`` and then the same
    moves (with goals: one that still ends in time)."""
    successors, live = phase.successors, phase.reachable
    moves = np.array(
        [
            int(np.flatnonzero(successors[a] == b)[0])
            for a, b in zip(path[:-1], path[1:], strict=True)
        ]
    )
    found = []
    for step in range(len(moves)):
        for action in range(successors.shape[1]):
            if action == moves[step]:
                continue
            changed = moves.copy()
            changed[step] = action
            cells = [path[0]]
            for t, move in enumerate(changed, start=1):
                following = successors[cells[-1], move]
                if following < 0 or not live[t, following]:
                    break
                cells.append(following)
            else:
                found.append(cells)
    return np.array(found, dtype=np.int64).reshape(-1, len(path))


def _best_of(
    game: Apprenticeship,
    theta: FloatArray,
    candidates: list[IntArray],
    known: list[dict[bytes, float]] | None = None,
) -> tuple[IntArray, FloatArray]:
    """Per trial, the candidate path with the lowest MAP regret (the first among equals).

    Each distinct path of a trial is fitted once: a path repeated among its candidates, or
    already in the trial's ``known`` regrets (path bytes to regret, updated here), is not
    fitted again. A fit depends only on its own trial and path, so the regrets are the same.
    """
    known = [{} for _ in candidates] if known is None else known
    rows_fitted: list[int] = []
    fitted: list[IntArray] = []
    for b, c in enumerate(candidates):
        pending: set[bytes] = set()
        for path in c:
            key = path.tobytes()
            if key not in known[b] and key not in pending:
                pending.add(key)
                rows_fitted.append(b)
                fitted.append(path)
    if fitted:
        rows = np.array(rows_fitted, dtype=np.int64)
        paths = np.array(fitted, dtype=np.int64)
        regrets = np.empty(len(rows))
        for start in range(0, len(rows), FIT_CHUNK):
            part = slice(start, start + FIT_CHUNK)
            estimate = map_estimate(game.learning.take(rows[part]), paths[part])
            regrets[part] = regret(
                game.deployment.take(rows[part]), theta[rows[part]], estimate.theta_hat
            )
        for b, path, value in zip(rows, paths, regrets, strict=True):
            known[b][path.tobytes()] = float(value)
    width = candidates[0].shape[1] if candidates else 0
    best = np.empty((len(candidates), width), dtype=np.int64)
    best_regret = np.empty(len(candidates))
    for b, c in enumerate(candidates):
        values = np.array([known[b][path.tobytes()] for path in c])
        pick = int(np.argmin(values))
        best[b], best_regret[b] = c[pick], values[pick]
    return best, best_regret


def literal_estimate(game: Apprenticeship, demos: IntArray, seeds: IntArray) -> Estimate:
    """The literal observer: the posterior mean under :math:`P(\\theta_h \\mid \\tau) \\propto
    P_L(\\tau \\mid \\theta_h)`, exact over the hypotheses."""
    space = game.space()
    counts = game.learning.path_counts(demos)
    return _posterior_mean(game, space.literal_posterior(counts), counts)


def pragmatic_estimate(game: Apprenticeship, demos: IntArray, seeds: IntArray) -> Estimate:
    """The pragmatic robot: the posterior mean under :math:`P(\\theta_h \\mid \\tau) \\propto
    P_P(\\tau \\mid \\theta_h)`, the pedagogic human's likelihood, exact over the hypotheses."""
    space = game.space()
    counts = game.learning.path_counts(demos)
    return _posterior_mean(game, space.pedagogic_posterior(counts), counts)


def _posterior_mean(game: Apprenticeship, posterior: FloatArray, counts: FloatArray) -> Estimate:
    """The estimate :math:`\\sum_h w_h \\theta_h` of a robot whose posterior is ``posterior``."""
    theta_hat = np.clip(np.einsum("bh,bhk->bk", posterior, game.space().thetas), -1.0, 1.0)
    batch = len(theta_hat)
    return Estimate(
        theta_hat=theta_hat,
        log_likelihood=game.learning.log_likelihood(theta_hat, counts),
        iterations=np.zeros(batch, dtype=np.int64),
        converged=np.ones(batch, dtype=bool),
    )
