"""The statistical tests of the study (docs/design.md §5), one function per test.

Every function takes a slice of the trial table (:func:`cirl_study.analysis.table.trial_table`)
and returns its typed rows at full precision (a :class:`~cirl_study.analysis.results.types.Table`
of rows of :mod:`cirl_study.analysis.results.types`, whose ``to_frame()`` is the tidy
:class:`pandas.DataFrame`), or its typed record. Notation:
``y_{s,p}`` is a measure of subject (reward draw) ``s`` under human ``p``, subject ``s``
belongs to exactly one feature level ``g(s)``; ``d_s = y_{s,br} - y_{s,expert}`` is its
paired difference (negative: the best response did better, since every measure is a loss).

The tests are computed by pingouin and scipy; this module only chooses
them, feeds them and names their outputs. The bootstrap uses a fixed seed, so every
number here is a deterministic function of the table.
"""

from __future__ import annotations

import contextlib
import functools
import itertools
import math
import warnings
from collections.abc import Iterator, Mapping, Sequence
from typing import NamedTuple, TypeVar

import numpy as np
import pandas as pd
import pingouin as pg
from scipy import special, stats

from cirl_study.analysis.results.types import (
    CellMean,
    CronbachAlpha,
    EtaMean,
    EtaUncertainty,
    JointTest,
    PairedComparison,
    PairedDifference,
    SignFlipStatistic,
    SimpleEffect,
    Table,
    TukeyRow,
    WilcoxonRow,
)
from cirl_study.analysis.statistics.studentized_range import studentized_range_log10_sf
from cirl_study.analysis.statistics.tails import NORMAL_TAIL, p_from_log10, t_tail
from cirl_study.record import BEST_RESPONSE, EXPERT, PAPER_HUMANS

CONFIDENCE = 0.95
"""Level of every confidence interval."""

BOOTSTRAP_RESAMPLES = 9999
"""Resamples of every bootstrap confidence interval."""

BOOTSTRAP_SEED = 2016
"""Seed of the generator of every bootstrap (each interval starts afresh from it)."""


def paired_differences(
    frame: pd.DataFrame, measure: str, factor: str, baseline: str, by: list[str]
) -> Table[PairedDifference]:
    """Paired t-tests of ``factor`` against its ``baseline`` level within each group of ``by``.

    In each group, subject ``s`` observed at both levels gives ``d_s = y_{s,other} -
    y_{s,baseline}`` for every other level of ``factor`` (a subject missing either is left
    out: only in a partial run); ``t = mean(d) / (sd(d) / sqrt(n))`` with ``n - 1`` degrees of
    freedom, a t-based CI of ``mean(d)``, ``d_z = mean(d) / sd(d)``, and ``p_holm``, Holm's
    adjustment over all rows returned (one family).

    References:
        Holm (1979), Scandinavian Journal of Statistics 6(2):65-70.
        Lakens (2013), Frontiers in Psychology 4:863 (``d_z``).
        ``scipy.stats.ttest_rel``.

    Returns:
        One row per group and other level, groups sorted.
    """
    cells, tests = [], []
    for key, group in frame.groupby(by, sort=True):
        paired = group.pivot(index="subject", columns=factor, values=measure).sort_index()
        for level in sorted(set(paired.columns) - {baseline}):
            both = paired[[baseline, level]].dropna()
            reference, other = both[baseline].to_numpy(), both[level].to_numpy()
            cells.append((dict(zip(by, key, strict=True)), level, reference, other))
            tests.append(paired_t(other, reference))
    adjusted = _holm_family(tests)
    return Table(
        PairedDifference,
        (
            PairedDifference(
                measure=measure,
                **cell,
                level=level,
                n=len(reference),
                mean_baseline=float(reference.mean()),
                mean_level=float(other.mean()),
                **test._asdict(),
                p_holm=p_holm,
                log10_p_holm=log10_p_holm,
            )
            for (cell, level, reference, other), test, (p_holm, log10_p_holm) in zip(
                cells, tests, adjusted, strict=True
            )
        ),
    )


