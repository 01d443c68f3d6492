"""The repeated-measures ANOVA of any factorial design, against R (afex, car) and pingouin.

The R numbers are fixtures made by ``tests/fixtures/factorial/make_fixtures.R`` on its own
data (non-spherical by construction), type II and type III where the cells are unequal;
pingouin covers one within factor with a between factor, and two within factors without one.
"""

from __future__ import annotations

import itertools
import math
from fractions import Fraction
from pathlib import Path

import mpmath
import msgspec
import numpy as np
import pandas as pd
import pingouin as pg
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cirl_study.analysis.report.study_sections import anova_table
from cirl_study.analysis.results.per_measure import plain
from cirl_study.analysis.results.types import Sphericity
from cirl_study.analysis.statistics.anova import (
    NO_ERROR_VARIANCE,
    SINGULAR,
    TOO_FEW_SUBJECTS,
    AnovaEffect,
    contrasts,
    repeated_measures_anova,
)
from cirl_study.analysis.statistics.procedures import holm, holm_log10, pairwise_differences
from cirl_study.analysis.statistics.tails import chi2_tail, f_tail, t_tail

FIXTURES = Path(__file__).parent / "fixtures" / "factorial"

DESIGNS = {
    "rm_human3": (["human"], []),
    "rm_human3_robot2": (["human", "robot"], []),
    "mixed_human3_robot2_group2": (["human", "robot"], ["group"]),
    "mixed_human4_group3": (["human"], ["group"]),
    "mixed_human2_robot2_group2": (["human", "robot"], ["group"]),
    "mixed_human3_group2_unbalanced": (["human"], ["group"]),
    "rm_human8": (["human"], []),
    "mixed_human3_group2_cohort2_unbalanced": (["human"], ["group", "cohort"]),
    "mixed_human2_robot2_group2_cohort3_unbalanced": (["human", "robot"], ["group", "cohort"]),
    "mixed_human3_group2_cohort2_site2_unbalanced": (["human"], ["group", "cohort", "site"]),
}
"""Each design's within and between factors; R's comparisons (the ``_pairwise`` and ``_paired``
fixtures) only for those with one between factor at most, the study's design."""

COMPARED = sorted(design for design, (_, between) in DESIGNS.items() if len(between) <= 1)

RTOL = 1e-10


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


def balanced(data: pd.DataFrame, between: list[str]) -> bool:
    """Whether every between cell of ``data`` holds as many subjects."""
    if not between:
        return True
    return data.groupby(between)["subject"].nunique().nunique() == 1


