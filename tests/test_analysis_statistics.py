"""The statistical tests (cirl_study.analysis.statistics.procedures).

Two kinds of check: published reference values for datasets bundled with pingouin
(computed by JASP, JAMOVI and R, as quoted in pingouin's own test-suite), and an
independent computation of the mixed ANOVA for two humans from t-tests on the
per-subject differences and means.
"""

from __future__ import annotations

import math
import re
import warnings

import msgspec
import numpy as np
import pandas as pd
import pingouin as pg
import pytest
from analysis_fixtures import rows, synthetic_records
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from cirl_study.analysis.results.types import CellMean
from cirl_study.analysis.statistics import procedures as statistics
from cirl_study.analysis.statistics.anova import repeated_measures_anova
from cirl_study.analysis.table import trial_table

ANOVA_ORDER = ["num_features", "human", "human:num_features"]
"""The references' row order: between, within, interaction (ours too)."""


def mixed_anova(data: pd.DataFrame) -> pd.DataFrame:
    """The ANOVA of ``score``: ``human`` within subjects, ``num_features`` between."""
    effects = repeated_measures_anova(data, "score", ["human"], ["num_features"])
    return pd.DataFrame([msgspec.structs.asdict(row) for row in effects]).set_index("effect")


def _as_study(data: pd.DataFrame, score: str, within: str, between: str, subject: str):
    return data.rename(
        columns={score: "score", within: "human", between: "num_features", subject: "subject"}
    )


def test_mixed_anova_matches_jasp_and_jamovi_on_the_balanced_dataset():
    # pingouin's test_parametric: SS, df, F and np2 from JASP; ges from JAMOVI.
    data = _as_study(pg.read_dataset("mixed_anova"), "Scores", "Time", "Group", "Subject")
    anova = mixed_anova(data).loc[ANOVA_ORDER]
    np.testing.assert_array_equal(anova["df1"], [1, 2, 2])
    np.testing.assert_array_equal(anova["df2"], [58, 116, 116])
    np.testing.assert_allclose(anova["SS"], [5.45996, 7.62843, 5.16719], atol=5e-6)
    np.testing.assert_allclose(anova["F"], [5.05171, 4.02739, 2.72800], atol=5e-6)
    np.testing.assert_allclose(anova["np2"], [0.08012, 0.06493, 0.04492], atol=5e-6)
    np.testing.assert_allclose(anova["ges"], [0.03067, 0.04234, 0.02908], atol=5e-6)


def test_mixed_anova_matches_jasp_on_the_unbalanced_dataset():
    # Three groups of unequal size, four time points (JASP, type II).
    data = _as_study(
        pg.read_dataset("mixed_anova_unbalanced"), "Scores", "Time", "Group", "Subject"
    )
    anova = mixed_anova(data).loc[ANOVA_ORDER]
    np.testing.assert_array_equal(anova["df1"], [2, 3, 6])
    np.testing.assert_array_equal(anova["df2"], [23, 69, 69])
    np.testing.assert_allclose(anova["F"], [2.3026, 1.7071, 0.8877], atol=5e-5)
    np.testing.assert_allclose(anova["p"], [0.1226, 0.1736, 0.5088], atol=5e-5)
    np.testing.assert_allclose(anova["np2"], [0.1668, 0.0691, 0.0717], atol=5e-5)
    np.testing.assert_allclose(anova["ges"], [0.0371, 0.0566, 0.0587], atol=5e-5)


def _two_human_study(sizes: tuple[int, int], seed: int) -> pd.DataFrame:
    """A random split-plot data set with feature levels 3 and 10 of the given sizes."""
    rng = np.random.default_rng(seed)
    rows = []
    for level, size, shift in ((3, sizes[0], 0.0), (10, sizes[1], rng.normal())):
        for index in range(size):
            person = rng.normal(shift, 1.0)
            for human, effect in (("expert", 0.0), ("best_response", rng.normal(-0.5, 0.3))):
                score = person + effect + rng.normal(0, 0.7)
                rows.append((f"{level}-{index}", level, human, score))
    return pd.DataFrame(rows, columns=["subject", "num_features", "human", "score"])


