"""The studentized range tail (cirl_study.analysis.statistics.studentized_range) and Tukey's
p-values.

Four independent checks of :func:`studentized_range_sf`: an mpmath evaluation of the usual
``1 - CDF`` form at enough digits, the closed form for two groups, SciPy where SciPy is
accurate, and monotonicity. Its fixed outer rule is checked against adaptive quadrature, the
path it falls back to. Then :func:`statistics.tukey_hsd` uses it, and the ANOVA's ``p <
1e-300`` is checked to be genuine.
"""

from __future__ import annotations

import bisect
import functools
import math
from types import SimpleNamespace

import mpmath as mp
import numpy as np
import pandas as pd
import pingouin as pg
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mpmath.calculus.quadrature import GaussLegendre
from scipy import integrate, stats

from cirl_study.analysis.statistics import procedures as statistics
from cirl_study.analysis.statistics import studentized_range
from cirl_study.analysis.statistics.studentized_range import (
    studentized_range_log10_sf,
    studentized_range_sf,
)
from cirl_study.analysis.statistics.tails import t_tail

TINY = np.finfo(np.float64).tiny
"""The smallest normal double, below which the tail may be 0.0."""


@functools.cache
def _mpmath_sf(q: float, k: int, df: float) -> mp.mpf:
    """``P(Q > q)`` from the CDF form, ``int [1 - P(R <= q s)] f_S(s) ds``, in mpmath.

    ``P(R <= w) = k int phi(z) [Phi(z + w) - Phi(z)]^(k-1) dz`` at ``digits`` digits, enough
    that ``1 - P(R <= w)`` is exact to ``10^-digits``, ``1e-12`` of a lower bound of the
    answer (a single pair: ``P(Q > q) >= P(sqrt(2) |T| > q)``). The integral runs over
    ``[z_lo, z_hi]``, outside which the integrand has mass below ``tol = 10^-(digits + 5)``
    (``k Phi(z_lo)`` on the left, ``Phibar(z_hi)^k`` on the right), by composite
    Gauss-Legendre (24 nodes per panel, panels at most 1, 0.75 or 0.5 wide); the rule's own
    error is measured where the tail is known to be nil. Nodes with ``Phibar(z + w) < tol``
    take ``Phi(z + w) = 1``, which is what the working precision would give anyway.

    The outer integral is Gauss-Legendre on ``s0 +- 10 sigma``, ``s0^2 = df / (df + q^2 /
    2)``, ``sigma = 1 / sqrt(2 df + q^2)`` (cut at 0), with 40 and with 48 nodes: their
    difference bounds its error, and the integrand is checked negligible at both ends.
    """
    lower = 2 * stats.t.sf(q / math.sqrt(2), df)
    digits = math.ceil(-math.log10(lower)) + 12
    with mp.workdps(digits):
        tolerance = mp.mpf(10) ** -(digits + 5)
        z_lo = -mp.sqrt(2 * mp.log(k / tolerance))  # k Phi(z_lo) < tolerance
        z_hi = -mp.sqrt(2) * mp.erfinv(2 * tolerance ** (mp.mpf(1) / k) - 1)  # Phibar^k
        z_one = -mp.sqrt(2) * mp.erfinv(2 * tolerance - 1)  # Phibar(z_one) = tolerance
        # Panel widths whose rule errors (~1e-41, 1e-56, 1e-62) stay below 10^-digits.
        most = 1.0 if digits <= 40 else 0.75 if digits <= 50 else 0.5
        panels = int(mp.ceil((z_hi - z_lo) / most))
        width = (z_hi - z_lo) / panels
        rule = GaussLegendre(mp.mp).calc_nodes(4, mp.mp.prec)  # 24 nodes on [-1, 1]
        nodes = [z_lo + width * (i + (x + 1) / 2) for i in range(panels) for x, _ in rule]
        weights = [k * width / 2 * v for _ in range(panels) for _, v in rule]
        coefficients = [v * mp.npdf(z) for z, v in zip(nodes, weights, strict=True)]
        below = [mp.ncdf(z) for z in nodes]
        # right[j]: the terms from node j on with Phi(z + w) = 1.
        right = [mp.mpf(0)]
        for c, p in zip(reversed(coefficients), reversed(below), strict=True):
            right.insert(0, right[0] + c * (1 - p) ** (k - 1))

        def sf_range(w: mp.mpf) -> mp.mpf:
            near = bisect.bisect_left(nodes, z_one - w)
            terms = (
                c * (mp.ncdf(z + w) - p) ** (k - 1)
                for c, z, p in zip(coefficients[:near], nodes[:near], below[:near], strict=True)
            )
            return 1 - mp.fsum(terms) - right[near]

        # The true tail at w = z_hi - z_lo is below tol: what is left is the rule's error.
        assert abs(sf_range(z_hi - z_lo)) < mp.mpf(10) ** -digits
        nu, qm = mp.mpf(df), mp.mpf(q)
        log_c = mp.log(2) + nu / 2 * mp.log(nu / 2) - mp.loggamma(nu / 2)

        def integrand(s: mp.mpf) -> mp.mpf:
            return sf_range(qm * s) * mp.exp(log_c + (nu - 1) * mp.log(s) - nu * s * s / 2)

        s0 = mp.sqrt(nu / (nu + qm * qm / 2))
        sigma = 1 / mp.sqrt(2 * nu + qm * qm)
        start, stop = max(s0 - 10 * sigma, mp.mpf(0)), s0 + 10 * sigma
        scale = integrand(s0)
        assert integrand(stop) < 1e-15 * scale
        assert start == 0 or integrand(start) < 1e-15 * scale
        middle, half = (start + stop) / 2, (stop - start) / 2
        estimates = []
        for n in (40, 48):
            x, v = np.polynomial.legendre.leggauss(n)
            estimates.append(
                half
                * mp.fsum(
                    mp.mpf(b) * integrand(middle + half * mp.mpf(a))
                    for a, b in zip(x, v, strict=True)
                )
            )
        assert abs(estimates[1] / estimates[0] - 1) < 1e-11
        return estimates[1]