@pytest.mark.parametrize("sums_of_squares", [2, 3])
@pytest.mark.parametrize("design", sorted(DESIGNS))
def test_the_anova_equals_afex_and_car(design: str, sums_of_squares: int) -> None:
    within, between = DESIGNS[design]
    data = read_fixture(f"{design}_data.csv")
    expected = read_fixture(f"{design}_anova.csv")
    if sums_of_squares not in set(expected["type"]):  # R's type 3 serves where the types agree
        assert balanced(data, between) and set(expected["type"]) == {3}
        sums_of_squares_in_r = 3
    else:
        sums_of_squares_in_r = sums_of_squares
    expected = expected[expected["type"] == sums_of_squares_in_r]
    table = {
        by_factors(row.effect): row
        for row in repeated_measures_anova(
            data, "y", within, between, sums_of_squares=sums_of_squares
        )
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
            assert close(mine, reference), (design, theirs.effect, mine, reference)


def test_effects_are_named_and_ordered_by_stratum_then_term() -> None:
    data = read_fixture("mixed_human3_group2_cohort2_unbalanced_data.csv")
    table = repeated_measures_anova(data, "y", ["human"], ["group", "cohort"])
    assert [row.effect for row in table] == [
        "group", "cohort", "group:cohort",
        "human", "human:group", "human:cohort", "human:group:cohort",
    ]  # fmt: skip


def _formulas_of_one_between_factor(
    frame: pd.DataFrame, within: list[str], levels: list[int]
) -> tuple[list[tuple[str, int, int, float, float]], float]:
    """``(effect, df1, df2, SS, error SS)`` of every row by the formulas of one between factor
    ``group`` (``N |zbar|^2``, ``sum_g n_g |zbar_g - zbar|^2``, ``tr E_T``), in the arithmetic
    the ANOVA used before it took several between factors, and the sum of the error terms."""
    ordered = frame.sort_values(["subject", *within])["y"].to_numpy()
    y = ordered.reshape(frame["subject"].nunique(), -1)
    group_of = frame.groupby("subject")["group"].first().sort_index()
    groups = group_of.map({g: i for i, g in enumerate(sorted(group_of.unique()))}).to_numpy()
    sizes = np.bincount(groups).astype(np.float64)
    count, subjects = len(sizes), len(y)
    rows, errors = [], []
    for size in range(len(within) + 1):
        for chosen in itertools.combinations(range(len(within)), size):
            matrix = np.ones((1, 1))
            for i, n in enumerate(levels):
                part = contrasts(n) if i in chosen else np.full((n, 1), 1 / math.sqrt(n))
                matrix = np.kron(matrix, part)
            z = y @ matrix
            means = np.zeros((count, z.shape[1]))
            np.add.at(means, groups, z)
            means /= sizes[:, None]
            grand = z.mean(axis=0)
            residual = z - means[groups]
            error = float(np.trace(residual.T @ residual))
            errors.append(error)
            d, df2 = z.shape[1], (subjects - count) * z.shape[1]
            name = ":".join(within[i] for i in chosen)
            if chosen:
                rows.append((name, d, df2, float(subjects * grand @ grand), error))
            if count > 1:
                between = float(sizes @ np.sum((means - grand) ** 2, axis=1))
                label = f"{name}:group" if chosen else "group"
                rows.append((label, (count - 1) * d, df2, between, error))
    return rows, sum(errors)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    sizes=st.lists(st.integers(1, 6), min_size=1, max_size=4).filter(lambda n: sum(n) > len(n)),
    levels=st.lists(st.integers(2, 4), max_size=2),
    offset=st.sampled_from([0.0, 1e3, 1e8]),
)
def test_one_between_factor_keeps_its_numbers_exactly(
    seed: int, sizes: list[int], levels: list[int], offset: float
) -> None:
    """With one between factor (of any number of groups, of any sizes) every row, its name,
    order, degrees of freedom and numbers, is the one-factor formulas' to the last bit."""
    rng = np.random.default_rng(seed)
    within = ["human", "robot"][: len(levels)]
    rows = []
    for g, n in enumerate(sizes):
        for s in range(n):
            base = offset + rng.normal()
            for cell in np.ndindex(*levels):
                value = base + rng.normal() + 0.4 * g * sum(cell)
                cells = dict(zip(within, cell, strict=True))
                rows.append({"subject": f"{g}-{s}", "group": f"g{g}", "y": value, **cells})
    frame = pd.DataFrame(rows)
    table = repeated_measures_anova(frame, "y", within, ["group"])
    expected, error_total = _formulas_of_one_between_factor(frame, within, levels)
    assert [(row.effect, row.df1, row.df2) for row in table] == [e[:3] for e in expected]
    for row, (_, df1, df2, ss, error) in zip(table, expected, strict=True):
        ours = (row.SS, row.MS, row.F, row.np2, row.ges)
        f_value = (ss / df1) / (error / df2)
        assert ours == (ss, ss / df1, f_value, ss / (ss + error), ss / (ss + error_total))


def _balanced(seed: int) -> pd.DataFrame:
    """Three humans, two by three between cells of four subjects each."""
    rng = np.random.default_rng(seed)
    rows = []
    for g, c, s in itertools.product(range(2), range(3), range(4)):
        base = rng.normal() + g - c
        for h in range(3):
            value = base + rng.normal(0, 1 + h) + 0.5 * h * (g + c)
            rows.append({"subject": f"{g}{c}{s}", "g": g, "c": c, "h": h, "y": value})
    return pd.DataFrame(rows)