def _from_t_tests(data: pd.DataFrame) -> dict[str, dict[str, float]]:
    """F, p, np2 and ges of each effect from t-tests on per-subject differences and means.

    ``d = y_br - y_expert`` and ``m = (y_br + y_expert) / 2`` per subject. The interaction
    is the two-sample (pooled) t-test of ``d`` between the levels, the between effect
    the same on ``m``, and the human effect the test of ``mean(d) = 0`` against the
    pooled within-level variance of ``d``; each ``F = t^2``.
    """
    wide = data.pivot(index="subject", columns="human", values="score")
    level = data.groupby("subject")["num_features"].first().loc[wide.index]
    d = wide["best_response"] - wide["expert"]
    m = (wide["best_response"] + wide["expert"]) / 2
    n = len(d)
    low, high = (level == 3), (level == 10)
    within_d = d - d.groupby(level).transform("mean")
    within_m = m - m.groupby(level).transform("mean")
    t = {
        "human": d.mean() / np.sqrt((within_d**2).sum() / (n - 2) / n),
        "num_features": stats.ttest_ind(m[low], m[high]).statistic,
        "human:num_features": stats.ttest_ind(d[low], d[high]).statistic,
    }
    ss = {
        "human": n * d.mean() ** 2 / 2,
        "num_features": 2 * (m.groupby(level).transform("mean") - m.mean()).pow(2).sum(),
        "human:num_features": (d.groupby(level).transform("mean") - d.mean()).pow(2).sum() / 2,
    }
    ss_subjects, ss_residual = 2 * (within_m**2).sum(), (within_d**2).sum() / 2
    return {
        effect: {
            "F": t[effect] ** 2,
            "p": 2 * stats.t.sf(abs(t[effect]), n - 2),
            "np2": t[effect] ** 2 / (t[effect] ** 2 + n - 2),
            "ges": ss[effect] / (ss[effect] + ss_subjects + ss_residual),
        }
        for effect in ANOVA_ORDER
    }


@settings(max_examples=10, deadline=None)
@given(sizes=st.tuples(st.integers(3, 12), st.integers(3, 12)), seed=st.integers(0, 2**32 - 1))
def test_mixed_anova_equals_t_tests_on_differences_and_means(sizes, seed):
    data = _two_human_study(sizes, seed)
    anova = mixed_anova(data)
    expected = _from_t_tests(data)
    for effect in ANOVA_ORDER:
        assert anova.at[effect, "df1"] == 1
        assert anova.at[effect, "df2"] == sum(sizes) - 2
        for column in ("F", "p", "np2", "ges"):
            assert anova.at[effect, column] == pytest.approx(expected[effect][column], rel=1e-9)


@pytest.fixture(scope="module")
def main() -> pd.DataFrame:
    table = trial_table(rows(synthetic_records(subjects_per_level=9, lambdas=(1.0,), etas=(1.0,))))
    return table[table["block"] == "main"]


def test_simple_effects_are_paired_t_tests_with_holm_and_d_z(main):
    frame = statistics.simple_effects(main, "regret").to_frame().set_index("num_features")
    for level in (3, 10):
        wide = main[main["num_features"] == level].pivot(
            index="subject", columns="human", values="regret"
        )
        d = (wide["best_response"] - wide["expert"]).to_numpy()
        n, mean, sd = len(d), d.mean(), d.std(ddof=1)
        t = mean / (sd / np.sqrt(n))
        half = stats.t.ppf(0.975, n - 1) * sd / np.sqrt(n)
        row = frame.loc[level]
        assert row["t"] == pytest.approx(t) and row["df"] == n - 1
        assert row["p"] == pytest.approx(2 * stats.t.sf(abs(t), n - 1))
        assert row["d_z"] == pytest.approx(mean / sd) == pytest.approx(t / np.sqrt(n))
        assert (row["ci95_low"], row["ci95_high"]) == pytest.approx((mean - half, mean + half))
        assert row["boot_diff_low"] < mean < row["boot_diff_high"]
        assert row["boot_d_z_low"] < mean / sd < row["boot_d_z_high"]
    p = frame["p"].to_numpy()
    smaller = min(1.0, 2 * p.min())
    holm = np.where(p == p.min(), smaller, max(smaller, p.max()))
    np.testing.assert_allclose(frame["p_holm"], holm)
    again = statistics.simple_effects(main, "regret").to_frame().set_index("num_features")
    assert again.equals(frame)  # the bootstrap is seeded