MPMATH_CASES = [
    (14.6, 4, 1996),  # the report's example: SciPy gives 0.0
    (3.0, 4, 10),
    (6.0, 2, 1996),
    (12.0, 4, 1996),
    (20.0, 4, 10),
    (30.0, 4, 10),
]
"""A few cases: each takes 1 to 5 s. (20, 4, 1996), 1.4e-42, agrees too but takes 18 s."""


@pytest.mark.parametrize(("q", "k", "df"), MPMATH_CASES)
def test_matches_mpmath_on_the_cdf_form(q, k, df):
    expected = _mpmath_sf(q, k, df)
    assert float(abs(studentized_range_sf(q, k, df) / expected - 1)) <= 1e-9


def test_the_report_example_is_far_from_zero():
    # SciPy's sf (1 - cdf) says 0.0; the tail is 1.34e-23.
    assert stats.studentized_range.sf(14.6, 4, 1996) == 0.0
    assert studentized_range_sf(14.6, 4, 1996) == pytest.approx(1.338774e-23, rel=1e-6)


@pytest.mark.parametrize("df", [1, 3, 10, 1996, 1e6, math.inf])
def test_two_groups_follow_the_t_distribution(df):
    # k = 2: Q = sqrt(2) |T| with T ~ t_df, so P(Q > q) = 2 P(T > q / sqrt(2)).
    t = stats.norm if math.isinf(df) else stats.t(df)
    for q in [0.05, 0.5, 1, 3, 6, 12, 14.6, 20, 30, 45, 60]:
        expected = 2 * t.sf(q / math.sqrt(2))
        if expected >= TINY:
            assert studentized_range_sf(q, 2, df) == pytest.approx(expected, rel=1e-9, abs=0)


def test_zero_only_below_the_smallest_normal_double():
    # k = 2, df = 1996: the tail crosses 2.2e-308 at q = 64.002.
    t = stats.t(1996)
    for q in np.arange(62.0, 66.0, 0.25):
        expected = 2 * t.sf(q / math.sqrt(2))
        value = studentized_range_sf(q, 2, 1996)
        if expected >= TINY:
            assert value == pytest.approx(expected, rel=1e-9, abs=0)
        elif expected < TINY / 2:
            assert value == 0.0
    assert studentized_range_sf(100, 4, 1996) == 0.0


