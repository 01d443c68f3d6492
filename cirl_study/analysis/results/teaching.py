"""The teaching sections of a study's results: humans who teach and robots who read them.

Each section is computed where the run has its cells (:mod:`cirl_study.analysis.results.cells`), and
is ``None`` otherwise (:func:`cirl_study.analysis.results.study.tests`); its paired sections hold
each measure the analysis tests, and the gap to the regret-optimal demonstration is in regret
(a loss: lower is better):

* ``milli_dragan`` (:data:`~cirl_study.analysis.results.cells.MILLI_DRAGAN`): the 2 x 2 of Milli &
  Dragan (2019), human {literal, pedagogic} x robot {literal_observer, pragmatic}: the
  repeated-measures ANOVA with both within subjects and the feature level between
  (:func:`cirl_study.analysis.statistics.anova.repeated_measures_anova`), and the simple effect of
  the robot, ``pragmatic - literal_observer``, under each human, pooled over the feature levels and
  at each (paired t, Holm per measure);
* ``best_response_vs_pedagogic`` (:data:`~cirl_study.analysis.results.cells.VERSUS_PEDAGOGIC`): per
  robot and feature level, ``best_response - pedagogic``, paired (Holm per measure);
* ``regret_optimal`` (:data:`~cirl_study.analysis.results.cells.REGRET_OPTIMAL_GAP`): with the MAP
  robot, every human's regret gap to the regret-optimal demonstration, ``regret(human) -
  regret(regret_optimal)``, per feature level (paired t, its smallest value, and the share of
  subjects at which the human's demonstration is as good as the best found).

The claims that read them are in :mod:`cirl_study.analysis.results.claims`.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from cirl_study.analysis.results.per_measure import anova_rows, paired_rows
from cirl_study.analysis.results.types import (
    MilliDragan,
    PairedDifference,
    RegretGap,
    RegretOptimal,
    Table,
)
from cirl_study.analysis.statistics import procedures as statistics
from cirl_study.record import (
    BEST_RESPONSE,
    LITERAL,
    LITERAL_OBSERVER,
    MAP,
    PEDAGOGIC,
    PRAGMATIC,
    REGRET_OPTIMAL,
)

SAME_REGRET = 1e-9
"""Regret gap (absolute) below which a demonstration counts as good as the best found: the
MAP robot certifies its estimate to 1e-6, and two demonstrations with the same visit class
give the same estimate bit for bit."""


def milli_dragan(main: pd.DataFrame) -> MilliDragan:
    """The section ``milli_dragan`` of the ``main`` block's table (see the module docstring)."""
    square = main[
        main["human"].isin([LITERAL, PEDAGOGIC]) & main["robot"].isin([LITERAL_OBSERVER, PRAGMATIC])
    ]
    return MilliDragan(
        anova=anova_rows(square, ["human", "robot"]),
        robot_effect=paired_rows(
            square.assign(pooled="all"), "robot", LITERAL_OBSERVER, ["human", "pooled"]
        ),
        robot_effect_by_level=paired_rows(
            square, "robot", LITERAL_OBSERVER, ["human", "num_features"]
        ),
    )


def versus_pedagogic(main: pd.DataFrame) -> Table[PairedDifference]:
    """The section ``best_response_vs_pedagogic`` of the ``main`` block's table."""
    pair = main[main["human"].isin([BEST_RESPONSE, PEDAGOGIC])]
    return paired_rows(pair, "human", PEDAGOGIC, ["robot", "num_features"])


def regret_optimal(main: pd.DataFrame) -> RegretOptimal:
    """The section ``regret_optimal`` of the ``main`` block's table: each human's regret gap to
    the regret-optimal demonstration with the MAP robot, per feature level."""
    gaps = Table(RegretGap)
    with_map = main[main["robot"] == MAP]
    for (level,), group in with_map.groupby(["num_features"], sort=True):
        paired = group.pivot(index="subject", columns="human", values="regret").sort_index()
        best = paired[REGRET_OPTIMAL].to_numpy()
        for human in paired.columns:
            if human == REGRET_OPTIMAL:
                continue
            gap = paired[human].to_numpy() - best
            (test,) = statistics.paired_differences(
                group[group["human"].isin([human, REGRET_OPTIMAL])],
                "regret",
                "human",
                REGRET_OPTIMAL,
                ["num_features"],
            )
            gaps.append(
                RegretGap(
                    num_features=int(level),
                    human=human,
                    n=len(gap),
                    mean_regret_optimal=float(best.mean()),
                    mean_human=float(paired[human].mean()),
                    mean_gap=float(gap.mean()),
                    ci95_low=test.ci95_low,
                    ci95_high=test.ci95_high,
                    p=test.p,
                    log10_p=test.log10_p,
                    smallest_gap=float(gap.min()),
                    share_optimal=float(np.mean(np.abs(gap) <= SAME_REGRET)),
                )
            )
    return RegretOptimal(gaps=gaps)