def test_tukey_hsd_matches_r_tukeyhsd_on_the_penguins():
    # R: TukeyHSD(aov(body_mass_g ~ species * sex), which = "species:sex"), as quoted by
    # pingouin's test_pairwise. Species become feature levels 1-3; female < male sorts
    # like best_response < expert, so the cells keep R's order.
    penguins = pg.read_dataset("penguins").dropna(subset=["sex", "body_mass_g"])
    data = pd.DataFrame(
        {
            "num_features": penguins["species"].map({"Adelie": 1, "Chinstrap": 2, "Gentoo": 3}),
            "human": penguins["sex"].map({"female": "best_response", "male": "expert"}),
            "mass": penguins["body_mass_g"],
        }
    )
    tukey = statistics.tukey_hsd(data, "mass").to_frame()
    assert len(tukey) == 15
    assert tuple(tukey.loc[0, ["a_num_features", "a_human", "b_num_features", "b_human"]]) == (
        1,
        "best_response",
        1,
        "expert",
    )
    rows = [0, 1, 6, 9]
    np.testing.assert_allclose(
        tukey.loc[rows, "diff"], [-674.6575342, -158.3702659, 104.5225624, -411.7647059]
    )
    np.testing.assert_allclose(
        tukey.loc[rows, "p_tukey"], [0, 0.1376213087, 0.5812048336, 0.0000012196], atol=1e-8
    )


def test_tukey_hsd_is_pingouins_but_for_the_p_values():
    penguins = pg.read_dataset("penguins").dropna(subset=["sex"])
    data = pd.DataFrame(
        {
            "num_features": penguins["species"].map({"Adelie": 1, "Chinstrap": 2, "Gentoo": 3}),
            "human": penguins["sex"].map({"female": "best_response", "male": "expert"}),
            "mass": penguins["body_mass_g"],
        }
    )
    data.loc[data.index[::40], "mass"] = np.nan  # dropped, as pingouin drops them
    ours = statistics.tukey_hsd(data, "mass").to_frame()
    theirs = pg.pairwise_tukey(data=data, dv="mass", between=["num_features", "human"])
    assert list(zip(ours["a_num_features"], ours["a_human"], strict=True)) == list(theirs["A"])
    assert list(zip(ours["b_num_features"], ours["b_human"], strict=True)) == list(theirs["B"])
    for column, theirs_column in [("mean_a", "mean_A"), ("mean_b", "mean_B"), ("diff", "diff"),
                                  ("se", "se"), ("T", "T"), ("hedges", "hedges")]:  # fmt: skip
        np.testing.assert_allclose(ours[column], theirs[theirs_column], rtol=1e-13)
    # Where SciPy's 1 - CDF still has digits, the two p-values agree.
    shown = theirs["p_tukey"] > 1e-6
    np.testing.assert_allclose(ours["p_tukey"][shown], theirs["p_tukey"][shown], rtol=1e-6)


def test_wilcoxon_tests_the_paired_differences_per_level(main):
    frame = statistics.wilcoxon(main, "kl").to_frame().set_index("num_features")
    for level in (3, 10):
        wide = main[main["num_features"] == level].pivot(
            index="subject", columns="human", values="kl"
        )
        expected = stats.wilcoxon(wide["best_response"] - wide["expert"])
        assert frame.at[level, "W"] == expected.statistic
        assert frame.at[level, "p"] == pytest.approx(expected.pvalue)
        assert frame.at[level, "n"] == len(wide)


