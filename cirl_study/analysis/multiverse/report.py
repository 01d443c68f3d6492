"""The report of a multiverse run: ``report.md``, ``results.json``, ``universes.csv``, figures.

:func:`write_multiverse_report` turns the rows of a multiverse run into a directory that reads
well on GitHub: which of the paper's claims hold in how many universes, at which levels of
which settings, the specification curve of the human effect on each of the paper's three
measures with the joint test of Simonsohn et al., and one line per universe. Like the paper
report it is a deterministic function of the trials (their order does not matter).
``universes.csv`` holds one row per universe (its settings, its verdicts and its human
effects) in place of the paper report's ``trials.csv``: the trials themselves are in the run's
logs.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import msgspec
import pandas as pd

from cirl_study import escape
from cirl_study.analysis.multiverse.results import PAPER_CLAIMS, analyse_multiverse, level_label
from cirl_study.analysis.report import figures
from cirl_study.analysis.report.markdown import (
    document,
    interval,
    measure_name,
    number,
    p_value,
    table,
)
from cirl_study.analysis.report.output import write_report_directory
from cirl_study.analysis.results.types import (
    ClaimShare,
    LevelShare,
    MultiverseResults,
    PairedDifference,
)
from cirl_study.measure_registry import PAPER_MEASURES
from cirl_study.record import TrialRow
from cirl_study.study.spec import AXES, Pipeline

CLAIM_TEXT = {
    "human_effect": "best response beats expert on every measure, p < .0001",
    "human_f_above_962": "human F > 962 on every measure",
    "interaction_kl_l2": "KL and L2: human x features interaction, gap larger at fewer features",
    "cronbach_alpha": "Cronbach's alpha of the measures is .47",
    "tukey_br_ahead": "Tukey HSD: best response ahead in every cell",
}
"""Each paper claim a universe tests, in a few words (the rules: the paper report's)."""


FIGURE_NAMES = {measure: f"specification_curve_{measure}.png" for measure in PAPER_MEASURES}
"""The specification curve of each measure."""


def _varied(results: MultiverseResults) -> list[str]:
    """The axes whose levels differ between the universes."""
    return [axis for axis, levels in results.axes.items() if len(levels) > 1]


def _header(results: MultiverseResults) -> list[str]:
    universes = results.universes
    base = results.base_universe
    varied = {axis: results.axes[axis] for axis in _varied(results)}
    lines = [
        f"# Multiverse report: {escape.markdown(results.pipeline)}",
        "",
        f"The paper's study (the eta cross-validation and the main human x num_features "
        f"design) played in **{len(universes)} universes**, each a choice of the settings the "
        f"paper leaves open, on the same reward draws ({results.trials['total']} trials). "
        "Each universe's claims are judged with the paper report's own rules; the lambda claim "
        "needs a sweep, which a universe does not play (lambda is an axis).",
        "",
        f"The base universe, the pipeline's own settings: {escape.markdown(base)}.",
        "",
        table(
            ["setting", "levels (base first)"],
            [
                [axis, ", ".join(level_label(level, axis) for level in levels)]
                for axis, levels in varied.items()
            ],
            [False, False],
        ),
    ]
    return lines


def _claims(results: MultiverseResults) -> list[str]:
    rows = []
    for claim in results.claims:
        reproduced, tested = claim.reproduced, claim.universes
        rows.append(
            [
                f"{claim.id}: {CLAIM_TEXT[claim.id]}",
                f"{reproduced} of {tested}",
                "✅" if claim.base_reproduced else "❌",
                _where(claim),
            ]
        )
    return [
        "## Claims across universes",
        "",
        table(
            [
                "claim",
                "universes reproducing it",
                "base universe",
                "levels at which every universe reproduces it (levels of two universes or more)",
            ],
            rows,
            [False, True, False, False],
        ),
        "",
        "Per level of each setting, the universes at that level that reproduce the claim:",
        "",
        *_level_tables(results),
    ]


def _where(claim: ClaimShare) -> str:
    """The axis levels, each of two universes or more, at which every universe reproduces the
    claim (or a word why none): a level of one universe says no more than that universe."""
    if claim.reproduced == 0:
        return "none"
    if claim.reproduced == claim.universes:
        return "everywhere"
    always = [
        f"{axis} = {level_label(level.level, axis)} ({_share(level)})"
        for axis, levels in claim.by_level.items()
        for level in levels
        if level.universes >= 2 and level.reproduced == level.universes
    ]
    return ", ".join(always) if always else "no single level"


def _level_tables(results: MultiverseResults) -> list[str]:
    claims = results.claims
    lines = []
    for axis in AXES:
        if axis not in claims[0].by_level:
            continue
        levels = claims[0].by_level[axis]
        header = [axis, *(claim.id for claim in claims)]
        body = [
            [
                f"{level_label(level.level, axis)} ({_universe_count(level.universes)})",
                *(_share(claim.by_level[axis][i]) for claim in claims),
            ]
            for i, level in enumerate(levels)
        ]
        lines += [table(header, body, [False, *[True] * len(claims)]), ""]
    return lines


def _universe_count(count: int) -> str:
    """``1 universe``, ``2 universes``."""
    return f"{count} universe" if count == 1 else f"{count} universes"


def _share(level: LevelShare) -> str:
    return f"{level.reproduced} / {level.universes}"


def _effect(row: PairedDifference) -> str:
    """A universe's human effect on a measure: the mean difference with its 95% CI."""
    return f"{number(row.mean_diff)} {interval(row.ci95_low, row.ci95_high)}"


def _holds(results: MultiverseResults) -> list[str]:
    lines = ["## Where the claims the base universe does not reproduce hold", ""]
    for claim in results.claims:
        if claim.base_reproduced:
            continue
        holds = claim.holds_in
        lines.append(f"- **{claim.id}** ({CLAIM_TEXT[claim.id]}): ")
        if not holds:
            lines[-1] += "in no universe."
        else:
            lines[-1] += f"in {len(holds)} universe(s): " + "; ".join(f"`{u}`" for u in holds)
    return lines


def _curves(results: MultiverseResults) -> list[str]:
    lines = [
        "## The human effect across universes",
        "",
        "Per measure, the mean over every main-block subject of best response minus expert "
        "(negative: the best response did better), universes sorted by it, with the joint test "
        "of Simonsohn, Simmons & Nelson (2020) that the best response beats the expert: the "
        "median effect, the share of universes significant in that direction (two-sided "
        "p < .05) and Stouffer's Z, each against the null of sign flips shared by all "
        "universes.",
        "",
    ]
    rows = []
    for measure in PAPER_MEASURES:
        test = results.joint_test[measure]
        rows.append(
            [
                measure_name(measure),
                number(test.median_effect.observed),
                p_value(test.median_effect.p),
                number(test.share_significant.observed),
                p_value(test.share_significant.p),
                number(test.stouffer_z.observed),
                p_value(test.stouffer_z.p),
            ]
        )
    resamples = results.joint_test[PAPER_MEASURES[0]].resamples
    lines += [
        table(
            [
                "measure",
                "median effect",
                "p (median)",
                "share significant",
                "p (share)",
                "Stouffer Z",
                "p (Z)",
            ],
            rows,
            [False, *[True] * 6],
        ),
        "",
        f"p-values from {resamples} sign-flip resamples: none is below "
        f"{1 / (resamples + 1):.2g}, the smallest such a test can give.",
        "",
    ]
    for measure in PAPER_MEASURES:
        lines += [f"![Specification curve, {measure_name(measure)}]({FIGURE_NAMES[measure]})", ""]
    return lines


def _regression(results: MultiverseResults) -> list[str]:
    lines = [
        "## What moves the effect",
        "",
        "Per measure, an OLS regression of the universes' human effects on the settings "
        "(each setting's base level the reference): each setting's share of the effect's "
        "variance across universes (type II sums of squares over the total), then the "
        "coefficients.",
        "",
    ]
    shares_rows = []
    for measure in PAPER_MEASURES:
        fit = results.regression[measure]
        if fit.variance_shares is None:
            continue
        shares_rows.append(
            [
                measure_name(measure),
                *(number(fit.variance_shares[axis], 3) for axis in fit.variance_shares),
                number(fit.r_squared, 3),
            ]
        )
    first = next(
        (results.regression[m] for m in PAPER_MEASURES if results.regression[m].variance_shares),
        None,
    )
    if first is None:
        return [*lines, "Too few universes for the regression (no residual degrees of freedom)."]
    axes = list(first.variance_shares)
    lines += [
        table(["measure", *axes, "R²"], shares_rows, [False, *[True] * (len(axes) + 1)]),
        "",
    ]
    for measure in PAPER_MEASURES:
        fit = results.regression[measure]
        rows = [
            [
                "intercept (base universe)" if c.axis is None else f"{c.axis} = {c.level}",
                number(c.estimate),
                interval(c.ci95_low, c.ci95_high),
                p_value(c.p),
            ]
            for c in fit.coefficients
        ]
        lines += [
            f"**{measure_name(measure)}** ({fit.universes} universes, "
            f"{int(fit.df_residual)} residual df):",
            "",
            table(["term", "estimate", "95% CI", "p"], rows, [False, True, False, True]),
            "",
        ]
    return lines


def _effects(results: MultiverseResults) -> dict[tuple[str | None, str], PairedDifference]:
    """Each universe's human effect on each measure, by ``(universe, measure)``."""
    return {(row.universe, row.measure): row for row in results.effects}


def universe_table(results: MultiverseResults) -> pd.DataFrame:
    """One row per universe: its settings, its verdicts and its human effect per measure."""
    effects = _effects(results)
    rows = []
    for universe in results.universes:
        row: dict[str, Any] = {"universe": universe.id, "base": universe.base}
        row |= {axis: universe.settings.get(axis) for axis in results.axes}
        row |= {claim: universe.claims[claim].reproduced for claim in PAPER_CLAIMS}
        for measure in PAPER_MEASURES:
            effect = effects[universe.id, measure]
            row |= {
                f"{measure}_effect": effect.mean_diff,
                f"{measure}_ci95_low": effect.ci95_low,
                f"{measure}_ci95_high": effect.ci95_high,
                f"{measure}_p": effect.p,
            }
        rows.append(row)
    return pd.DataFrame(rows)


def _universes(results: MultiverseResults) -> list[str]:
    effects = _effects(results)
    varied = _varied(results)
    rows = [
        [
            ("**base** " if universe.base else "")
            + ", ".join(f"{a} = {level_label(universe.settings.get(a), a)}" for a in varied),
            *("✅" if universe.claims[claim].reproduced else "❌" for claim in PAPER_CLAIMS),
            *(_effect(effects[universe.id, measure]) for measure in PAPER_MEASURES),
        ]
        for universe in results.universes
    ]
    return [
        "## Universes",
        "",
        table(
            [
                "settings",
                *PAPER_CLAIMS,
                *(f"{measure_name(m)} effect [95% CI]" for m in PAPER_MEASURES),
            ],
            rows,
            [False, *[False] * len(PAPER_CLAIMS), *[True] * len(PAPER_MEASURES)],
        ),
        "",
        "Every number of every universe (its ANOVA, cell means, etas and claim values) is in "
        "`results.json`; one row per universe in `universes.csv`.",
    ]


def render_markdown(results: MultiverseResults) -> str:
    """``report.md`` of a multiverse: every section, from the results alone."""
    sections = [
        _header(results),
        _claims(results),
        _holds(results),
        _curves(results),
        _regression(results),
        _universes(results),
    ]
    return document(sections)


def render_figures(results: MultiverseResults) -> dict[str, bytes]:
    """The specification curves, PNG and SVG, by file name."""
    varied = _varied(results)
    choices = pd.DataFrame(
        [
            {axis: level_label(u.settings.get(axis), axis) for axis in varied}
            for u in results.universes
        ],
        index=[u.id for u in results.universes],
    )
    return figures.draw_all(
        {
            FIGURE_NAMES[measure]: (
                figures.specification_curve,
                (
                    results.effects.filter(
                        lambda row, measure=measure: row.measure == measure
                    ).to_frame(),
                    choices,
                    measure,
                    results.base_universe,
                ),
            )
            for measure in PAPER_MEASURES
        }
    )


def write_multiverse_report(
    trials: Sequence[TrialRow],
    out_dir: Path | str,
    pipeline: Pipeline,
    *,
    run_id: str,
    provenance: Mapping[str, Any] | None = None,
    progress: Callable[[str], None] = lambda stage: None,
) -> MultiverseResults:
    """Analyse a multiverse run's trials and write its report directory.

    Writes ``report.md``, ``results.json`` (every number at full precision),
    ``universes.csv`` and a specification curve per measure (PNG and SVG) into ``out_dir``,
    and ``provenance`` (if given) as ``provenance.json``.

    Returns:
        The typed content of ``results.json``.

    Raises:
        UserError: a universe's design cannot be analysed, or the report cannot be written.
    """
    results = analyse_multiverse(trials, pipeline, run_id=run_id, progress=progress)
    progress("figures")
    write_report_directory(
        out_dir,
        markdown=render_markdown(results),
        results=msgspec.to_builtins(results),
        tables={"universes.csv": universe_table(results)},
        figures=render_figures(results),
        provenance=provenance,
    )
    return results