@pytest.mark.parametrize("between", [[], ["g"], ["g", "c"]])
def test_type_2_equals_type_3_in_a_balanced_design(between: list[str]) -> None:
    frame = _balanced(11)
    second, third = (
        repeated_measures_anova(frame, "y", ["h"], between, sums_of_squares=kind) for kind in (2, 3)
    )
    assert [row.effect for row in second] == [row.effect for row in third]
    for a, b in zip(second, third, strict=True):
        assert (a.df1, a.df2) == (b.df1, b.df2)
        for mine, theirs in ((a.SS, b.SS), (a.F, b.F), (a.p, b.p), (a.ges, b.ges)):
            assert close(mine, theirs, 1e-12), (a.effect, mine, theirs)
        if a.sphericity is None:
            assert b.sphericity is None
            continue
        ours, theirs = a.sphericity, b.sphericity  # one error matrix: the same epsilons
        assert (ours.mauchly_w, ours.gg_epsilon, ours.hf_epsilon) == (
            theirs.mauchly_w,
            theirs.gg_epsilon,
            theirs.hf_epsilon,
        )
        assert close(ours.gg.p, theirs.gg.p, 1e-12) and close(ours.hf.p, theirs.hf.p, 1e-12)


def test_an_empty_between_cell_is_refused() -> None:
    data = read_fixture("mixed_human3_group2_cohort2_unbalanced_data.csv")
    missing = (data["group"] == "g2") & (data["cohort"] == "c1")
    with pytest.raises(ValueError, match="no subject in the between cell group=g2, cohort=c1"):
        repeated_measures_anova(data[~missing], "y", ["human"], ["group", "cohort"])


def test_a_subject_in_two_between_cells_is_refused() -> None:
    data = read_fixture("mixed_human3_group2_cohort2_unbalanced_data.csv")
    data.loc[data.index[0], "cohort"] = "c2" if data["cohort"].iloc[0] == "c1" else "c1"
    with pytest.raises(ValueError, match="a subject lies in two levels of cohort"):
        repeated_measures_anova(data, "y", ["human"], ["group", "cohort"])


def test_the_between_factors_are_a_sequence_and_the_type_2_or_3() -> None:
    data = read_fixture("mixed_human3_group2_unbalanced_data.csv")
    with pytest.raises(TypeError, match="not a string"):
        repeated_measures_anova(data, "y", ["human"], "group")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="2 or 3"):
        repeated_measures_anova(data, "y", ["human"], ["group"], sums_of_squares=1)  # type: ignore[arg-type]


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
    ours = {row.effect: row for row in repeated_measures_anova(data, "y", ["human"], ["group"])}
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


@pytest.mark.parametrize("design", COMPARED)
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


def _absent(sphericity: Sphericity) -> bool:
    """Whether none of Mauchly's test, the epsilons and the corrected p-values is reported."""
    numbers = [sphericity.mauchly_w, sphericity.gg_epsilon, sphericity.hf_epsilon]
    numbers += [sphericity.mauchly.p, sphericity.mauchly.log10_p, sphericity.gg.p]
    numbers += [sphericity.gg.log10_p, sphericity.hf.p, sphericity.hf.log10_p]
    return all(value is None for value in numbers)


def test_sphericity_is_not_reported_with_fewer_error_degrees_of_freedom_than_contrasts() -> None:
    """Four subjects, five levels: the SSCP matrix of the four contrasts has rank 3 whatever
    the data, and eps_GG <= n / d = 3 / 4 measures the sample size: nothing is reported, the
    uncorrected F test is."""
    rng = np.random.default_rng(1)
    rows = [{"subject": s, "h": h, "y": rng.normal()} for s in range(4) for h in range(5)]
    (effect,) = repeated_measures_anova(pd.DataFrame(rows), "y", ["h"])
    assert _absent(effect.sphericity) and effect.sphericity.reason == TOO_FEW_SUBJECTS
    assert math.isfinite(effect.F) and math.isfinite(effect.log10_p)


