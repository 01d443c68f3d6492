"""The eta each human with a trade-off plays (docs/design.md §3): one function for the run and
the report.

By default eta is cross-validated before the test trials: each human with a trade-off (the
best response) is played on the cross-validation draws (block ``eta_cv``, disjoint from the
test draws) at every eta of a grid, and per feature level the eta with the best mean regret
is chosen. A multiverse universe (:class:`~cirl_study.study.spec.Universe`) may choose on the
mean of another registered measure (``eta_measure``: the lowest of a loss, the highest of a
score), over another grid (``eta_grid``), or fix eta at some feature levels (``eta``), which
then play no cross-validation. The run plays the main block and the lambda sweep with these
etas (:func:`study_etas`), and the report re-derives them from the same records with the same
functions, so the two can only disagree if the logs do.

In a pipeline with ``[tasks]`` the test subjects are the tasks, and the cross-validation
still plays draws from the prior over the same features (:mod:`cirl_study.study.plan`): the
tasks are the test set, and an eta chosen on them would be fitted to the rewards it is
judged on (docs/tiles.md).
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace

from cirl_study.measure_registry import MEASURES
from cirl_study.record import ETA_CV, TrialRow
from cirl_study.study.multiverse import cv_universe, played_universes, universe_pipeline
from cirl_study.study.spec import ETA_MEASURE, Pipeline

EtaKey = tuple[str | None, str, int]
"""``(universe, human, num_features)``: whose eta (``universe`` ``None`` in a single study)."""


@dataclass(frozen=True)
class EtaChoice:
    """The eta of one human at one feature level: cross-validated, or fixed by a universe.

    Attributes:
        universe: the id of the multiverse universe it belongs to, ``None`` in a single
            study: of :func:`choose_etas`, the universe whose cross-validation trials chose it;
            of :func:`study_etas`, the universe whose study plays it.
        human: the human whose trade-off it is.
        num_features: the feature level ``K``.
        eta: the eta: of a cross-validation, the best mean of ``measure`` (ties to the
            smaller eta).
        measure: the measure the cross-validation chose on; ``None``: a fixed eta.
        means: the mean of ``measure`` over the cross-validation draws at every eta tried
            (empty for a fixed eta).
        subjects: the number of cross-validation draws behind each mean (0 for a fixed eta).
    """

    universe: str | None
    human: str
    num_features: int
    eta: float
    measure: str | None = ETA_MEASURE
    means: Mapping[float, float] = field(default_factory=dict)
    subjects: int = 0

    @property
    def fixed(self) -> bool:
        """Whether the eta is fixed rather than cross-validated."""
        return self.measure is None


def choose_etas(rows: Iterable[TrialRow], measure: str = ETA_MEASURE) -> dict[EtaKey, EtaChoice]:
    """Per ``(universe, human, num_features)`` of the ``eta_cv`` trials among ``rows`` (other
    blocks are ignored), the eta with the best mean of ``measure`` over the draws: the lowest
    of a loss, the highest of a score (:attr:`~cirl_study.measure_registry.Measure.
    lower_is_better`); ties go to the smaller eta.

    A draw without a value of ``measure`` at some eta (``null``: undefined for it) is left
    out of every eta's mean, so the means compare the same draws. Means are exactly rounded
    sums (:func:`math.fsum`), so they do not depend on the order the trials come in.

    Raises:
        ValueError: an ``eta_cv`` record has no eta, the etas of one feature level were not
            all played on the same draws, or no draw has a value of ``measure`` at every eta.
    """
    values: dict[EtaKey, dict[float, dict[str, float | None]]] = defaultdict(
        lambda: defaultdict(dict)
    )
    for row in rows:
        if row.block != ETA_CV:
            continue
        if row.eta is None:
            raise ValueError(f"cross-validation trial {row.trial_id} has no eta")
        values[row.universe, row.human, row.num_features][row.eta][row.subject] = row.measure(
            measure
        )
    sign = 1.0 if MEASURES[measure].lower_is_better else -1.0
    choices = {}
    for (universe, human, k), by_eta in sorted(values.items(), key=_universe_first):
        where = f"cross-validation of {human} at K={k}" + (
            "" if universe is None else f" in universe {universe}"
        )
        draws = {frozenset(by_subject) for by_subject in by_eta.values()}
        if len(draws) != 1:
            sizes = sorted({len(subjects) for subjects in draws})
            played = (
                f"different numbers of draws ({', '.join(map(str, sizes))})"
                if len(sizes) > 1
                else "different draws"
            )
            raise ValueError(f"{where}: the etas were played on {played}")
        kept = [
            subject
            for subject in draws.pop()
            if all(by_subject[subject] is not None for by_subject in by_eta.values())
        ]
        if not kept:
            raise ValueError(f"{where}: no draw has a value of {measure} at every eta")
        means = {
            eta: math.fsum(by_eta[eta][subject] for subject in kept) / len(kept)  # type: ignore[misc]
            for eta in sorted(by_eta)
        }
        best = min(means, key=lambda eta: (sign * means[eta], eta))
        choices[universe, human, k] = EtaChoice(universe, human, k, best, measure, means, len(kept))
    return choices


def _universe_first(item: tuple[EtaKey, object]) -> tuple[str, str, int]:
    (universe, human, k), _ = item
    return (universe or "", human, k)


def etas_of_study(study: Pipeline, rows: Iterable[TrialRow]) -> dict[tuple[str, int], EtaChoice]:
    """Per ``(human, num_features)`` of the single study ``study`` (a universe's,
    :func:`~cirl_study.study.multiverse.universe_pipeline`), the eta its study blocks play:
    where its universe fixes eta, that eta; elsewhere the choice of :func:`choose_etas` on the
    universe's measure from ``rows``, the ``eta_cv`` trials of its cross-validation (a level
    they do not hold is left out)."""
    universe = study.universe
    measure = (
        ETA_MEASURE if universe is None or universe.eta_measure is None else (universe.eta_measure)
    )
    chosen = {(human, k): c for (_, human, k), c in choose_etas(rows, measure).items()}
    etas = {}
    for human in study.humans_with_eta:
        for k in study.game.feature_levels:
            fixed = None if universe is None else universe.fixed_eta(k)
            if fixed is not None:
                etas[human, k] = EtaChoice(None, human, k, fixed, measure=None)
            elif (human, k) in chosen:
                etas[human, k] = chosen[human, k]
    return etas


def study_etas(pipeline: Pipeline, rows: Iterable[TrialRow]) -> dict[EtaKey, EtaChoice]:
    """Per ``(universe, human, num_features)``, the eta the study blocks of ``pipeline`` play
    (:func:`etas_of_study`), from ``rows``, its logged ``eta_cv`` trials: in a multiverse, of
    every universe that plays trials (its id), each from the trials of its cross-validation
    universe (:func:`~cirl_study.study.multiverse.cv_universe`); in a single study, ``None``.

    Raises:
        ValueError: the cross-validation trials admit no choice (:func:`choose_etas`).
    """
    cv_rows = [row for row in rows if row.block == ETA_CV]
    if pipeline.multiverse is None:
        return {(None, h, k): c for (h, k), c in etas_of_study(pipeline, cv_rows).items()}
    by_universe: dict[str | None, list[TrialRow]] = defaultdict(list)
    for row in cv_rows:
        by_universe[row.universe].append(row)
    etas = {}
    for universe in played_universes(pipeline):
        cv = cv_universe(pipeline, universe)
        own = [] if cv is None else by_universe[cv.id]
        study = universe_pipeline(pipeline, universe)
        for (human, k), choice in etas_of_study(study, own).items():
            etas[universe.id, human, k] = replace(choice, universe=universe.id)
    return etas
