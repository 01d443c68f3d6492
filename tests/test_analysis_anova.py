"""The repeated-measures ANOVA of any factorial design, against R (afex, car) and pingouin.

The R numbers are fixtures made by ``tests/fixtures/factorial/make_fixtures.R`` on its own
data (non-spherical by construction); pingouin covers one within factor with a between
factor, and two within factors without one.
"""

from __future__ import annotations

import math
from pathlib import Path

import mpmath
import numpy as np
import pandas as pd
import pingouin as pg
import pytest

from cirl_study.analysis.anova import AnovaEffect, contrasts, repeated_measures_anova
from cirl_study.analysis.statistics import holm, holm_log10, pairwise_differences
from cirl_study.analysis.tails import chi2_tail, f_tail, t_tail

FIXTURES = Path(__file__).parent / "fixtures" / "factorial"

DESIGNS = {
    "rm_human3": (["human"], None),
    "rm_human3_robot2": (["human", "robot"], None),
    "mixed_human3_robot2_group2": (["human", "robot"], "group"),
    "mixed_human4_group3": (["human"], "group"),
    "mixed_human2_robot2_group2": (["human", "robot"], "group"),
    "mixed_human3_group2_unbalanced": (["human"], "group"),
    "rm_human8": (["human"], None),
}

RTOL = 1e-9


def read_fixture(name: str) -> pd.DataFrame:
    return pd.read_csv(FIXTURES / name, keep_default_na=False, na_values=["NA"])


def by_factors(effect: str) -> frozenset[str]:
    return frozenset(effect.split(":"))


def exact_log10_tail(x: mpmath.mpf, a: mpmath.mpf, b: mpmath.mpf) -> float:
    """``log10 I_x(a, b)`` at 60 digits."""
    with mpmath.workdps(60):
        return float(mpmath.log10(mpmath.betainc(a, b, 0, x, regularized=True)))


def close(ours: float, theirs: float, rtol: float = RTOL) -> bool:
    return math.isclose(ours, theirs, rel_tol=rtol, abs_tol=1e-300)


@pytest.mark.parametrize("design", sorted(DESIGNS))
def test_the_anova_equals_afex_and_car(design: str) -> None:
    within, between = DESIGNS[design]
    data = read_fixture(f"{design}_data.csv")
    expected = read_fixture(f"{design}_anova.csv")
    # With unequal groups our within effects weight the group means by size: R's type 2.
    expected = expected[expected["type"] == expected["type"].min()]
    table = {
        by_factors(row.effect): row for row in repeated_measures_anova(data, "y", within, between)
    }
    assert set(table) == {by_factors(effect) for effect in expected["effect"]}
    for theirs in expected.itertuples():
        ours = table[by_factors(theirs.effect)]
        assert (ours.df1, ours.df2) == (theirs.df1, theirs.df2)
        for mine, reference in (
            (ours.SS, theirs.SS),
            (ours.SS / ours.np2 - ours.SS, theirs.error_SS),
            (ours.F, theirs.F),
            (ours.p, theirs.p),
            (ours.ges, theirs.ges),
            (ours.np2, theirs.pes),
        ):
            assert close(mine, reference), (design, theirs.effect, mine, reference)
        assert close(ours.log10_p, math.log10(theirs.p))
        if math.isnan(theirs.gg_eps):
            assert ours.sphericity is None
            continue
        sphericity = ours.sphericity
        assert sphericity is not None
        for mine, reference in (
            (sphericity.mauchly_w, theirs.mauchly_W),
            (sphericity.mauchly.p, theirs.mauchly_p),
            (sphericity.gg_epsilon, theirs.gg_eps),
            (sphericity.hf_epsilon, theirs.hf_eps),
            (sphericity.gg.p, theirs.p_gg),
            (sphericity.hf.p, theirs.p_hf),
        ):
            assert close(mine, reference, 1e-7), (design, theirs.effect, mine, reference)