def _exact_epsilons(frame: pd.DataFrame, levels: int) -> tuple[Fraction, int]:
    """Box's epsilon of one within factor of ``levels`` levels, in exact arithmetic, and the
    rank of its error SSCP matrix: from the centred cross products ``S`` of the subjects' rows
    (the doubles are exact rationals) and the projection ``Q = I - J / C`` onto the contrasts,
    ``eps = tr(Q S)^2 / (d tr((Q S)^2))``, which no orthonormal basis of the contrasts
    changes; the rank is that of ``Q S Q``."""
    wide = frame.pivot(index="subject", columns="h", values="y").sort_index()
    rows = [[Fraction(value) for value in row] for row in wide.to_numpy().tolist()]
    means = [sum(column, Fraction(0)) / len(rows) for column in zip(*rows, strict=True)]
    centred = [[value - mean for value, mean in zip(row, means, strict=True)] for row in rows]
    cells = range(levels)
    s = [[sum((r[i] * r[j] for r in centred), Fraction(0)) for j in cells] for i in cells]
    q = [[Fraction(int(i == j)) - Fraction(1, levels) for j in cells] for i in cells]

    def product(a: list, b: list) -> list:
        return [
            [sum((a[i][k] * b[k][j] for k in cells), Fraction(0)) for j in cells] for i in cells
        ]

    qs = product(q, s)
    d = levels - 1
    trace = sum(qs[i][i] for i in cells)
    epsilon = trace**2 / (d * sum(product(qs, qs)[i][i] for i in cells))
    return epsilon, _rank(product(qs, q))


def _rank(matrix: list[list[Fraction]]) -> int:
    """The rank of a matrix of fractions, by Gaussian elimination."""
    rows = [row[:] for row in matrix]
    rank = 0
    for column in range(len(rows[0])):
        pivot = next((i for i in range(rank, len(rows)) if rows[i][column] != 0), None)
        if pivot is None:
            continue
        rows[rank], rows[pivot] = rows[pivot], rows[rank]
        for i in range(len(rows)):
            if i != rank and rows[i][column] != 0:
                factor = rows[i][column] / rows[rank][column]
                rows[i] = [a - factor * b for a, b in zip(rows[i], rows[rank], strict=True)]
        rank += 1
    return rank


def test_a_singular_error_matrix_has_w_0_and_no_mauchly_p() -> None:
    """A third human scored exactly as the first by every subject: the error matrix of the
    two contrasts has rank 1, so W = 0 exactly (not the rounding's 1e-16) and its chi-square
    statistic is infinite: Mauchly's p is not reported. Box's epsilon, defined for any
    covariance, is, as exact arithmetic has it."""
    rng = np.random.default_rng(7)
    rows = []
    for s in range(10):
        a, b = rng.normal(0.3, 0.1, 2)
        rows += [{"subject": s, "h": h, "y": float(v)} for h, v in (("a", a), ("b", b), ("c", a))]
    frame = pd.DataFrame(rows)
    (effect,) = repeated_measures_anova(frame, "y", ["h"])
    sphericity = effect.sphericity
    epsilon, rank = _exact_epsilons(frame, 3)
    assert rank == 1
    assert sphericity.mauchly_w == 0.0 and sphericity.reason == SINGULAR
    assert sphericity.mauchly.p is None and sphericity.mauchly.log10_p is None
    assert close(sphericity.gg_epsilon, float(epsilon), 1e-12)
    n, d = 9, 2
    hf = ((n + 1) * d * epsilon - 2) / (d * (n - d * epsilon))
    assert close(sphericity.hf_epsilon, float(hf), 1e-12)
    gg_p = f_tail(effect.F, float(epsilon) * 2, float(epsilon) * 18)[1]
    assert close(sphericity.gg.log10_p, gg_p, 1e-12)