@pytest.mark.parametrize(("k", "df"), [(2, 5), (3, 20), (4, 1996), (6, 60), (10, 2)])
def test_agrees_with_scipy_where_scipy_is_accurate(k, df):
    checked = 0
    for q in np.linspace(0.25, 9.0, 36):
        expected = stats.studentized_range.sf(q, k, df)
        if expected > 1e-3:
            assert studentized_range_sf(q, k, df) == pytest.approx(expected, rel=1e-8, abs=0)
            checked += 1
    assert checked >= 5


@settings(max_examples=25, deadline=None)
@given(
    q=st.floats(0.05, 40.0),
    step=st.floats(0.01, 5.0),
    k=st.sampled_from([2, 3, 4, 7]),
    df=st.sampled_from([2.0, 10.0, 1996.0, math.inf]),
)
def test_decreases_in_q(q, step, k, df):
    before, after = studentized_range_sf(q, k, df), studentized_range_sf(q + step, k, df)
    assert 0.0 <= after <= before <= 1.0
    if after > 0:
        assert after < before


def test_edge_cases_and_arguments():
    assert studentized_range_sf(0.0, 4, 10) == 1.0
    assert studentized_range_sf(-1.0, 4, 10) == 1.0
    assert studentized_range_sf(math.inf, 4, 10) == 0.0
    assert math.isnan(studentized_range_sf(math.nan, 4, 10))
    for k, df in [(1, 10), (2.5, 10), (4, 0), (4, -3), (4, math.nan)]:
        with pytest.raises(ValueError):
            studentized_range_sf(3.0, k, df)


DEEP_Q = {0.5: 1e300, 1: 1e300, 2: 2e150, 10: 5e30, 1996: 63.0, 1e8: 52.5}
"""Per ``df``, a ``q`` whose tail is about ``1e-300`` (``1e-150`` for ``df = 0.5``: no
double ``q`` reaches further)."""

FIXED_RULE_CASES = [
    (q, k, df) for k in (2, 4, 100) for df, deep in DEEP_Q.items() for q in (0.3, 3.0, 12.0, deep)
]
"""Tiny to huge ``df``, ``k`` up to 100, ``q`` from the bulk to the deep tail. For ``k = 100,
df <= 2`` the outer rule's first step is off by up to ``5e-4``: its check must halve it."""


def _adaptive_sf(monkeypatch: pytest.MonkeyPatch, q: float, k: int, df: float) -> float:
    """The tail with the outer integral left to ``scipy.integrate.quad`` from the start."""
    with monkeypatch.context() as patch:
        patch.setattr(studentized_range, "_OUTER_MAX_NODES", 0)
        return studentized_range_sf(q, k, df)


@pytest.mark.parametrize(("q", "k", "df"), FIXED_RULE_CASES)
def test_the_fixed_outer_rule_matches_adaptive_quadrature(monkeypatch, q, k, df):
    def no_quad(*args, **kwargs):
        raise AssertionError("the fixed outer rule fell back to quad")

    with monkeypatch.context() as patch:
        patch.setattr(studentized_range, "integrate", SimpleNamespace(quad=no_quad))
        fixed = studentized_range_sf(q, k, df)
    assert fixed > TINY
    assert fixed == pytest.approx(_adaptive_sf(monkeypatch, q, k, df), rel=1e-12, abs=0)


def test_the_adaptive_path_warns_when_quad_is_unsure(monkeypatch):
    # Two subintervals leave quad's error estimate far above 1e-9 on this skewed integrand.
    def coarse_quad(*args, **kwargs):
        return integrate.quad(*args, **{**kwargs, "limit": 2})

    monkeypatch.setattr(studentized_range, "_OUTER_MAX_NODES", 0)
    monkeypatch.setattr(studentized_range, "integrate", SimpleNamespace(quad=coarse_quad))
    with pytest.warns(RuntimeWarning, match="relative error up to"):
        studentized_range_sf(3.0, 100, 1.0)


def test_the_report_calls_take_few_outer_nodes(monkeypatch):
    # k = 4, df = 1996: 64 outer nodes per call (3 for Newton's method, 61 for the rule);
    # adaptive quadrature takes about 270.
    nodes = []

    def counted(w, k):
        nodes.append(np.size(w))
        return log_range_sf(w, k)

    log_range_sf = studentized_range._log_range_sf
    monkeypatch.setattr(studentized_range, "_log_range_sf", counted)
    for q in np.geomspace(0.5, 40, 18):
        studentized_range_sf(q, 4, 1996)
    assert sum(nodes) <= 18 * 100


