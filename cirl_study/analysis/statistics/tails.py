"""Tail probabilities of the F, t and chi-square distributions in log space, exact where
doubles underflow.

A p-value below the smallest normal double (``2.2e-308``) is stored by its common logarithm,
``log10 p``, never as 0. The F and t tails reduce to the regularised incomplete beta function
``I_x(a, b)``, the chi-square tail to the regularised upper incomplete gamma ``Q(a, x)``:

* ``P(F_{d1, d2} > f) = I_x(d2 / 2, d1 / 2)`` with ``x = d2 / (d2 + d1 f)``;
* ``P(|T_df| > t) = I_x(df / 2, 1 / 2)`` with ``x = df / (df + t^2)`` (two-sided);
* ``P(chi2_f > z) = Q(f / 2, z / 2)``.

Where the tail is at least :data:`NORMAL_TAIL`, ``log10 p`` is the logarithm of SciPy's
``sf`` (relative error about 1e-15). Below it, ``log I_x(a, b) = a log x + b log(1 - x) -
log a - log B(a, b) + log CF``, with ``CF`` the continued fraction of Numerical Recipes'
``betacf``, evaluated by the modified Lentz method (Press et al. 2007, §6.4) to a relative
error below 1e-15; likewise ``log Q(a, x) = -x + a log x - log Gamma(a) + log CF`` with the
continued fraction of ``gcf`` (§6.2), where the tail is small (``x > a + 1``). The tests check
both branches against mpmath at 60 digits.

References:
    Press, Teukolsky, Vetterling & Flannery (2007), *Numerical Recipes*, 3rd ed., §6.4.
    Abramowitz & Stegun (1964), 26.5.8 (the continued fraction) and 26.6.2, 26.7.1.
"""

from __future__ import annotations

import itertools
import math
import sys
from collections.abc import Iterator

from scipy import special, stats

NORMAL_TAIL = 1e-300
"""Smallest p taken from SciPy's ``sf`` directly; a smaller one comes from the continued
fraction (which is also accurate above it: the tests check the two agree)."""

_TINY = 1e-300

_LOG_TINY = math.log(sys.float_info.min)
"""Log of the smallest normal double, ``log(2.2250738585072014e-308)``."""
_ITERATIONS = 10_000


def log10_beta_tail(log_ratio: float, a: float, b: float) -> float:
    """``log10 I_x(a, b)`` with ``x = r / (1 + r)`` given ``log r``, in log space.

    Taking ``log r`` rather than ``x`` keeps ``log x = log r - log(1 + r)`` and ``log(1 - x)
    = -log(1 + r)`` exact when ``x`` itself underflows (an F or t statistic past ``1e154``).

    Examples:
        >>> round(log10_beta_tail(0.0, 1.0, 1.0), 5)  # I_x(1, 1) = x = 1/2
        -0.30103
        >>> log10_beta_tail(-2000.0, 3.0, 2.0) < -2600
        True
    """
    log1p_r = math.log1p(math.exp(log_ratio)) if log_ratio < 700 else log_ratio
    x = math.exp(log_ratio - log1p_r)
    if not x < 1.0:
        raise ValueError(f"I_x(a, b) at x = 1 is not a tail (log r = {log_ratio!r})")
    log_front = a * (log_ratio - log1p_r) - b * log1p_r - math.log(a) - float(special.betaln(a, b))
    return (log_front + math.log(_continued_fraction(x, a, b))) / math.log(10.0)


def _lentz(first: float, terms: Iterator[tuple[float, float]]) -> float:
    """``b_0 + a_1 / (b_1 + a_2 / (b_2 + ...))`` by the modified Lentz method (Press et al.
    2007, §5.2), ``terms`` the pairs ``(a_i, b_i)``, to a relative error of 1e-16."""
    f = first if abs(first) > _TINY else _TINY
    c, d = f, 0.0
    for a, b in itertools.islice(terms, _ITERATIONS):
        d = b + a * d
        d = 1.0 / (d if abs(d) > _TINY else _TINY)
        c = b + a / c
        c = c if abs(c) > _TINY else _TINY
        step = c * d
        f *= step
        if abs(step - 1.0) < 1e-16:
            return f
    raise ArithmeticError("a continued fraction did not converge")