def test_the_fixtures_exercise_the_corrections() -> None:
    """The R data are non-spherical: the corrections are tested where they bite."""
    epsilons = pd.concat(read_fixture(f"{d}_anova.csv") for d in DESIGNS)
    assert epsilons["gg_eps"].min() < 0.5
    assert (epsilons["hf_eps"] > 1).any() and (epsilons["hf_eps"] < 0.7).any()
    assert epsilons["mauchly_p"].min() < 1e-6


def test_one_within_factor_with_a_between_factor_equals_pingouin() -> None:
    data = read_fixture("mixed_human4_group3_data.csv")
    theirs = pg.mixed_anova(
        data=data, dv="y", within="human", between="group", subject="subject", correction=True
    ).set_index("Source")
    ours = {row.effect: row for row in repeated_measures_anova(data, "y", ["human"], "group")}
    for source, effect in (("group", "group"), ("human", "human"), ("Interaction", "human:group")):
        assert close(ours[effect].F, theirs.at[source, "F"])
        assert close(ours[effect].p, theirs.at[source, "p_unc"])
        assert close(ours[effect].np2, theirs.at[source, "np2"])
    assert close(ours["human"].sphericity.gg_epsilon, theirs.at["human", "eps"])
    assert close(ours["human"].sphericity.gg.p, theirs.at["human", "p_GG_corr"])


def test_two_within_factors_equal_pingouin() -> None:
    data = read_fixture("rm_human3_robot2_data.csv")
    theirs = pg.rm_anova(
        data=data, dv="y", within=["human", "robot"], subject="subject", correction=True
    ).set_index("Source")
    ours = {row.effect: row for row in repeated_measures_anova(data, "y", ["human", "robot"])}
    for source, effect in (
        ("human", "human"),
        ("robot", "robot"),
        ("human * robot", "human:robot"),
    ):
        assert close(ours[effect].F, theirs.at[source, "F"])
        assert close(ours[effect].p, theirs.at[source, "p_unc"])
        assert close(ours[effect].ges, theirs.at[source, "ng2"])


def test_an_effect_too_strong_for_doubles_keeps_its_log10_p() -> None:
    rng = np.random.default_rng(3)
    rows = [
        {"subject": s, "h": h, "y": 1000.0 * h + rng.normal()} for s in range(400) for h in range(3)
    ]
    (effect,) = repeated_measures_anova(pd.DataFrame(rows), "y", ["h"])
    assert effect.p == 0.0
    with mpmath.workdps(60):
        x = mpmath.mpf(effect.df2) / (effect.df2 + effect.df1 * mpmath.mpf(effect.F))
        exact = exact_log10_tail(x, mpmath.mpf(effect.df2) / 2, mpmath.mpf(effect.df1) / 2)
    assert effect.log10_p < -308
    assert close(effect.log10_p, exact, 1e-12)


@pytest.mark.parametrize(
    ("f_value", "df1", "df2"),
    [(4.0, 1, 10), (1e4, 2, 30), (1e6, 1, 1000), (3000.0, 3, 1996), (1e200, 2, 5), (2e3, 1, 998)],
)
def test_the_f_tail_equals_mpmath_in_both_branches(f_value: float, df1: int, df2: int) -> None:
    with mpmath.workdps(60):
        x = mpmath.mpf(df2) / (df2 + df1 * mpmath.mpf(f_value))
        exact = exact_log10_tail(x, mpmath.mpf(df2) / 2, mpmath.mpf(df1) / 2)
    assert close(f_tail(f_value, df1, df2)[1], exact, 1e-13)


@pytest.mark.parametrize(("t_value", "df"), [(2.0, 10), (40.0, 499), (-60.0, 999), (1e170, 3)])
def test_the_t_tail_equals_mpmath(t_value: float, df: int) -> None:
    with mpmath.workdps(60):
        x = mpmath.mpf(df) / (df + mpmath.mpf(t_value) ** 2)
        exact = exact_log10_tail(x, mpmath.mpf(df) / 2, mpmath.mpf(1) / 2)
    assert close(t_tail(t_value, df)[1], exact, 1e-13)