def _tukey_frame() -> pd.DataFrame:
    """Feature levels 3 and 10 (30 subjects each), two humans, one far-apart pair."""
    rng = np.random.default_rng(7)
    centers = {(3, "best_response"): 0.0, (3, "expert"): 0.3, (10, "best_response"): 0.5}
    rows = []
    for level in (3, 10):
        for index in range(30):
            for human in ("best_response", "expert"):
                center = centers.get((level, human), 3.5)
                rows.append((f"{level}-{index}", level, human, rng.normal(center, 1.0)))
    frame = pd.DataFrame(rows, columns=["subject", "num_features", "human", "regret"])
    frame.loc[5, "regret"] = np.nan  # pingouin drops it: N = 119, df = 115
    return frame


def test_tukey_hsd_uses_the_accurate_tail():
    frame = _tukey_frame()
    tukey = statistics.tukey_hsd(frame, "regret").to_frame()
    expected = [studentized_range_sf(math.sqrt(2) * abs(t), 4, 119 - 4) for t in tukey["T"]]
    assert list(tukey["p_tukey"]) == expected
    pingouin = pg.pairwise_tukey(data=frame, dv="regret", between=["num_features", "human"])
    np.testing.assert_array_equal(tukey["T"], pingouin["T"])
    moderate = pingouin["p_tukey"] > 1e-3
    assert moderate.sum() >= 2
    np.testing.assert_allclose(tukey["p_tukey"][moderate], pingouin["p_tukey"][moderate], rtol=1e-8)
    # The far pairs: pingouin's 1 - CDF is 0.0, the tail is not.
    far = np.sqrt(2) * np.abs(tukey["T"]) > 12
    assert far.any()
    assert (pingouin["p_tukey"][far] == 0).all()
    assert (tukey["p_tukey"][far] > 0).all()


def test_anova_p_below_1e300_is_genuine():
    # The report's F = 3716 on (1, 998): with df1 = 1, F = T^2 and T ~ t_998, so
    # P(F > f) = P(|T| > sqrt(f)) = I_{df2 / (df2 + f)}(df2 / 2, 1 / 2).
    def p_value(f: float, df2: int) -> mp.mpf:
        with mp.workdps(50):
            return mp.betainc(mp.mpf(df2) / 2, 0.5, 0, df2 / (df2 + mp.mpf(f)), regularized=True)

    # The formula, where SciPy is accurate in the tail.
    for f in (4.0, 100.0, 800.0):
        assert float(p_value(f, 998)) == pytest.approx(stats.f.sf(f, 1, 998), rel=1e-10)
    p = p_value(3716.0, 998)
    assert p < mp.mpf("1e-300")
    assert p < TINY  # even below every normal double: SciPy's 0.0 is the right double
    assert stats.f.sf(3716.0, 1, 998) == 0.0


@pytest.mark.parametrize(("q", "df"), [(10.0, 1996), (60.0, 1996), (80.0, 998), (120.0, 1996)])
def test_the_log_tail_below_the_smallest_double_equals_the_closed_form_at_k_2(q, df):
    """``P(Q_2 > q) = P(|T_df| > q / sqrt 2)``: the log tail stays exact down to 1e-664."""
    exact = t_tail(q / math.sqrt(2), df)[1]
    assert studentized_range_log10_sf(q, 2, df) == pytest.approx(exact, rel=1e-12)


@pytest.mark.parametrize(("q", "df"), [(60.0, 1996), (120.0, 1996), (200.0, 500)])
def test_the_log_tail_at_k_4_lies_between_its_bonferroni_bounds(q, df):
    """Some pair's difference exceeds ``q``: at least the largest pair's tail, at most the
    sum over the six pairs (``P_2`` the tail of one pair, ``k = 2``)."""
    pair = t_tail(q / math.sqrt(2), df)[1]
    assert pair <= studentized_range_log10_sf(q, 4, df) <= pair + math.log10(6) + 1e-12
    assert (studentized_range_sf(q, 4, df) == 0.0) == (pair < -308)