@settings(max_examples=25, deadline=None)
@given(
    n=st.integers(2, 300),
    seed=st.integers(0, 2**32 - 1),
    ties=st.booleans(),
)
def test_the_bootstrap_is_scipys_bca_in_linear_time(n, seed, ties):
    rng = np.random.default_rng(seed)
    d = rng.standard_t(3, n) * rng.uniform(0.1, 5) + rng.normal()
    if ties:
        d = np.round(d)
    got = statistics.bootstrap_mean_d_z(d)
    for name, statistic in (("mean", np.mean), ("d_z", statistics._d_z)):
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            expected = stats.bootstrap(
                (d,),
                statistic,
                n_resamples=statistics.BOOTSTRAP_RESAMPLES,
                confidence_level=statistics.CONFIDENCE,
                method="BCa",
                rng=np.random.default_rng(statistics.BOOTSTRAP_SEED),
            ).confidence_interval
        np.testing.assert_allclose(
            getattr(got, name),
            (expected.low, expected.high),
            rtol=1e-10,
            atol=1e-12,
            equal_nan=True,
        )


def test_the_bootstrap_batches_do_not_change_the_interval(monkeypatch):
    d = np.random.default_rng(5).normal(0.3, 1.0, 400)
    whole = statistics.bootstrap_mean_d_z(d)
    monkeypatch.setattr(statistics, "BOOTSTRAP_BATCH_ELEMENTS", 7 * 400 + 3)
    assert statistics.bootstrap_mean_d_z(d) == whole


@settings(max_examples=25, deadline=None)
@given(
    n=st.integers(2, 300),
    resamples=st.integers(1, 400),
    block=st.integers(1, 5000),
    seed=st.integers(0, 2**32 - 1),
    kind=st.sampled_from(["spread", "ties", "constant"]),
)
def test_the_resamples_reduced_in_blocks_are_numpys_mean_and_d_z_to_the_bit(
    n, resamples, block, seed, kind
):
    rng = np.random.default_rng(seed)
    d = {
        "spread": rng.normal(0.3, 2.0, n),
        "ties": rng.integers(-2, 3, n).astype(float),
        "constant": np.full(n, 0.7),
    }[kind]
    indices = rng.integers(0, n, (resamples, n))
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(statistics, "BOOTSTRAP_BLOCK_ELEMENTS", block)
        means, d_zs = statistics._resampled_mean_and_d_z(d, indices)
    np.testing.assert_array_equal(means, np.mean(d[indices], axis=-1))
    np.testing.assert_array_equal(d_zs, statistics._d_z(d[indices]))


def test_a_constant_difference_has_no_bootstrap_interval():
    intervals = statistics.bootstrap_mean_d_z(np.ones(12))
    assert all(math.isnan(v) for pair in intervals for v in pair)


@settings(max_examples=25, deadline=None)
@given(n=st.integers(6, 200), seed=st.integers(0, 2**32 - 1), decimals=st.integers(0, 2))
def test_wilcoxon_equals_pingouins(n, seed, decimals):
    rng = np.random.default_rng(seed)
    best = np.round(rng.normal(0.0, 1.0, n), decimals)
    expert = np.round(rng.normal(0.3, 1.0, n), decimals)
    if np.all(best == expert):
        return
    main = pd.DataFrame(
        {
            "subject": [f"s{i:03d}" for i in range(n)] * 2,
            "human": ["best_response"] * n + ["expert"] * n,
            "num_features": 3,
            "regret": np.concatenate([best, expert]),
        }
    )
    (row,) = statistics.wilcoxon(main, "regret")
    expected = pg.wilcoxon(best, expert).iloc[0]
    assert expected["W_val"] == row.W and row.p == expected["p_val"]
    assert row.rbc == pytest.approx(expected["RBC"], rel=1e-12, abs=1e-15)
    assert row.cles == expected["CLES"]