def test_the_contrasts_are_orthonormal() -> None:
    for levels in range(2, 9):
        basis = contrasts(levels)
        assert np.allclose(basis.T @ basis, np.eye(levels - 1))
        assert np.allclose(basis.sum(axis=0), 0.0)


def test_an_incomplete_subject_is_refused() -> None:
    data = read_fixture("rm_human3_data.csv")
    with pytest.raises(ValueError, match="exactly one observation in every within cell"):
        repeated_measures_anova(data.iloc[1:], "y", ["human"])
    with pytest.raises(ValueError, match="two levels or more"):
        repeated_measures_anova(data[data["human"] == "h1"], "y", ["human"])


def test_rows_are_typed() -> None:
    data = read_fixture("rm_human3_data.csv")
    (row,) = repeated_measures_anova(data, "y", ["human"])
    assert isinstance(row, AnovaEffect)
    with pytest.raises(AttributeError):
        row.F = 0.0  # type: ignore[misc]


def as_study_columns(data: pd.DataFrame) -> pd.DataFrame:
    """A fixture's factors under the trial table's names: human -> human, group ->
    num_features (g1 -> 1, ...), a constant robot or feature level where the design has none."""
    frame = data.rename(columns={"human": "human"})
    if "robot" not in frame:
        frame["robot"] = "r"
    frame["num_features"] = frame["group"].str[1:].astype(int) if "group" in frame else 1
    return frame


@pytest.mark.parametrize("design", sorted(DESIGNS))
def test_pairwise_comparisons_equal_r_paired_t_tests_with_holm(design: str) -> None:
    frame = as_study_columns(read_fixture(f"{design}_data.csv"))
    expected = read_fixture(f"{design}_paired.csv")
    for factor, column in (("human", "human"), ("robot", "robot")):
        theirs = expected[expected["factor"] == factor]
        if theirs.empty:
            continue
        levels = sorted(frame[column].unique())
        ours = pairwise_differences(frame, "y", column, levels)
        assert len(ours) == len(theirs)
        found = {}
        for row in ours:
            cell = {"robot": row.robot, "human": row.human, "group": f"g{row.num_features}"}
            found[(row.level_a, row.level_b, frozenset(cell.items()))] = row
        for reference in theirs.itertuples():
            by = dict(part.split("=") for part in reference.by.split(",") if part)
            matches = [
                row
                for (a, b, cell), row in found.items()
                if (a, b) == (reference.level_a, reference.level_b)
                and all(dict(cell)[name] == by[name] for name in by)
            ]
            assert len(matches) == 1, (design, reference)
            (row,) = matches
            assert row.n == reference.n and row.df == reference.df
            for mine, value in (
                (row.mean_diff, reference.mean_diff),
                (row.t, reference.t),
                (row.p, reference.p),
                (10**row.log10_p, reference.p),
                (row.ci95_low, reference.ci_low),
                (row.ci95_high, reference.ci_high),
                (row.p_holm, reference.p_holm),
            ):
                assert close(mine, value, 1e-9), (design, reference, mine, value)


def test_pairwise_comparisons_equal_pingouin() -> None:
    data = read_fixture("rm_human3_robot2_data.csv")
    frame = as_study_columns(data)
    ours = pairwise_differences(frame, "y", "human", ["h1", "h2", "h3"])
    theirs = pg.pairwise_tests(
        data=data, dv="y", within=["robot", "human"], subject="subject", padjust="none"
    )
    theirs = theirs[theirs["robot"].isin(["r1", "r2"])]
    for row in ours:
        match = theirs[
            (theirs["robot"] == row.robot)
            & (theirs["A"] == row.level_a)
            & (theirs["B"] == row.level_b)
        ]
        assert close(row.t, float(match["T"].iloc[0]))
        assert close(row.p, float(match["p_unc"].iloc[0]), 1e-9)


