"""Every number of a multiverse's report: the paper's claims in every universe, and across them.

:func:`analyse_multiverse` takes the rows of a multiverse run (:mod:`cirl_study.study.multiverse`)
and its pipeline, and returns them typed
(:class:`~cirl_study.analysis.results.types.MultiverseResults`):

* ``universes``: per universe, its settings, the paper's claims judged on its trials with the
  paper report's own rules (:func:`cirl_study.analysis.results.claims.evaluate_claims` on
  :func:`cirl_study.analysis.results.study.analyse` of its ``main`` block and the cross-validation
  it used), the cross-validated etas, the paper's mixed ANOVA, the cell means and Cronbach's
  alpha;
* ``effects``: per universe and measure of the paper's three
  (:data:`~cirl_study.measure_registry.PAPER_MEASURES`, those its claims are about; so
  ``regression`` and ``joint_test`` too), the human effect: the mean over every ``main``
  subject (both feature levels) of ``d_s = y_{s,br} - y_{s,expert}``, with its paired-t 95%
  CI, ``t``, ``p`` and ``d_z``
  (:func:`cirl_study.analysis.statistics.procedures.paired_differences`);
* ``claims``: per claim, how many universes reproduce it (``tested`` universes only), whether
  the base universe does, and the share reproduced at each level of each axis;
* ``regression``: per measure, an OLS regression of the universes' human effects on the axis
  levels (treatment coding, each axis's base level as the reference), with each axis's share
  of the effect's variance across universes (type II sums of squares over the total);
* ``joint_test``: per measure, the joint test of Simonsohn et al. that the best response beats
  the expert (:func:`cirl_study.analysis.statistics.procedures.joint_sign_flip_test`).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Sequence
from typing import Any

import msgspec
import numpy as np
import pandas as pd
import statsmodels.api as sm
from statsmodels.stats.anova import anova_lm

from cirl_study.analysis.results.per_measure import plain
from cirl_study.analysis.results.study import analyse, with_claims
from cirl_study.analysis.results.types import (
    ClaimShare,
    Coefficient,
    JointTest,
    LevelShare,
    MultiverseResults,
    PairedDifference,
    Regression,
    Table,
    UniverseClaim,
    UniverseSummary,
)
from cirl_study.analysis.statistics import procedures as statistics
from cirl_study.analysis.statistics.tails import t_tail
from cirl_study.analysis.table import check_design, trial_table
from cirl_study.errors import UserError
from cirl_study.measure_registry import MEASURES, PAPER_MEASURES
from cirl_study.record import ETA_CV, EXPERT, MAIN, TrialRow
from cirl_study.study.multiverse import base_universe, cv_universe, universe_pipeline, universes
from cirl_study.study.spec import AXES, Pipeline, Universe, shortest_number
from cirl_study.workers import map_in_workers

PAPER_CLAIMS: tuple[str, ...] = (
    "human_effect",
    "human_f_above_962",
    "interaction_kl_l2",
    "cronbach_alpha",
    "tukey_br_ahead",
)
"""The paper's claims a universe can test (the lambda claim needs a sweep, which a universe
does not play: lambda is one of the axes)."""


def universe_trials(
    trials: Sequence[TrialRow], pipeline: Pipeline
) -> dict[Universe, list[TrialRow]]:
    """Per universe, the rows its study is analysed on: the ``main`` trials of the universe it
    plays (:attr:`~cirl_study.study.spec.Universe.played`) as its own, read with its
    analysis's settings (:func:`judged_rows`), and the cross-validation trials of its
    cross-validation universe (none where it fixes every eta).

    Raises:
        UserError: a universe judges regret under the estimate, which its trials' records do
            not hold (logs of a format before 7).
    """
    by_universe: dict[str | None, list[TrialRow]] = defaultdict(list)
    for row in trials:
        by_universe[row.universe].append(row)
    chosen = {}
    for universe in universes(pipeline):
        main = [r for r in by_universe[universe.played.id] if r.block == MAIN]
        judged = judged_rows(main, universe)
        cv = cv_universe(pipeline, universe)
        own = [] if cv is None else [r for r in by_universe[cv.id] if r.block == ETA_CV]
        chosen[universe] = judged + own
    return chosen


def judged_rows(rows: list[TrialRow], universe: Universe) -> list[TrialRow]:
    """The ``rows`` of the universe ``universe`` plays as ``universe`` analyses them: its id,
    and with ``regret = "estimate"`` the regret under the estimate as the measure ``regret``
    (docs/design.md §4)."""
    if universe == universe.played:
        return rows
    judged = []
    regret = list(MEASURES).index("regret")
    for row in rows:
        under_estimate = row.measure("regret_under_estimate")
        if under_estimate is None:
            raise UserError(
                f"universe {universe.id} judges regret under the estimate, which trial "
                f"{row.trial_id} does not record (its log format is older than 7)"
            )
        measures = (*row.measures[:regret], under_estimate, *row.measures[regret + 1 :])
        judged.append(msgspec.structs.replace(row, universe=universe.id, measures=measures))
    return judged


def level_label(value: Any, axis: str | None = None) -> str:
    """An axis level as the report writes it: ``yes``/``no``, numbers in their shortest exact
    form (:func:`~cirl_study.study.spec.shortest_number`), names as they are, and for a
    universe without the setting (``None``) the ``axis``'s
    :attr:`~cirl_study.study.spec.Axis.unset` (an en dash where the universe's robot lacks it,
    ``cv`` for an eta cross-validated)."""
    if value is None:
        return "–" if axis is None else AXES[axis].unset
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return shortest_number(value)
    return str(value)


def settings(universe: Universe) -> dict[str, Any]:
    """A universe's choices, by axis: every axis's level (``None`` where it does not apply),
    but an optional axis (:attr:`~cirl_study.study.spec.Axis.optional`) only where the
    universe sets it, spelled as in its id (a fixed eta ``k3:1+k10:0.1``, a grid
    ``0.1+1+10``)."""
    chosen = {}
    for name, axis in AXES.items():
        level = getattr(universe, name)
        if not axis.optional:
            chosen[name] = level
        elif level is not None:
            chosen[name] = axis.show(level)
    return chosen


def analyse_multiverse(
    trials: Sequence[TrialRow],
    pipeline: Pipeline,
    *,
    run_id: str | None,
    progress: Callable[[str], None] = lambda stage: None,
) -> MultiverseResults:
    """Every number of the multiverse report (see the module docstring), with the run's id.

    Raises:
        UserError: a universe's trials do not hold a design the paper analysis can use
            (:func:`~cirl_study.analysis.table.check_design`).
    """
    base = base_universe(pipeline)
    chosen = universe_trials(trials, pipeline)
    work = [
        (universe, rows_of_universe, universe_pipeline(pipeline, universe), universe == base)
        for universe, rows_of_universe in chosen.items()
    ]
    per_universe = []
    for position, summary in enumerate(map_in_workers(_universe_summary, work), start=1):
        progress(f"universe {position} of {len(chosen)} analysed: {summary.id}")
        per_universe.append(summary)
    progress("across universes")
    levels = _axes(pipeline)
    table = trial_table(trials)
    main = trial_table([r for rows in chosen.values() for r in rows if r.block == MAIN])
    effects = _effects(main)
    return MultiverseResults(
        pipeline=pipeline.name,
        base_universe=base.id,
        axes=plain(levels),
        trials={
            "total": len(table),
            **{str(b): int(n) for b, n in sorted(table["block"].value_counts().items())},
        },
        universes=Table(UniverseSummary, per_universe),
        effects=effects,
        claims=_claim_shares(per_universe, levels),
        regression={m: _regression(effects, m, levels, pipeline) for m in PAPER_MEASURES},
        joint_test={m: _joint_test(main, m) for m in PAPER_MEASURES},
        run_id=run_id,
    )


def _universe_summary(work: tuple[Universe, list[TrialRow], Pipeline, bool]) -> UniverseSummary:
    """One universe's entry of ``universes`` (see the module docstring), from its rows; the
    universes are analysed on every core (:func:`~cirl_study.workers.map_in_workers`).

    Raises:
        UserError: its rows do not hold a design the paper analysis can use.
    """
    universe, rows_of_universe, study, base = work
    check_design(rows_of_universe)
    results = with_claims(analyse(rows_of_universe, study), run_id=None, partial=None, theory=None)
    if results.paper is None:
        raise UserError(f"universe {universe.id}: its trials lack the paper's two humans")
    return UniverseSummary(
        id=universe.id,
        base=base,
        settings=plain(settings(universe)),
        claims={
            claim.id: UniverseClaim(
                tested=claim.tested, reproduced=claim.reproduced, values=claim.values
            )
            for claim in results.claims
            if claim.id in PAPER_CLAIMS
        },
        eta=results.eta_cv.chosen,
        anova=results.paper.anova,
        cells=results.cells,
        cronbach_alpha=results.paper.cronbach_alpha,
    )


def _axes(pipeline: Pipeline) -> dict[str, list[Any]]:
    """Each axis's levels across the universes as :func:`settings` gives them (``None`` for a
    universe without the setting), the base level first; an optional axis only where some
    universe sets it."""
    levels: dict[str, list[Any]] = {axis: [] for axis in AXES}
    for universe in universes(pipeline):
        chosen = settings(universe)
        for axis in AXES:
            if chosen.get(axis) not in levels[axis]:
                levels[axis].append(chosen.get(axis))
    return {
        axis: each
        for axis, each in levels.items()
        if not AXES[axis].optional or any(level is not None for level in each)
    }


def _effects(main: pd.DataFrame) -> Table[PairedDifference]:
    """Per measure and universe (each sorted), the paired human effect over every ``main``
    subject: without a level or Holm, one comparison per universe."""
    effects = [
        msgspec.structs.replace(row, level=None, p_holm=None, log10_p_holm=None)
        for measure in PAPER_MEASURES
        for row in statistics.paired_differences(main, measure, "human", EXPERT, ["universe"])
    ]
    ordered = sorted(effects, key=lambda row: (row.measure, row.universe))
    return Table(PairedDifference, ordered)


def _claim_shares(
    per_universe: list[UniverseSummary], levels: dict[str, list[Any]]
) -> Table[ClaimShare]:
    """Per claim: universes reproducing it, the base universe's verdict, shares at each of the
    axis ``levels`` (:func:`_axes`)."""
    shares = Table(ClaimShare)
    for claim in PAPER_CLAIMS:
        tested = [u for u in per_universe if u.claims[claim].tested]
        by_level = {
            axis: Table(
                LevelShare,
                (
                    LevelShare(
                        level=plain(level),
                        universes=len(at := [u for u in tested if u.settings.get(axis) == level]),
                        reproduced=sum(u.claims[claim].reproduced for u in at),
                    )
                    for level in levels[axis]
                ),
            )
            for axis in levels
            if len(levels[axis]) > 1
        }
        shares.append(
            ClaimShare(
                id=claim,
                universes=len(tested),
                reproduced=sum(u.claims[claim].reproduced for u in tested),
                base_reproduced=next(u.claims[claim].reproduced for u in per_universe if u.base),
                holds_in=[u.id for u in tested if u.claims[claim].reproduced],
                by_level=by_level,
            )
        )
    return shares


def _regression(
    effects: Table[PairedDifference], measure: str, levels: dict[str, list[Any]], pipeline: Pipeline
) -> Regression:
    """OLS of the universes' human effects on the axis ``levels`` (:func:`_axes`), and each
    axis's share of the effect's variance (type II SS over the total SS); ``None`` parts when
    the universes are too few for the model (no residual degrees of freedom). A nested axis
    (:attr:`~cirl_study.study.spec.Axis.nested`) is left out: its levels are confounded with
    the axis it refines."""
    varied = [axis for axis in levels if len(levels[axis]) > 1 and not AXES[axis].nested]
    by_id = {u.id: settings(u) for u in universes(pipeline)}
    data = pd.DataFrame(
        [
            {
                "effect": row.mean_diff,
                **{a: level_label(by_id[row.universe].get(a)) for a in varied},
            }
            for row in effects
            if row.measure == measure
        ]
    )
    terms = [f"C({axis}, Treatment(reference={level_label(levels[axis][0])!r}))" for axis in varied]
    formula = "effect ~ " + (" + ".join(terms) if terms else "1")
    model = sm.OLS.from_formula(formula, data).fit()
    if model.df_resid < 1:
        return Regression(
            universes=len(data),
            df_residual=float(model.df_resid),
            coefficients=None,
            variance_shares=None,
        )
    interval = model.conf_int(0.05)
    coefficients = Table(Coefficient)
    for name in model.params.index:
        axis, level = _term(name, varied)
        coefficients.append(
            Coefficient(
                axis=axis,
                level=level,
                estimate=float(model.params[name]),
                ci95_low=float(interval.loc[name, 0]),
                ci95_high=float(interval.loc[name, 1]),
                p=float(model.pvalues[name]),
                log10_p=t_tail(float(model.tvalues[name]), float(model.df_resid))[1],
            )
        )
    shares = None
    if terms:
        anova = anova_lm(model, typ=2)
        total = float(np.sum((data["effect"] - data["effect"].mean()) ** 2))
        shares = {
            axis: float(anova.loc[term, "sum_sq"]) / total if total > 0 else None
            for axis, term in zip(varied, terms, strict=True)
        }
        shares["residual"] = float(anova.loc["Residual", "sum_sq"]) / total if total > 0 else None
    return Regression(
        universes=len(data),
        df_residual=float(model.df_resid),
        coefficients=coefficients,
        variance_shares=shares,
        r_squared=float(model.rsquared),
    )


def _term(name: str, axes: list[str]) -> tuple[str | None, str | None]:
    """``(axis, level)`` of a coefficient name of :func:`_regression` (``None`` for the
    intercept, which is the universe at every axis's base level)."""
    if name == "Intercept":
        return None, None
    for axis in axes:
        if name.startswith(f"C({axis},"):
            return axis, name.rsplit("[T.", 1)[1].rstrip("]")
    raise ValueError(f"unexpected regression term {name}")


def _joint_test(main: pd.DataFrame, measure: str) -> JointTest:
    """:func:`~cirl_study.analysis.statistics.procedures.joint_sign_flip_test` on the ``main``
    block."""
    wide = main.pivot_table(
        index="universe", columns=["subject", "human"], values=measure, aggfunc="first"
    ).sort_index()
    differences = (
        wide.xs("best_response", axis=1, level="human") - wide.xs(EXPERT, axis=1, level="human")
    ).sort_index(axis=1)
    if differences.isna().to_numpy().any():
        raise ValueError("the universes do not all play the same subjects")
    return statistics.joint_sign_flip_test(differences.to_numpy())