def test_group_means_use_the_t_interval():
    rows = pd.DataFrame({"g": ["a", "a", "a", "b", "c", "c"], "y": [1.0, 2.0, 4.0, 5.0, 2.0, 2.0]})
    frame = statistics.group_means(rows, "y", ["g"]).set_index("g")
    half = stats.t.ppf(0.975, 2) * np.std([1, 2, 4], ddof=1) / np.sqrt(3)
    assert frame.at["a", "mean"] == pytest.approx(7 / 3)
    assert frame.at["a", "ci95_low"] == pytest.approx(7 / 3 - half)
    assert frame.at["a", "ci95_high"] == pytest.approx(7 / 3 + half)
    assert frame.at["b", "n"] == 1 and np.isnan(frame.at["b", "ci95_low"])
    assert frame.at["c", "ci95_low"] == frame.at["c", "ci95_high"] == 2.0


def test_cronbach_alpha_matches_r_psych():
    # R: psych::alpha on pingouin's cronbach_alpha dataset: 0.592, 95% CI [0.195, 0.840].
    data = pg.read_dataset("cronbach_alpha").pivot(index="Subj", columns="Items", values="Scores")
    alpha = statistics.cronbach_alpha(data, "one row per subject")
    assert round(alpha.raw, 3) == 0.592
    assert [round(bound, 3) for bound in alpha.ci95] == [0.195, 0.840]
    assert alpha.n_rows == len(data) and alpha.n_items == data.shape[1]
    assert alpha.items == [str(item) for item in data.columns]


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), rows=st.integers(5, 40), k=st.integers(2, 5))
def test_cronbach_alpha_closed_forms(seed, rows, k):
    rng = np.random.default_rng(seed)
    items = pd.DataFrame(
        rng.normal(size=(rows, 1)) + rng.normal(size=(rows, k)) * rng.uniform(0.2, 3.0, size=k)
    )
    values = items.to_numpy()
    raw = k / (k - 1) * (1 - values.var(axis=0, ddof=1).sum() / values.sum(axis=1).var(ddof=1))
    correlations = np.corrcoef(values, rowvar=False)
    mean_r = correlations[np.triu_indices(k, 1)].mean()
    alpha = statistics.cronbach_alpha(items, "one row per observation")
    assert alpha.raw == pytest.approx(raw, rel=1e-9, abs=1e-12)
    assert alpha.standardised == pytest.approx(
        k * mean_r / (1 + (k - 1) * mean_r), rel=1e-9, abs=1e-12
    )
    low, high = alpha.ci95
    quantiles = stats.f.ppf([0.975, 0.025], rows - 1, (rows - 1) * (k - 1))
    assert (low, high) == pytest.approx(tuple(1 - (1 - raw) * quantiles))


def test_eta_means_are_the_best_responses_mean_regret_per_level_and_eta():
    # The choice of eta is cirl_study.study.eta_cv.choose_etas; here only the curve.
    cv = pd.DataFrame(
        {
            "human": ["best_response"] * 8 + ["expert"],
            "num_features": [3, 3, 3, 3, 10, 10, 10, 10, 3],
            "eta": [0.1, 0.1, 1.0, 1.0, 0.1, 0.1, 1.0, 1.0, np.nan],
            "regret": [1.0, 3.0, 1.5, 2.5, 1.0, 2.0, 0.5, 1.5, 0.0],
        }
    )
    means = statistics.eta_means(cv).to_frame()
    assert means[["num_features", "eta", "n", "mean"]].to_dict("list") == {
        "num_features": [3, 3, 10, 10],
        "eta": [0.1, 1.0, 0.1, 1.0],
        "n": [2, 2, 2, 2],
        "mean": [2.0, 2.0, 1.5, 1.0],
    }
    expected = statistics.group_means(cv.iloc[:8], "regret", ["num_features", "eta"])
    pd.testing.assert_frame_equal(means, expected, check_dtype=False)