def test_a_nearly_singular_error_matrix_keeps_its_test() -> None:
    """The same design with the third human off the first by 1e-6: the error matrix is
    non-singular in exact arithmetic, far above the rounding floor, and Mauchly's W is its
    own, as exact arithmetic has it (through the eigenvalues of the exact matrix)."""
    rng = np.random.default_rng(7)
    rows = []
    for s in range(10):
        a, b = rng.normal(0.3, 0.1, 2)
        c = a + 1e-6 * rng.normal()
        rows += [{"subject": s, "h": h, "y": float(v)} for h, v in (("a", a), ("b", b), ("c", c))]
    frame = pd.DataFrame(rows)
    (effect,) = repeated_measures_anova(frame, "y", ["h"])
    sphericity = effect.sphericity
    assert sphericity.reason is None and 0 < sphericity.mauchly_w < 1e-8
    with mpmath.workdps(60):
        wide = frame.pivot(index="subject", columns="h", values="y").sort_index()
        y = mpmath.matrix([[mpmath.mpf(v) for v in row] for row in wide.to_numpy().tolist()])
        centred = y - mpmath.ones(10, 1) * (mpmath.ones(1, 10) * y) / 10
        basis = mpmath.matrix(
            [[1 / mpmath.sqrt(2), 1 / mpmath.sqrt(6)], [-1 / mpmath.sqrt(2), 1 / mpmath.sqrt(6)],
             [0, -2 / mpmath.sqrt(6)]]
        )  # fmt: skip
        z = centred * basis
        e = z.T * z
        w = mpmath.det(e) / (e[0, 0] + e[1, 1]) ** 2 * 4
    assert close(sphericity.mauchly_w, float(w), 1e-6)


def test_a_stratum_whose_error_is_rounding_reports_no_sphericity() -> None:
    """Every subject scores the two humans alike: the human x robot stratum's effect and
    error are 0 in exact arithmetic, rounding in doubles. Its F is 0 / 0, and neither
    Mauchly's test nor the epsilons are computed from that rounding; the robot stratum keeps
    its own."""
    rng = np.random.default_rng(0)
    rows = []
    for s in range(12):
        scores = rng.normal(0.3, 0.1, 3)
        rows += [
            {"subject": s, "human": h, "robot": r, "y": float(scores[r])}
            for h in ("a", "b")
            for r in range(3)
        ]
    frame = pd.DataFrame(rows)
    y = frame.sort_values(["subject", "human", "robot"])["y"].to_numpy().reshape(12, 6)
    noise = y @ np.kron(contrasts(2), contrasts(3))
    assert np.any(noise != 0.0)  # the premise: the doubles leave rounding in the stratum
    analysed = frame.rename(columns={"y": "regret"})  # a registered measure, for the table
    effects = {
        row.effect: row for row in repeated_measures_anova(analysed, "regret", ["human", "robot"])
    }
    crossed = effects["human:robot"]
    assert crossed.SS == 0 and crossed.F is None
    assert _absent(crossed.sphericity) and crossed.sphericity.reason == NO_ERROR_VARIANCE
    assert effects["robot"].sphericity.reason is None
    epsilon, _ = _exact_epsilons(frame[frame["human"] == "a"].rename(columns={"robot": "h"}), 3)
    assert close(effects["robot"].sphericity.gg_epsilon, float(epsilon), 1e-12)
    typed = msgspec.convert(plain(msgspec.to_builtins(crossed)), AnovaEffect)
    cells = anova_table([effects["robot"], typed]).splitlines()[-1].split(" | ")
    assert cells[5:8] == ["–", "–", "–"]


@pytest.mark.parametrize("design", COMPARED)
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
        r.effect: r for r in repeated_measures_anova(pd.DataFrame(rows), "y", ["human"], ["group"])
    }
    assert pytest.approx(13.5) == effects["group"].F and effects["group"].np2 > 0
    for name in ("human", "human:group"):
        row = effects[name]
        assert row.F is None and row.p is None and row.np2 is None
        assert row.SS == 0 and row.ges == 0
