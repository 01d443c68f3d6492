"""The cross-validated choice of eta (docs/design.md §3): one function for the run and the report.

Before the test trials, each human with a trade-off (the best response) is played on the
cross-validation draws (block ``eta_cv``, disjoint from the test draws) at every eta of a
grid; per feature level, the eta with the lowest mean regret is chosen. The run plays the
main block and the lambda sweep with that eta, and the report re-derives it from the same
records with the same function, so the two can only disagree if the logs do.

In a pipeline with ``[tasks]`` the test subjects are the tasks, and the cross-validation
still plays draws from the prior over the same features (:mod:`cirl_study.study.plan`): the
tasks are the test set, and an eta chosen on them would be fitted to the rewards it is
judged on (docs/tiles.md).
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from cirl_study.record import ETA_CV, TrialRow


@dataclass(frozen=True)
class EtaChoice:
    """The cross-validated eta of one human at one feature level.

    Attributes:
        universe: the id of the multiverse universe whose cross-validation this is, ``None``
            in a single study.
        human: the human whose trade-off was chosen.
        num_features: the feature level ``K``.
        eta: the eta with the lowest mean regret (ties to the smaller eta).
        mean_regret: mean regret over the cross-validation draws of every eta tried.
        subjects: the number of cross-validation draws behind each mean.
    """

    universe: str | None
    human: str
    num_features: int
    eta: float
    mean_regret: Mapping[float, float]
    subjects: int


def choose_etas(rows: Iterable[TrialRow]) -> dict[tuple[str | None, str, int], EtaChoice]:
    """Per ``(universe, human, num_features)``, the eta with the lowest mean regret over
    ``eta_cv`` trials (``universe`` is ``None`` in a single study).

    ``rows`` are the trials' :class:`~cirl_study.record.TrialRow`; other blocks are ignored.
    Means are exactly rounded sums (:func:`math.fsum`) over the draws, so they do not depend
    on the order the trials come in; ties go to the smaller eta.

    Raises:
        ValueError: an ``eta_cv`` record has no eta, or the etas of one feature level were
            not all played on the same number of draws.
    """
    regrets: dict[tuple[str | None, str, int], dict[float, list[float]]] = defaultdict(
        lambda: defaultdict(list)
    )
    for row in rows:
        if row.block != ETA_CV:
            continue
        if row.eta is None:
            raise ValueError(f"cross-validation trial {row.trial_id} has no eta")
        regrets[row.universe, row.human, row.num_features][row.eta].append(row.measure("regret"))
    choices = {}
    for (universe, human, k), by_eta in sorted(regrets.items(), key=_universe_first):
        sizes = {len(values) for values in by_eta.values()}
        if len(sizes) != 1:
            where = "" if universe is None else f" in universe {universe}"
            raise ValueError(
                f"cross-validation of {human} at K={k}{where}: the etas were played on "
                f"different numbers of draws ({', '.join(map(str, sorted(sizes)))})"
            )
        means = {eta: math.fsum(values) / len(values) for eta, values in sorted(by_eta.items())}
        best = min(means, key=lambda eta: (means[eta], eta))
        choices[universe, human, k] = EtaChoice(universe, human, k, best, means, sizes.pop())
    return choices


def _universe_first(item: tuple[tuple[str | None, str, int], object]) -> tuple[str, str, int]:
    (universe, human, k), _ = item
    return (universe or "", human, k)