def test_group_mean_rows_are_the_group_means_typed():
    table = trial_table(rows(synthetic_records(subjects_per_level=3, lambdas=(0.1, 1.0, 10.0))))
    sweep = table[table["block"] == "lambda_sweep"]
    by = ["rationality", "num_features", "human", "robot"]
    means = statistics.group_mean_rows(sweep, "kl", by, CellMean)
    assert len(means) == 3 * 2 * 2 and {row.n for row in means} == {3}
    assert [row.rationality for row in means[:4]] == [0.1] * 4
    expected = statistics.group_means(sweep, "kl", by)
    pd.testing.assert_frame_equal(means.to_frame()[expected.columns], expected, check_dtype=False)


@pytest.mark.parametrize(("n", "seed"), [(60, 0), (300, 1), (900, 2)])
def test_the_wilcoxon_log_tail_is_scipys_normal_approximation(n, seed):
    """The log-space tail (forced here with p = 0) equals log10 of SciPy's p, ties and zeros
    included, where SciPy's p is a double; past the smallest double it stays finite."""
    d = np.round(np.random.default_rng(seed).normal(0.8, 1.0, n), 1)
    p = float(stats.wilcoxon(d, correction=True).pvalue)
    assert statistics.wilcoxon_log10_p(d, 0.0) == pytest.approx(math.log10(p), rel=1e-12)
    huge = np.arange(1.0, 2001.0)
    assert float(stats.wilcoxon(huge, correction=True).pvalue) == 0.0
    assert -330 < statistics.wilcoxon_log10_p(huge, 0.0) < -320


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_a_non_finite_value_is_refused_naming_its_trial_never_averaged(value: float) -> None:
    """A value no record holds (the records refuse NaN, infinities and ``null`` of a measure
    every trial has), in a table handed to the analysis: one line naming the trial, where a
    NaN would have left its reward draw out silently, and an infinity would have made every
    sum of squares NaN."""
    from analysis_fixtures import pipeline

    from cirl_study.analysis.results.study import estimates, tests
    from cirl_study.errors import UserError

    trials = rows(synthetic_records(subjects_per_level=4, lambdas=(1.0,), etas=(1.0,)))
    table = trial_table(trials)
    position = table.index[(table["block"] == "main")][5]
    table.loc[position, "kl"] = value
    trial = table.at[position, "trial_id"]
    with pytest.raises(UserError, match=f"^kl of trial {re.escape(trial)} is .*not a finite"):
        tests(estimates(trials, table, pipeline()), table, pipeline())
    frame = table[table["block"] == "main"]
    with pytest.raises(UserError, match=f"^kl of trial {re.escape(trial)} is"):
        repeated_measures_anova(frame, "kl", ["human"], ["num_features"])


def test_a_measure_a_trial_may_lack_leaves_its_draws_out_as_before() -> None:
    """``null`` where the registry allows it (``order_agreement``: undefined where theta has no
    two different weights, and not logged before format 8) is a missing value: its reward draw
    is left out of that measure's statistics, and a measure missing from every trial has none;
    a missing value of a measure every trial has is refused."""
    from cirl_study.analysis.results.per_measure import measured
    from cirl_study.errors import UserError

    table = trial_table(rows(synthetic_records(subjects_per_level=4, lambdas=(1.0,), etas=(1.0,))))
    main = table[table["block"] == "main"].copy()
    lacking = main["subject"].iloc[0]
    main.loc[main["subject"] == lacking, "order_agreement"] = math.nan
    kept = dict(measured(main))
    assert lacking not in set(kept["order_agreement"]["subject"])
    assert kept["regret"].equals(main)
    main["order_agreement"] = math.nan
    assert "order_agreement" not in dict(measured(main))
    main.loc[main.index[0], "regret"] = math.nan
    with pytest.raises(UserError, match=f"^regret of trial {re.escape(main['trial_id'].iloc[0])}"):
        dict(measured(main))