def test_holm_in_log_space_equals_holm_where_p_is_a_double() -> None:
    rng = np.random.default_rng(5)
    p = rng.uniform(0, 0.2, 40) ** 3
    assert np.allclose(10 ** holm_log10(np.log10(p)), holm(p), rtol=1e-12)
    tiny = holm_log10(np.array([-600.0, -400.0, np.nan, -2.0]))
    assert tiny[0] == pytest.approx(-600 + np.log10(3))
    assert np.isnan(tiny[2]) and tiny[3] == pytest.approx(-2.0)


@pytest.mark.parametrize(("statistic", "df"), [(3.84, 1), (500.0, 14), (5000.0, 14), (1e5, 10)])
def test_the_chi2_tail_equals_mpmath(statistic: float, df: int) -> None:
    with mpmath.workdps(60):
        exact = float(
            mpmath.log10(
                mpmath.gammainc(mpmath.mpf(df) / 2, mpmath.mpf(statistic) / 2, regularized=True)
            )
        )
    assert close(chi2_tail(statistic, df)[1], exact, 1e-13)


def test_mauchly_is_undefined_with_fewer_error_degrees_of_freedom_than_contrasts() -> None:
    """Four subjects, five levels: the SSCP matrix of the four contrasts has rank 3."""
    rng = np.random.default_rng(1)
    rows = [{"subject": s, "h": h, "y": rng.normal()} for s in range(4) for h in range(5)]
    (effect,) = repeated_measures_anova(pd.DataFrame(rows), "y", ["h"])
    sphericity = effect.sphericity
    assert sphericity.mauchly_w is None and sphericity.mauchly.p is None
    assert 1 / 4 <= sphericity.gg_epsilon <= 1 and math.isfinite(sphericity.gg.p)


@pytest.mark.parametrize("design", sorted(DESIGNS))
def test_pairwise_differences_are_emmeans_contrasts(design: str) -> None:
    """emmeans' simple contrasts (multivariate model) estimate the same differences; without a
    between factor its error is the pair's own, so its t, df and p are the paired t-test's."""
    frame = as_study_columns(read_fixture(f"{design}_data.csv"))
    expected = read_fixture(f"{design}_pairwise.csv")
    within_only = "group" not in read_fixture(f"{design}_data.csv")
    checked = 0
    for factor, column in (("human", "human"), ("robot", "robot")):
        theirs = expected[(expected["factor"] == factor) & (expected["by"] != "")]
        if factor == "human" and theirs.empty:  # one within factor: the marginal is the simple
            theirs = expected[expected["factor"] == factor]
        if theirs.empty:
            continue
        ours = pairwise_differences(frame, "y", column, sorted(frame[column].unique()))
        for reference in theirs.itertuples():
            by = dict(part.split("=") for part in reference.by.split(",") if part)
            (row,) = [
                r
                for r in ours
                if (r.level_a, r.level_b) == (reference.level_a, reference.level_b)
                and by.get("robot", r.robot) == r.robot
                and by.get("human", r.human) == r.human
                and by.get("group", f"g{r.num_features}") == f"g{r.num_features}"
            ]
            assert close(row.mean_diff, reference.estimate)
            if within_only:
                assert row.df == reference.df
                assert close(row.t, reference.t) and close(row.p, reference.p_unadjusted)
            checked += 1
    assert checked >= 3


@pytest.mark.parametrize("humans", [("a", "b"), ("a", "b", "c")])
def test_an_effect_without_any_variance_is_undefined_not_an_error(humans) -> None:
    """A human identical to another (the best response at eta -> 0 is the expert): the
    within effect and its error are both 0, so F and the effect sizes are 0 / 0."""
    rows = [
        {"subject": f"s{s}", "human": h, "group": "g1" if s < 3 else "g2", "y": float(s)}
        for s in range(6)
        for h in humans
    ]
    effects = {
        r.effect: r for r in repeated_measures_anova(pd.DataFrame(rows), "y", ["human"], "group")
    }
    assert pytest.approx(13.5) == effects["group"].F and effects["group"].np2 > 0
    for name in ("human", "human:group"):
        row = effects[name]
        assert row.F is None and row.p is None and row.np2 is None
        assert row.SS == 0 and row.ges == 0