def _continued_fraction(x: float, a: float, b: float) -> float:
    """Numerical Recipes' ``betacf(a, b, x)``: ``1 / (1 + d_1 / (1 + d_2 / (1 + ...)))`` with
    ``d_{2m+1} = -(a + m)(a + b + m) x / ((a + 2m)(a + 2m + 1))`` and ``d_{2m} = m (b - m) x /
    ((a + 2m - 1)(a + 2m))``."""

    def terms() -> Iterator[tuple[float, float]]:
        for m in itertools.count():
            if m:
                yield m * (b - m) * x / ((a + 2 * m - 1) * (a + 2 * m)), 1.0
            yield -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1)), 1.0

    return 1.0 / _lentz(1.0, terms())


def f_tail(f_value: float, df1: float, df2: float) -> tuple[float, float]:
    """``(p, log10 p)`` of ``P(F_{df1, df2} > f_value)``; NaN for an undefined ``f_value``.

    Examples:
        >>> p, log10_p = f_tail(4.0, 1, 10)
        >>> round(p, 6), round(log10_p, 6)
        (0.073388, -1.134375)
        >>> f_tail(1e6, 1, 1000)[1] < -1000
        True
    """
    if not math.isfinite(f_value) or df1 <= 0 or df2 <= 0:
        return math.nan, math.nan
    p = float(stats.f.sf(f_value, df1, df2))
    log_ratio = math.log(df2) - math.log(df1) - math.log(f_value) if p < NORMAL_TAIL else 0.0
    return _beta_tail(p, log_ratio, df2 / 2, df1 / 2)


def t_tail(t_value: float, df: float) -> tuple[float, float]:
    """``(p, log10 p)`` of the two-sided ``P(|T_df| > |t_value|)``; NaN when undefined.

    Examples:
        >>> p, log10_p = t_tail(2.0, 10)
        >>> round(p, 6), round(log10_p, 6)
        (0.073388, -1.134375)
    """
    if not math.isfinite(t_value) or df <= 0:
        return math.nan, math.nan
    p = float(2 * stats.t.sf(abs(t_value), df))
    log_ratio = math.log(df) - 2 * math.log(abs(t_value)) if p < NORMAL_TAIL else 0.0
    return _beta_tail(p, log_ratio, df / 2, 0.5)


def _beta_tail(p: float, log_ratio: float, a: float, b: float) -> tuple[float, float]:
    """``(p, log10 p)``: SciPy's ``p`` where it is at least :data:`NORMAL_TAIL`, else the
    continued fraction's ``log10 I_x(a, b)`` at ``x = r / (1 + r)``, ``log r = log_ratio``."""
    if p >= NORMAL_TAIL:
        return p, math.log10(p)
    return p, log10_beta_tail(log_ratio, a, b)


def chi2_tail(statistic: float, df: float) -> tuple[float, float]:
    """``(p, log10 p)`` of ``P(chi2_df > statistic)``; NaN for an undefined statistic.

    Examples:
        >>> p, log10_p = chi2_tail(3.84, 1)
        >>> round(p, 4)
        0.05
        >>> chi2_tail(5000.0, 14)[1] < -1000
        True
    """
    if not math.isfinite(statistic) or df <= 0:
        return math.nan, math.nan
    p = float(stats.chi2.sf(statistic, df))
    a, x = df / 2, statistic / 2
    if p >= NORMAL_TAIL or x <= a + 1:
        return p, math.log10(p) if p > 0 else -math.inf
    log_q = -x + a * math.log(x) - float(special.gammaln(a)) + math.log(_gamma_fraction(a, x))
    return p, log_q / math.log(10.0)


def _gamma_fraction(a: float, x: float) -> float:
    """Numerical Recipes' ``gcf``: ``1 / (x + 1 - a - 1 (1 - a) / (x + 3 - a - 2 (2 - a) /
    (x + 5 - a - ...)))``."""
    terms = ((-i * (i - a), x + 2 * i + 1 - a) for i in itertools.count(1))
    return 1.0 / _lentz(x + 1.0 - a, terms)


def p_from_log10(log10_p: float) -> float:
    """``p`` from ``log10 p``: 0.0 below the smallest normal double (never a subnormal),
    at most 1, NaN for NaN.

    Examples:
        >>> p_from_log10(-2.0), p_from_log10(-400.0), p_from_log10(0.5)
        (0.01, 0.0, 1.0)
    """
    log10_p = float(log10_p)
    if math.isnan(log10_p):
        return math.nan
    if log10_p * math.log(10.0) < _LOG_TINY:
        return 0.0
    return min(10.0**log10_p, 1.0)