def pairwise_differences(
    frame: pd.DataFrame, measure: str, factor: str, levels: Sequence[str]
) -> Table[PairedComparison]:
    """Paired t-tests of every pair of ``levels`` of the within factor ``factor``, within
    each cell of the other factors (``human``, ``robot`` and ``num_features``).

    For the levels ``a`` before ``b`` in ``levels`` and subject ``s``: ``d_s = y_{s,a} -
    y_{s,b}``; ``t = mean(d) / (sd(d) / sqrt(n))`` on ``n - 1`` degrees of freedom (R's
    ``t.test(paired = TRUE)``), a t-based CI of ``mean(d)``, ``d_z = mean(d) / sd(d)``. One
    Holm family: every row returned (one measure and factor), adjusted in log space
    (:func:`holm_log10`).

    References:
        Holm (1979), Scandinavian Journal of Statistics 6(2):65-70.
        Lakens (2013), Frontiers in Psychology 4:863 (``d_z``).
        R: ``t.test``, ``p.adjust(method = "holm")`` (``tests/fixtures/factorial``).

    Returns:
        One row per cell and pair, cells sorted, pairs in the order of ``levels``.
    """
    cells = [c for c in ("human", "robot", "num_features") if c != factor]
    compared, tests = [], []
    for key, group in frame.groupby(cells, sort=True):
        cell = dict(zip(cells, key, strict=True))
        wide = group.pivot(index="subject", columns=factor, values=measure).sort_index()
        present = [level for level in levels if level in wide.columns]
        for a, b in itertools.combinations(present, 2):
            both = wide[[a, b]].dropna()
            first, second = both[a].to_numpy(), both[b].to_numpy()
            compared.append((cell, a, b, first, second))
            tests.append(paired_t(first, second))
    adjusted = holm_log10(np.array([test.log10_p for test in tests]))
    # An adjusted p is never below its p: at a multiplier of 1 the round trip through log10
    # can lose the last bit.
    return Table(
        PairedComparison,
        (
            PairedComparison(
                measure=measure,
                factor=factor,
                level_a=a,
                level_b=b,
                human=cell.get("human"),
                robot=cell.get("robot"),
                num_features=int(cell["num_features"]),
                n=len(first),
                mean_a=float(first.mean()),
                mean_b=float(second.mean()),
                **test._asdict(),
                p_holm=_at_least(p_from_log10(q), test.p),
                log10_p_holm=float(q),
            )
            for (cell, a, b, first, second), test, q in zip(compared, tests, adjusted, strict=True)
        ),
    )


def _at_least(adjusted: float, p: float) -> float:
    """``adjusted``, or ``p`` where rounding left ``adjusted`` just below it."""
    return p if adjusted < p else adjusted


def holm_log10(log10_p: np.ndarray) -> np.ndarray:
    """Holm's step-down adjustment (Holm 1979) of a family given by ``log10 p``:
    ``log10 p~_(i) = min(0, max_{j <= i} (log10(n - j + 1) + log10 p_(j)))`` over the ``n``
    finite values in increasing order; NaN stays NaN. The same numbers as :func:`holm`,
    without underflow.

    Examples:
        >>> holm_log10(np.log10([0.01, 0.04, 0.03])).round(6).tolist()
        [-1.522879, -1.221849, -1.221849]
    """
    values = np.asarray(log10_p, dtype=np.float64)
    result = np.full(values.shape, np.nan)
    finite = np.flatnonzero(~np.isnan(values))
    order = finite[np.argsort(values[finite], kind="mergesort")]
    count = len(order)
    scaled = np.log10(count - np.arange(count)) + values[order]
    result[order] = np.minimum(0.0, np.maximum.accumulate(scaled))
    return result


def paired_by_subject(main: pd.DataFrame, measure: str, level: int) -> pd.DataFrame:
    """Subjects x humans frame of ``measure`` at one feature level, subjects sorted."""
    cell = main[main["num_features"] == level]
    paired = cell.pivot(index="subject", columns="human", values=measure)
    return paired[list(PAPER_HUMANS)].sort_index()


@contextlib.contextmanager
def undefined_as_nan() -> Iterator[None]:
    """Compute statistics of samples that may be too small for them, quietly: a variance of one
    value, a t of differences all alike, an effect size over no spread are NaN (or infinite) by
    their definitions, and the results record each as ``null`` (shown as a dash), saying so;
    numpy's, scipy's and pingouin's warnings of them would only repeat it, hundreds of times.
    Usable as a decorator. Any other warning is shown as it is."""
    with np.errstate(divide="ignore", invalid="ignore"), warnings.catch_warnings():
        for message in (
            "Degrees of freedom <= 0",
            "invalid value encountered",
            "divide by zero encountered",
            "Precision loss occurred in moment calculation",
            "Mean of empty slice",
        ):
            warnings.filterwarnings("ignore", message, RuntimeWarning)
        yield


def _d_z(differences: np.ndarray, axis: int = -1) -> np.ndarray:
    """Cohen's ``d_z = mean(d) / sd(d)`` (``ddof = 1``) along ``axis``; ``sd = 0`` gives inf/NaN,
    and fewer than two differences NaN (no ``sd``)."""
    if np.shape(differences)[axis] < 2:
        return np.full(np.delete(np.shape(differences), axis), math.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.mean(differences, axis=axis) / np.std(differences, axis=axis, ddof=1)


class PairedTest(NamedTuple):
    """A paired t-test of ``d = first - second`` (:func:`paired_t`): the fields of
    :class:`~cirl_study.analysis.results.types.PairedT`, NaN where undefined."""

    mean_diff: float
    ci95_low: float
    ci95_high: float
    t: float
    df: int
    p: float
    log10_p: float
    d_z: float


def paired_t(first: np.ndarray, second: np.ndarray) -> PairedTest:
    """Paired t-test of ``d = first - second``: ``mean_diff``, its t-based CI, ``t``, ``df``,
    ``p`` (two-sided, ``scipy.stats.ttest_rel``), ``log10_p`` (in log space,
    :func:`cirl_study.analysis.statistics.tails.t_tail`) and ``d_z``."""
    difference = first - second
    if len(difference) < 2:  # no spread to test against: everything but the mean undefined
        mean = float(difference.mean()) if len(difference) else math.nan
        return PairedTest(mean, math.nan, math.nan, math.nan, 0, math.nan, math.nan, math.nan)
    with undefined_as_nan():  # differences all alike: t infinite (or 0 / 0), p 0 (or NaN)
        test = stats.ttest_rel(first, second)
        interval = test.confidence_interval(CONFIDENCE)
    return PairedTest(
        mean_diff=float(difference.mean()),
        ci95_low=float(interval.low),
        ci95_high=float(interval.high),
        t=float(test.statistic),
        df=int(test.df),
        p=float(test.pvalue),
        log10_p=t_tail(float(test.statistic), int(test.df))[1],
        d_z=float(_d_z(difference)),
    )


def _holm_family(tests: Sequence[PairedTest]) -> list[tuple[float, float]]:
    """``(p_holm, log10_p_holm)`` of each test, :func:`holm` and :func:`holm_log10` over
    ``tests`` as one family."""
    if not tests:
        return []
    p = holm(np.array([test.p for test in tests]))
    log10_p = holm_log10(np.array([test.log10_p for test in tests]))
    return [(float(a), float(b)) for a, b in zip(p, log10_p, strict=True)]


BOOTSTRAP_BATCH_ELEMENTS = 1 << 22
"""Resampled values drawn at once (32 MiB of float64): bounds the bootstrap's memory at any n."""


class BootstrapIntervals(NamedTuple):
    """The BCa intervals ``(low, high)`` of :func:`bootstrap_mean_d_z`."""

    mean: tuple[float, float]
    d_z: tuple[float, float]


def bootstrap_mean_d_z(differences: np.ndarray) -> BootstrapIntervals:
    """BCa bootstrap confidence intervals of ``mean(d)`` and ``d_z`` of one paired sample.

    The interval of Efron & Tibshirani (1993, §14.3), with :data:`BOOTSTRAP_RESAMPLES`
    resamples ``d*_b`` drawn from a generator seeded with :data:`BOOTSTRAP_SEED` (both
    statistics on the same resamples), so the intervals are a deterministic function of
    ``differences``. Bias correction ``z_0 = Phi^{-1}(#{theta*_b < theta_hat} / B + #{theta*_b
    = theta_hat} / (2 B))``; acceleration ``a = sum U_i^3 / (6 (sum U_i^2)^{3/2})`` from the
    jackknife values ``U_i = (n - 1)(theta_(.) - theta_(i))``; bounds the ``Phi(z_0 + (z_0 +
    z_alpha) / (1 - a (z_0 + z_alpha)))`` quantiles of the ``theta*_b``. When the bootstrap
    distribution is degenerate (tiny samples, constant differences) an interval is undefined:
    NaN.

    This equals ``scipy.stats.bootstrap(method="BCa")`` with the same generator (the
    resamples are the same draws; checked in the tests), but stays linear in ``n``: scipy
    computes the ``n`` leave-one-out statistics from ``n`` copies of the sample (``O(n^2)``
    time and, unbatched, memory), where here they have closed forms,
    and the resamples are drawn :data:`BOOTSTRAP_BATCH_ELEMENTS` values at a time. Leave-one-out
    mean ``m_(i) = m - e_i / (n - 1)`` with ``e_i = d_i - m``, and sum of squares about it
    ``Q - e_i^2 n / (n - 1)`` with ``Q = sum e_j^2``, so ``d_z(i) = m_(i) / sqrt((Q - e_i^2 n /
    (n - 1)) / (n - 2))``.

    References:
        Efron & Tibshirani (1993), *An Introduction to the Bootstrap*, ch. 14.
        ``scipy.stats.bootstrap``.

    Returns:
        The intervals of ``mean`` and ``d_z`` at level :data:`CONFIDENCE`.
    """
    d = np.asarray(differences, dtype=np.float64)
    n = d.size
    if n < 2:  # no resample differs from the sample: no interval
        return BootstrapIntervals(mean=(math.nan, math.nan), d_z=(math.nan, math.nan))
    means, d_zs = [], []
    for indices in _resample_indices(n):
        batch_means, batch_d_zs = _resampled_mean_and_d_z(d, indices)
        means.append(batch_means)
        d_zs.append(batch_d_zs)
    mean, centered = d.mean(), d - d.mean()
    with np.errstate(divide="ignore", invalid="ignore"):
        leave_one_out_mean = mean - centered / (n - 1)
        squares = np.sum(centered**2) - centered**2 * n / (n - 1)
        leave_one_out_d_z = leave_one_out_mean / np.sqrt(squares / (n - 2))
    return BootstrapIntervals(
        mean=_bca(np.concatenate(means), float(mean), leave_one_out_mean),
        d_z=_bca(np.concatenate(d_zs), float(_d_z(d)), leave_one_out_d_z),
    )


BOOTSTRAP_BLOCK_ELEMENTS = 1 << 16
"""Resampled values reduced at once (512 KiB of float64): a block stays in the cache."""


def _resampled_mean_and_d_z(d: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``mean(d*_b)`` and ``d_z(d*_b)`` of the resamples ``d*_b = d[indices[b]]``, a few
    rows at a time (:data:`BOOTSTRAP_BLOCK_ELEMENTS`) rather than on the whole batch: the same
    sums, differences and squares as ``np.mean`` and ``np.std(ddof=1)`` row by row, so the
    same bits, without their batch-sized temporaries (twice as fast, and no fresh memory to
    fault in for every sample)."""
    n = d.size
    rows = max(1, BOOTSTRAP_BLOCK_ELEMENTS // max(n, 1))
    means, d_zs = np.empty(len(indices)), np.empty(len(indices))
    for start in range(0, len(indices), rows):
        block = d[indices[start : start + rows]]
        mean = np.add.reduce(block, axis=-1) / n
        centered = np.subtract(block, mean[:, None], out=block)
        squares = np.add.reduce(np.multiply(centered, centered, out=centered), axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            d_zs[start : start + rows] = mean / np.sqrt(squares / (n - 1))
        means[start : start + rows] = mean
    return means, d_zs


def _resample_indices(n: int) -> Iterator[np.ndarray]:
    """The indices of the bootstrap's resamples of a sample of ``n``, batch by batch (at most
    :data:`BOOTSTRAP_BATCH_ELEMENTS` a batch), from a generator seeded with
    :data:`BOOTSTRAP_SEED`: the same for every sample of ``n``. They are drawn once and kept
    (:func:`_kept_resample_indices`) when all of them fit in one batch's memory
    twice over, as a report's samples of one size (one per measure and feature level) do."""
    if BOOTSTRAP_RESAMPLES * n <= 2 * BOOTSTRAP_BATCH_ELEMENTS:
        yield from _kept_resample_indices(n)
        return
    yield from _drawn_resample_indices(n)


@functools.lru_cache(maxsize=1)
def _kept_resample_indices(n: int) -> tuple[np.ndarray, ...]:
    """:func:`_drawn_resample_indices`, kept for the next sample of ``n``."""
    return tuple(_drawn_resample_indices(n))


def _drawn_resample_indices(n: int) -> Iterator[np.ndarray]:
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    batch = max(1, BOOTSTRAP_BATCH_ELEMENTS // max(n, 1))
    for start in range(0, BOOTSTRAP_RESAMPLES, batch):
        indices = rng.integers(0, n, (min(batch, BOOTSTRAP_RESAMPLES - start), n))
        indices.flags.writeable = False
        yield indices


def _bca(replicates: np.ndarray, estimate: float, jackknife: np.ndarray) -> tuple[float, float]:
    """The BCa interval from the bootstrap ``replicates`` and the ``jackknife`` values."""
    with np.errstate(divide="ignore", invalid="ignore"):
        below = np.count_nonzero(replicates < estimate) + np.count_nonzero(replicates <= estimate)
        z_0 = stats.norm.ppf(below / (2 * replicates.size))
        spread = (jackknife.size - 1) * (jackknife.mean() - jackknife)
        size = float(jackknife.size)
        a = 1 / 6 * (np.sum(spread**3) / size**3) / (np.sum(spread**2) / size**2) ** 1.5
        z_alpha = float(stats.norm.ppf((1 - CONFIDENCE) / 2))
        levels = [
            stats.norm.cdf(z_0 + (z_0 + z) / (1 - a * (z_0 + z))) for z in (z_alpha, -z_alpha)
        ]
    if not all(np.isfinite(levels)):
        return math.nan, math.nan
    low, high = stats.quantile(replicates, np.array(levels))
    return float(low), float(high)


def simple_effects(main: pd.DataFrame, measure: str) -> Table[SimpleEffect]:
    """Simple effects of ``human`` within each feature level: paired t-tests.

    At level ``g``: ``t = mean(d) / (sd(d) / sqrt(n))`` with ``n - 1`` degrees of freedom,
    Holm-adjusted over the feature levels of this measure; effect size
    ``d_z = mean(d) / sd(d)``; a t-based CI of ``mean(d)`` and BCa bootstrap CIs of
    ``mean(d)`` and ``d_z``.

    References:
        Holm (1979), Scandinavian Journal of Statistics 6(2):65-70.
        Lakens (2013), Frontiers in Psychology 4:863 (``d_z``).
        ``scipy.stats.ttest_rel``, ``pingouin.multicomp``.

    Returns:
        One row per feature level, levels sorted.
    """
    levels, tests, boots = [], [], []
    for level in sorted(main["num_features"].unique()):
        paired = paired_by_subject(main, measure, level)
        expert = paired[EXPERT].to_numpy()
        best = paired[BEST_RESPONSE].to_numpy()
        levels.append((int(level), expert, best))
        tests.append(paired_t(best, expert))
        boots.append(bootstrap_mean_d_z(best - expert))
    adjusted = _holm_family(tests)
    return Table(
        SimpleEffect,
        (
            SimpleEffect(
                measure=measure,
                num_features=level,
                n=len(expert),
                mean_expert=float(expert.mean()),
                mean_best_response=float(best.mean()),
                **test._asdict(),
                p_holm=p_holm,
                log10_p_holm=log10_p_holm,
                boot_diff_low=boot.mean[0],
                boot_diff_high=boot.mean[1],
                boot_d_z_low=boot.d_z[0],
                boot_d_z_high=boot.d_z[1],
            )
            for (level, expert, best), test, (p_holm, log10_p_holm), boot in zip(
                levels, tests, adjusted, boots, strict=True
            )
        ),
    )


def holm(p_values: np.ndarray) -> np.ndarray:
    """Holm's step-down adjustment of a family of p-values (Holm 1979).

    ``p~_(i) = min(1, max_{j <= i} (n - j + 1) p_(j))`` over the ``n`` finite p-values in
    increasing order; a NaN stays NaN and does not count in ``n``. By ``pingouin.multicomp``:
    statsmodels' ``multipletests`` computes the same numbers but runs a full garbage
    collection on every call, which walks every object of the process (a read run's rows
    among them).
    """
    return pg.multicomp(p_values, method="holm")[1]


def tukey_hsd(main: pd.DataFrame, measure: str) -> Table[TukeyRow]:
    """Tukey HSD over the ``num_features x human`` cells, as the paper did it.

    Every pair of cells is compared with ``q = sqrt(2) |mean_A - mean_B| / sqrt(MSE (1/n_A
    + 1/n_B)) = sqrt(2) |T|`` against the studentized range distribution of ``k`` cells on
    ``N - k`` degrees of freedom (``N`` observations), ``MSE = sum_i (n_i - 1) s_i^2 / (N - k)``
    pooled over all cells. This treats the cells as independent groups: it IGNORES THE PAIRING
    of the two humans within a subject, so its within-level comparisons are conservative
    compared with :func:`simple_effects`.

    ``pingouin.pairwise_tukey`` (checked against R ``TukeyHSD``) without its p-values: the
    same cells (observed combinations, sorted, NaN rows dropped), means, ``se = sqrt(MSE / n_A
    + MSE / n_B)``, ``T = diff / se`` and Hedges' g (``pingouin.compute_effsize``); the tests
    check the two agree. Its p-values are SciPy's ``1 - CDF``, which is 0.0 from ``q ~ 10.5``
    on (``k = 4``, ``N = 2000``), so they are not computed. Here
    ``p_tukey`` is the accurate tail ``P(Q > q)`` (relative error ``<= 1e-8``) and
    ``log10_p_tukey`` its common logarithm, computed in log space by
    :func:`cirl_study.analysis.statistics.studentized_range.studentized_range_log10_sf`: where the
    p-value is below the smallest double, ``p_tukey`` is 0.0 and ``log10_p_tukey`` holds it.

    References:
        Tukey (1949), Biometrics 5(2):99-114; Kramer (1956), Biometrics 12(3):307-310.
        ``pingouin.pairwise_tukey``.

    Returns:
        One row per pair of cells, cells in sorted order.
    """
    cells = ["num_features", "human"]
    observed = main[[measure, *cells]].dropna()
    groups = {
        cell: values.to_numpy(dtype=np.float64)
        for cell, values in observed.groupby(cells, observed=True)[measure]
    }
    labels = list(groups)
    sizes = np.array([len(groups[cell]) for cell in labels], dtype=np.float64)
    means = np.array([groups[cell].mean() for cell in labels])
    variances = np.array(
        [groups[cell].var(ddof=1) if len(groups[cell]) > 1 else np.nan for cell in labels]
    )
    k, df = len(labels), int(sizes.sum()) - len(labels)
    mse = np.nansum((sizes - 1) * variances) / df
    first, second = np.triu_indices(k, k=1)
    diff = means[first] - means[second]
    se = np.sqrt(mse / sizes[first] + mse / sizes[second])
    t = diff / se
    rows = []
    for i, (a, b) in enumerate(zip(first, second, strict=True)):
        log10_p = studentized_range_log10_sf(math.sqrt(2) * abs(t[i]), k, df)
        rows.append(
            TukeyRow(
                measure=measure,
                a_num_features=int(labels[a][0]),
                a_human=labels[a][1],
                b_num_features=int(labels[b][0]),
                b_human=labels[b][1],
                mean_a=float(means[a]),
                mean_b=float(means[b]),
                diff=float(diff[i]),
                se=float(se[i]),
                T=float(t[i]),
                p_tukey=p_from_log10(log10_p),
                log10_p_tukey=log10_p,
                hedges=float(
                    pg.compute_effsize(groups[labels[a]], groups[labels[b]], eftype="hedges")
                ),
            )
        )
    return Table(TukeyRow, rows)


def wilcoxon(main: pd.DataFrame, measure: str) -> Table[WilcoxonRow]:
    """Wilcoxon signed-rank test of ``d`` within each feature level (non-parametric check).

    ``W`` is the smaller of the signed-rank sums, ``p`` two-sided (normal approximation
    for large ``n``, as ``scipy.stats.wilcoxon`` decides, with continuity correction); ``rbc``
    the matched-pairs rank-biserial correlation ``(R+ - R-) / (R+ + R-)`` over the non-zero
    ``d``; ``cles`` the common-language effect size ``P(y_br > y_expert) + P(=) / 2`` over all
    ``n^2`` pairs of a best-response and an expert value (Vargha & Delaney 2000).

    These are ``pingouin.wilcoxon``'s numbers (checked equal in the tests), computed here
    because pingouin forms the ``n x n`` matrix of pairs for ``cles`` (``O(n^2)`` memory);
    counting them by binary search over the sorted expert values is ``O(n log n)`` and exact.

    References:
        Wilcoxon (1945), Biometrics Bulletin 1(6):80-83.
        Kerby (2014), Comprehensive Psychology 3 (rank-biserial correlation).
        Vargha & Delaney (2000), J. Educational and Behavioral Statistics 25(2):101-132.
        ``pingouin.wilcoxon``, ``scipy.stats.wilcoxon``.

    Returns:
        One row per feature level, levels sorted.
    """
    rows = []
    for level in sorted(main["num_features"].unique()):
        paired = paired_by_subject(main, measure, level)
        best, expert = paired[BEST_RESPONSE].to_numpy(), paired[EXPERT].to_numpy()
        if np.any(best != expert):
            test = stats.wilcoxon(best, expert, correction=True)
            w, p = float(test.statistic), float(test.pvalue)
            log10_p, rbc = wilcoxon_log10_p(best - expert, p), _rank_biserial(best - expert)
        else:  # every difference is 0: the signed ranks are empty and the test undefined
            w = p = log10_p = rbc = math.nan
        rows.append(
            WilcoxonRow(
                measure=measure,
                num_features=int(level),
                n=len(paired),
                W=w,
                p=p,
                log10_p=log10_p,
                rbc=rbc,
                cles=_common_language(best, expert),
            )
        )
    return Table(WilcoxonRow, rows)


def wilcoxon_log10_p(differences: np.ndarray, p: float) -> float:
    """``log10 p`` of the two-sided signed-rank test ``p`` of ``scipy.stats.wilcoxon`` (zeros
    dropped, continuity correction), in log space where ``p`` is below
    :data:`~cirl_study.analysis.statistics.tails.NORMAL_TAIL`.

    There SciPy used the normal approximation (its exact null has ``p >= 2^(1-n)``, and it is
    exact only up to ``n = 50``): ``z = (T - n (n + 1) / 4 - sign / 2) / se``, ``T`` the smaller
    rank sum, ``se^2 = (n (n + 1)(2 n + 1) - sum_ties t (t^2 - 1) / 2) / 24``, so ``log p =
    log 2 + log Phi(-|z|)`` (``scipy.special.log_ndtr``, exact far into the tail).

    Examples:
        >>> d = np.arange(1.0, 2001.0)
        >>> p = float(stats.wilcoxon(d, correction=True).pvalue)
        >>> p, round(wilcoxon_log10_p(d, p), 2)
        (0.0, -327.49)
    """
    if p >= NORMAL_TAIL:
        return math.log10(p)
    nonzero = differences[differences != 0]
    n = nonzero.size
    ranks = stats.rankdata(np.abs(nonzero))
    plus = float(ranks[nonzero > 0].sum())
    smaller = min(plus, float(ranks.sum()) - plus)
    mean = n * (n + 1) / 4
    _, ties = np.unique(ranks, return_counts=True)
    variance = (n * (n + 1) * (2 * n + 1) - 0.5 * float(np.sum(ties * (ties**2 - 1.0)))) / 24
    z = (smaller - mean - 0.5 * np.sign(smaller - mean)) / math.sqrt(variance)
    return (math.log(2.0) + float(special.log_ndtr(-abs(z)))) / math.log(10.0)


def _rank_biserial(differences: np.ndarray) -> float:
    """Matched-pairs rank-biserial correlation ``(R+ - R-) / (R+ + R-)`` (Kerby 2014)."""
    nonzero = differences[differences != 0]
    ranks = stats.rankdata(np.abs(nonzero))
    total = ranks.sum()
    return float(np.sum((nonzero > 0) * ranks) / total - np.sum((nonzero < 0) * ranks) / total)


def _common_language(first: np.ndarray, second: np.ndarray) -> float:
    """``(#{first_i > second_j} + #{first_i = second_j} / 2) / (n_first n_second)``, exactly."""
    ordered = np.sort(second)
    below = np.searchsorted(ordered, first, side="left").sum()
    tied = np.searchsorted(ordered, first, side="right").sum() - below
    return float((below + 0.5 * tied) / (first.size * second.size))


def group_means(rows: pd.DataFrame, measure: str, by: list[str]) -> pd.DataFrame:
    """Mean of ``measure`` per group with a t-based confidence interval.

    ``mean +- t_{(1 + CONFIDENCE) / 2, n - 1} * sd / sqrt(n)`` (NaN when ``n < 2``).

    Returns:
        One row per group, groups sorted: ``measure, *by, n, mean, sd, ci95_low, ci95_high``.
    """
    grouped = rows.groupby(by, sort=True)[measure]
    frame = grouped.agg(n="count", mean="mean", sd="std").reset_index()
    half = stats.t.ppf((1 + CONFIDENCE) / 2, frame["n"] - 1) * frame["sd"] / np.sqrt(frame["n"])
    frame["ci95_low"], frame["ci95_high"] = frame["mean"] - half, frame["mean"] + half
    frame.insert(0, "measure", measure)
    frame["n"] = frame["n"].astype(int)
    return frame


Means = TypeVar("Means", CellMean, EtaMean)
"""A row of group means: a cell's (:class:`CellMean`) or an eta's (:class:`EtaMean`)."""


def group_mean_rows(
    rows: pd.DataFrame, measure: str, by: list[str], row_type: type[Means]
) -> Table[Means]:
    """:func:`group_means` as rows of ``row_type``, whose fields are ``measure``, ``by``,
    ``n, mean, sd, ci95_low, ci95_high``."""
    frame = group_means(rows, measure, by)
    return Table(row_type, (row_type(**group) for group in frame.to_dict(orient="records")))


def feldt_ci(alpha: float, n: int, k: int) -> tuple[float, float]:
    """Feldt's confidence interval of coefficient alpha from ``n`` rows and ``k`` items.

    ``1 - (1 - alpha) F_{(1 -+ CONFIDENCE) / 2}(n - 1, (n - 1)(k - 1))`` (upper quantiles).

    References:
        Feldt, Woodruff & Salih (1987), Applied Psychological Measurement 11(1):93-103.
    """
    df1, df2 = n - 1, (n - 1) * (k - 1)
    tail = (1 - CONFIDENCE) / 2
    low = 1 - (1 - alpha) * stats.f.isf(tail, df1, df2)
    high = 1 - (1 - alpha) * stats.f.isf(1 - tail, df1, df2)
    return float(low), float(high)


def cronbach_alpha(items: pd.DataFrame, rows: str) -> CronbachAlpha:
    """Cronbach's alpha of the columns of ``items`` (one row per observation; ``rows`` says
    what a row is, in words, kept with the result).

    Raw: ``alpha = k / (k - 1) (1 - sum_i var(y_i) / var(sum_i y_i))``. Standardised: the
    same on z-scored items, ``k rbar / (1 + (k - 1) rbar)`` with ``rbar`` the mean
    inter-item correlation. Both with Feldt's interval (:func:`feldt_ci`).

    References:
        Cronbach (1951), Psychometrika 16(3):297-334.
        ``pingouin.cronbach_alpha`` (checked against R ``psych::alpha``).
    """
    n, k = items.shape
    raw = float(pg.cronbach_alpha(data=items)[0])
    standardised_items = (items - items.mean()) / items.std()
    standardised = float(pg.cronbach_alpha(data=standardised_items)[0])
    return CronbachAlpha(
        raw=raw,
        standardised=standardised,
        ci95=list(feldt_ci(raw, n, k)),
        ci95_standardised=list(feldt_ci(standardised, n, k)),
        n_rows=int(n),
        n_items=int(k),
        items=[str(item) for item in items.columns],
        rows=rows,
    )


def eta_choice_uncertainty(cv: pd.DataFrame, chosen: Mapping[int, float]) -> Table[EtaUncertainty]:
    """How clear-cut the cross-validated eta is, per feature level.

    With ``m_e`` the mean best-response regret at ``eta = e`` over the cross-validation
    draws: the chosen ``e* = chosen[K]`` (the run's rule, lowest mean,
    :func:`cirl_study.study.eta_cv.choose_etas`) against the runner-up ``e2`` (the lowest
    mean among the other etas), by the paired difference ``d_s = y_{s,e2} - y_{s,e*}`` over
    the draws (every draw plays every eta) with its t-based CI and two-sided p; and the
    one-standard-error
    rule: the etas whose mean is within ``SE(m_{e*}) = sd / sqrt(n)`` of the minimum, all as
    good as the chosen one by that rule.

    References:
        Hastie, Tibshirani & Friedman (2009), *The Elements of Statistical Learning*, 2nd ed.,
        section 7.10 (the one-standard-error rule).

    Returns:
        One row per feature level with a chosen eta, levels sorted (``within_one_se`` a sorted
        list of etas; without another eta, no runner-up and no test).
    """
    best = cv[(cv["human"] == BEST_RESPONSE) & cv["eta"].notna()]
    rows = []
    for level, group in best.groupby("num_features", sort=True):
        if int(level) not in chosen:
            continue
        wide = group.pivot(index="subject", columns="eta", values="regret").sort_index()
        means = wide.mean()
        eta = chosen[int(level)]
        column = wide[eta].to_numpy()
        se = float(np.std(column, ddof=1) / np.sqrt(len(column)))
        row = {
            "num_features": int(level),
            "n": len(column),
            "eta": eta,
            "mean": float(means[eta]),
            "se": se,
            "within_one_se": sorted(float(e) for e, m in means.items() if m <= means[eta] + se),
        }
        others = means.drop(eta).sort_values(kind="mergesort")
        if len(others):
            runner_up = float(others.index[0])
            row |= {"runner_up": runner_up, "runner_up_mean": float(others.iloc[0])}
            row |= paired_t(wide[runner_up].to_numpy(), column)._asdict()
        rows.append(EtaUncertainty(**row))
    return Table(EtaUncertainty, rows)


def eta_means(cv: pd.DataFrame) -> Table[EtaMean]:
    """Mean regret of the best response with its CI per feature level and ``eta``.

    The curve behind the cross-validated choice of ``eta`` (docs/design.md §3); the choice
    itself is :func:`cirl_study.study.eta_cv.choose_etas`, the one the run made.

    Returns:
        :func:`group_means` of regret by ``num_features, eta`` over the best-response
        trials of ``cv``.
    """
    best = cv[(cv["human"] == BEST_RESPONSE) & cv["eta"].notna()]
    return group_mean_rows(best, "regret", ["num_features", "eta"], EtaMean)


JOINT_RESAMPLES = 5000
"""Sign-flip resamples of :func:`joint_sign_flip_test` (Simonsohn et al. ask for >= 500)."""

JOINT_SEED = 2020
"""Seed of the generator of :func:`joint_sign_flip_test`'s sign flips."""


def joint_sign_flip_test(
    differences: np.ndarray,
    resamples: int = JOINT_RESAMPLES,
    seed: int = JOINT_SEED,
    batch: int = 100,
) -> JointTest:
    """Joint test across universes that the effect is negative (Simonsohn et al. 2020).

    ``differences`` is ``U x S``: ``d_{u,s} = y_{s,br} - y_{s,expert}`` of subject ``s`` in
    universe ``u`` (every universe plays the same subjects; negative: the best response did
    better). Per universe, the paired t-statistic ``t_u = mean(d_u) / (sd(d_u) / sqrt(S))`` on
    ``S - 1`` degrees of freedom. Three statistics of the whole specification curve:

    * ``median_effect``: the median over universes of ``mean(d_u)``;
    * ``share_significant``: the share of universes with a two-sided ``p < .05`` in the
      claimed direction, ``t_u < -t_{.975, S-1}``;
    * ``stouffer_z``: ``sum_u z_u / sqrt(U)`` with ``z_u = Phi^{-1}(1 - p_u)`` and ``p_u =
      P(T_{S-1} <= t_u)`` the one-sided p-value (computed from ``log p_u``, so it is exact in
      the far tail where ``p_u`` itself underflows).

    Their null distribution: under "no effect in any universe" each subject's differences are
    symmetric about 0, so flipping the sign of subject ``s``'s differences in *every* universe
    at once (``d*_{u,s} = e_s d_{u,s}``, ``e_s = +-1`` fair and independent) keeps the
    dependence between universes that share the subjects. ``resamples`` flips drawn from a
    generator seeded with ``seed``; each p-value is ``(1 + #{null at least as extreme}) / (1 +
    resamples)`` (Phipson & Smyth 2010), one-sided towards a negative effect. The sums are
    numpy's (pairwise, in a fixed order), not BLAS's, so the counts do not depend on the
    machine.

    References:
        Simonsohn, Simmons & Nelson (2020), Nature Human Behaviour 4:1208-1214.
        Stouffer et al. (1949), *The American Soldier*, vol. 1.
        Phipson & Smyth (2010), Statistical Applications in Genetics and Molecular Biology 9(1).

    Returns:
        The joint test: ``universes, subjects, resamples, seed``, and each statistic observed
        with its ``p`` and ``log10_p`` (the common logarithm of the exact ratio,
        :func:`sign_flip_log10_p`).
    """
    d = np.asarray(differences, dtype=np.float64)
    universes, subjects = d.shape
    squares = np.sum(d**2, axis=1)
    observed = _curve_statistics(d.mean(axis=1), squares, subjects)
    rng = np.random.default_rng(seed)
    extreme = dict.fromkeys(observed, 0)
    for start in range(0, resamples, batch):
        flips = rng.choice(np.array([-1.0, 1.0]), size=(min(batch, resamples - start), subjects))
        means = (flips[:, None, :] * d[None, :, :]).sum(axis=2) / subjects
        null = _curve_statistics(means.T, squares[:, None], subjects)
        extreme["median_effect"] += int(np.sum(null["median_effect"] <= observed["median_effect"]))
        for key in ("share_significant", "stouffer_z"):
            extreme[key] += int(np.sum(null[key] >= observed[key]))
    found = {
        key: SignFlipStatistic(
            observed=float(value),
            p=(1 + extreme[key]) / (1 + resamples),
            log10_p=sign_flip_log10_p(extreme[key], resamples),
        )
        for key, value in observed.items()
    }
    return JointTest(
        universes=universes, subjects=subjects, resamples=resamples, seed=seed, **found
    )


def sign_flip_log10_p(extreme: int, resamples: int) -> float:
    """``log10 p`` of the sign-flip ``p = (1 + extreme) / (1 + resamples)`` (Phipson & Smyth
    2010): ``log10(1 + extreme) - log10(1 + resamples)``, to rounding; never below
    ``-log10(1 + resamples)``, as ``p`` never underflows.

    Examples:
        >>> sign_flip_log10_p(0, 9999)
        -4.0
    """
    return math.log10(1 + extreme) - math.log10(1 + resamples)


def _curve_statistics(
    means: np.ndarray, squares: np.ndarray, subjects: int
) -> dict[str, np.ndarray]:
    """The three statistics of :func:`joint_sign_flip_test` from each universe's mean
    difference and sum of squares (axis 0: universes; further axes: resamples)."""
    variance = np.maximum(squares - subjects * means**2, 0.0) / (subjects - 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = means / np.sqrt(variance / subjects)
    critical = stats.t.ppf(0.975, subjects - 1)
    z = -special.ndtri_exp(stats.t.logcdf(t, subjects - 1))
    return {
        "median_effect": np.median(means, axis=0),
        "share_significant": np.mean(t < -critical, axis=0),
        "stouffer_z": np.sum(z, axis=0) / np.sqrt(means.shape[0]),
    }
