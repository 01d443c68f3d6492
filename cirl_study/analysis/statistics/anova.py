"""The repeated-measures ANOVA of any factorial design: within factors of any number of levels,
at most one between factor, sphericity tested and corrected.

Notation: subject ``s`` belongs to group ``g(s)`` of the between factor (``G`` groups of
``n_g`` subjects, ``N`` in all; one group when there is no between factor) and is observed
once in each of the ``C`` cells of the crossed within factors ``W_1, ..., W_m`` (``L_i``
levels each): its row ``y_s in R^C``. For a set ``T`` of within factors, the contrast matrix
``M_T = (x)_i A_i`` (Kronecker product, in factor order) takes ``A_i = P_i``, an orthonormal
basis of the contrasts of ``W_i`` (``L_i x (L_i - 1)``), for ``W_i in T`` and ``A_i = 1 /
sqrt(L_i)`` otherwise, so ``z_s = M_T' y_s`` has ``d_T = prod_{i in T} (L_i - 1)``
coordinates. With ``zbar_g`` the group means and ``zbar`` the mean over all subjects:

* the effect ``T``: ``SS_T = N |zbar|^2`` on ``d_T`` degrees of freedom;
* its interaction with the between factor: ``SS_{T:B} = sum_g n_g |zbar_g - zbar|^2`` on
  ``(G - 1) d_T``;
* their error term: ``E_T = sum_s (z_s - zbar_{g(s)}) (z_s - zbar_{g(s)})'``, ``SS = tr E_T``
  on ``(N - G) d_T``;
* ``T`` empty is the between-subjects stratum: the between factor ``B`` against subjects
  within groups.

``F = MS_effect / MS_error``; partial eta squared ``np2 = SS / (SS + SS_error)``; generalised
eta squared ``ges = SS / (SS + sum of every error term's SS)`` (Olejnik & Algina 2003, every
factor manipulated). With unequal group sizes the means are weighted by ``n_g``, as
``pingouin.mixed_anova`` computes them; in a balanced design every type of sums of squares
agrees with these.

Sphericity, for every effect with ``d_T >= 2``, from ``E_T`` on ``n = N - G`` degrees of
freedom (R's ``mauchly.test``, ``car::Anova``):

* Mauchly's ``W = det(E_T) / (tr(E_T) / d)^d`` and its p-value from the chi-square expansion
  of Anderson (2003, §10.7): ``rho = 1 - (2 d^2 + d + 2) / (6 d n)``, ``z = -n rho log W``,
  ``f = d (d + 1) / 2 - 1``, ``p = P1 + w2 (P2 - P1)`` with ``P1 = P(chi2_f > z)``, ``P2 =
  P(chi2_{f + 4} > z)``, ``w2 = (d + 2)(d - 1)(d - 2)(2 d^3 + 6 d^2 + 3 C + 2) / (288 (d n
  rho)^2)``. Anderson's ``w2`` has ``3 d`` where R's ``mauchly.test`` and ``car`` have ``3 C``
  (``C`` the within cells, the dimension before the contrasts); the two agree when ``d <= 2``
  (``w2 = 0``), and this follows R so the p-values are the ones afex users see (at ``d = 3``,
  ``C = 4`` they differ by 0.2%);
* Greenhouse-Geisser ``epsilon = tr(E_T)^2 / (d tr(E_T^2))``, in ``[1 / d, 1]``;
* Huynh-Feldt ``epsilon = ((n + 1) d eps_GG - 2) / (d (n - d eps_GG))``, reported as
  computed (it may exceed 1; infinite where ``n <= d eps_GG``, the estimator's pole) and
  capped at 1 for its p-value;
* a corrected p tests ``F`` on ``epsilon d_T`` and ``epsilon df_error`` degrees of freedom;
  the effect's interaction with the between factor takes the same epsilons.

Where these are not defined they are ``None`` (NaN until the results are made plain), and
:attr:`~cirl_study.analysis.results.types.Sphericity.reason` says why (:func:`_sphericity`):

* no error variance (``tr E_T`` within rounding of 0, as the F test decides it): none of them;
* fewer error degrees of freedom than contrasts (``n < d``): ``E_T`` is singular whatever the
  data, ``eps_GG <= n / d`` measures the sample size rather than sphericity, and ``W`` is 0:
  none of them;
* a singular ``E_T`` (its smallest eigenvalue within rounding of 0, with ``n >= d``): ``W =
  0`` exactly, so ``z`` is infinite and Mauchly's p, which would be 0, is not reported (its
  chi-square expansion assumes a non-singular covariance, which such data, e.g. two humans
  scored alike by every subject, do not have); the epsilons are reported, Box's epsilon being
  defined for any covariance of positive trace.

Every p-value carries ``log10 p`` (:mod:`cirl_study.analysis.statistics.tails`), exact where ``p``
underflows.

References:
    Maxwell, Delaney & Kelley (2018), *Designing Experiments and Analyzing Data*, ch. 12-14.
    Mauchly (1940), Annals of Mathematical Statistics 11(2):204-209.
    Greenhouse & Geisser (1959), Psychometrika 24(2):95-112.
    Huynh & Feldt (1976), Journal of Educational Statistics 1(1):69-82.
    Olejnik & Algina (2003), Psychological Methods 8(4):434-447.
    Higham (2002), *Accuracy and Stability of Numerical Algorithms*, 2nd ed., §3.1.
    R: ``afex::aov_ez`` and ``car::Anova`` (the fixtures of ``tests/fixtures/factorial``).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import NamedTuple

import msgspec
import numpy as np
import pandas as pd
from numpy.typing import NDArray

from cirl_study.analysis.results.types import AnovaEffect, Probability, Sphericity
from cirl_study.analysis.statistics.tails import chi2_tail, f_tail
from cirl_study.errors import UserError


def refuse_non_finite(frame: pd.DataFrame, measure: str, missing_allowed: bool = False) -> None:
    """Refuse a value of ``measure`` in ``frame`` that no statistic can take: an infinity or
    NaN, or with ``missing_allowed`` an infinity only (NaN then marks a missing value, which
    the caller leaves out).

    Raises:
        UserError: one line naming the first such trial (its ``trial_id``, else its
            ``subject``) and how many there are.
    """
    values = pd.to_numeric(frame[measure], errors="coerce").to_numpy(dtype=np.float64)
    bad = np.isinf(values) if missing_allowed else ~np.isfinite(values)
    if not bad.any():
        return
    first = frame[bad].iloc[0]
    trial = f"trial {first['trial_id']}" if "trial_id" in frame else f"subject {first['subject']}"
    more = int(bad.sum()) - 1
    others = f" (and {more} more)" if more else ""
    raise UserError(
        f"{measure} of {trial} is {frame[measure][bad].iloc[0]!r}, not a finite number{others}: "
        "the statistics refuse it rather than average it"
    )


def contrasts(levels: int) -> NDArray[np.float64]:
    """An orthonormal basis of the contrasts of a factor with ``levels`` levels (``levels x
    (levels - 1)``): the normalised Helmert contrasts, orthogonal to the constant vector.

    Examples:
        >>> basis = contrasts(3)
        >>> np.allclose(basis.T @ basis, np.eye(2)), np.allclose(basis.sum(axis=0), 0)
        (True, True)
    """
    basis = np.zeros((levels, levels - 1))
    for j in range(1, levels):
        basis[:j, j - 1] = 1.0
        basis[j, j - 1] = -float(j)
        basis[:, j - 1] /= math.sqrt(j * (j + 1))
    return basis


def repeated_measures_anova(
    frame: pd.DataFrame,
    measure: str,
    within: Sequence[str],
    between: str | None = None,
    subject: str = "subject",
) -> list[AnovaEffect]:
    """The ANOVA table of ``measure``: within factors ``within``, between factor ``between``.

    Args:
        frame: one row per observation, with the columns ``subject``, ``measure``, every
            factor of ``within`` and ``between``.
        measure: the dependent variable.
        within: the within-subjects factors, each with at least two levels (their levels
            sorted); none gives the one-way between-subjects ANOVA of ``between``.
        between: the between-subjects factor (each subject in one of its levels), or ``None``.
        subject: the subject column.

    Returns:
        The between effect first (when ``between`` has at least two levels), then for every
        non-empty set of within factors, by size and then in the order of ``within``, its
        effect and its interaction with ``between``: effect names join the within factors
        with ``:`` and end with ``:between``.

    Raises:
        ValueError: a subject misses a within cell or has two observations in one, a
            subject lies in two groups, a factor has one level, or an error term has no
            degrees of freedom.
        UserError: a value of ``measure`` is not a finite number (NaN or infinite), naming
            its trial (:func:`refuse_non_finite`): it would turn every sum of squares into
            NaN; leave a missing value's subject out first.

    Examples:
        >>> rng = np.random.default_rng(0)
        >>> rows = [
        ...     {"subject": f"{g}-{s}", "group": g, "a": a, "y": rng.normal() + a}
        ...     for g in (0, 1) for s in range(5) for a in (0, 1, 2)
        ... ]
        >>> table = repeated_measures_anova(pd.DataFrame(rows), "y", ["a"], "group")
        >>> [(row.effect, row.df1, row.df2) for row in table]
        [('group', 1, 8), ('a', 2, 16), ('a:group', 2, 16)]
        >>> table[1].sphericity.gg_epsilon <= 1
        True
    """
    refuse_non_finite(frame, measure)
    y, groups, levels = _subject_rows(frame, measure, list(within), between, subject)
    subjects, group_count = len(y), int(groups.max()) + 1
    error_df = subjects - group_count
    if error_df < 1:
        raise ValueError(f"{measure}: no degrees of freedom left for the error terms")
    sizes = np.bincount(groups, minlength=group_count).astype(np.float64)
    strata = []
    for size in range(len(within) + 1):
        for chosen in itertools.combinations(range(len(within)), size):
            strata.append((chosen, _stratum(y, groups, sizes, _contrast_matrix(levels, chosen))))
    error_total = sum(stratum.error_ss for _, stratum in strata)
    rows: list[AnovaEffect] = []
    for chosen, stratum in strata:
        name = ":".join(within[i] for i in chosen)
        d = stratum.dimension
        sphericity = (
            _sphericity(stratum, error_df, y.shape, _rounding_floor(y, d)) if d >= 2 else None
        )
        effects = [] if not chosen else [(name, stratum.effect_ss, d)]
        if group_count > 1 and between is not None:
            label = f"{name}:{between}" if chosen else between
            effects.append((label, stratum.interaction_ss, (group_count - 1) * d))
        for label, ss, df1 in effects:
            rows.append(
                _effect_row(
                    measure, label, ss, df1, stratum.error_ss, error_df * d, error_total,
                    sphericity,
                )
            )  # fmt: skip
    return rows


class _Stratum(msgspec.Struct, frozen=True):
    dimension: int
    effect_ss: float
    interaction_ss: float
    error_ss: float
    error_sscp: NDArray[np.float64]


def _subject_rows(
    frame: pd.DataFrame, measure: str, within: list[str], between: str | None, subject: str
) -> tuple[NDArray[np.float64], NDArray[np.intp], list[int]]:
    """``y`` (subjects x cells, cells in the C order of the within factors' sorted levels),
    each subject's group index, and the within factors' level counts."""
    levels = [sorted(frame[factor].unique()) for factor in within]
    counts = [len(values) for values in levels]
    single = [factor for factor, n in zip(within, counts, strict=True) if n < 2]
    if single:
        raise ValueError(f"{measure}: a within factor needs two levels or more: {single}")
    cells = frame.groupby([subject, *within], sort=True)[measure]  # one cell: C = 1
    sizes = cells.size()
    subject_ids = sorted(frame[subject].unique())
    cell_count = int(np.prod(counts))
    if len(sizes) != len(subject_ids) * cell_count or (sizes != 1).any():
        raise ValueError(
            f"{measure}: every subject needs exactly one observation in every within cell"
        )
    y = cells.first().to_numpy(dtype=np.float64).reshape(len(subject_ids), cell_count)
    if between is None:
        return y, np.zeros(len(subject_ids), dtype=np.intp), counts
    membership = frame.groupby(subject, sort=True)[between].unique()
    if (membership.map(len) != 1).any():
        raise ValueError(f"{measure}: a subject lies in two levels of {between}")
    group_of = membership.map(lambda values: values[0])
    group_levels = sorted(group_of.unique())
    groups = group_of.map({level: i for i, level in enumerate(group_levels)}).to_numpy(np.intp)
    return y, groups, counts


def _contrast_matrix(levels: list[int], chosen: tuple[int, ...]) -> NDArray[np.float64]:
    """``M_T``: contrasts for the factors in ``chosen``, the normalised mean for the others."""
    matrix = np.ones((1, 1))
    for i, count in enumerate(levels):
        part = contrasts(count) if i in chosen else np.full((count, 1), 1 / math.sqrt(count))
        matrix = np.kron(matrix, part)
    return matrix


def _stratum(
    y: NDArray[np.float64],
    groups: NDArray[np.intp],
    sizes: NDArray[np.float64],
    matrix: NDArray[np.float64],
) -> _Stratum:
    """The sums of squares of one stratum ``z = y M_T`` (see the module docstring).

    A sum of squares within the rounding of ``z`` is 0: each entry of ``z`` is a sum over the
    ``C`` cells of ``y`` times contrasts of at most 1 in size, so it is off by at most about
    ``C eps max|y|``, and a sum of ``S d`` such squares by ``S d (C eps max|y|)^2``. Below that
    bound (:func:`_rounding_floor`) an effect is indistinguishable from none; its F is then
    0 / 0, undefined, not a ratio of rounding errors.
    """
    z = y @ matrix
    group_means = np.zeros((len(sizes), z.shape[1]))
    np.add.at(group_means, groups, z)
    group_means /= sizes[:, None]
    grand = z.mean(axis=0)
    residual = z - group_means[groups]
    sscp = residual.T @ residual
    floor = _rounding_floor(y, z.shape[1])
    return _Stratum(
        dimension=z.shape[1],
        effect_ss=_above(float(len(z) * grand @ grand), floor),
        interaction_ss=_above(float(sizes @ np.sum((group_means - grand) ** 2, axis=1)), floor),
        error_ss=_above(float(np.trace(sscp)), floor),
        error_sscp=sscp,
    )


def _rounding_floor(y: NDArray[np.float64], dimension: int) -> float:
    """The largest sum of squares of a stratum of ``dimension`` contrasts of ``y`` that rounding
    alone can make (:func:`_stratum`), with a factor of 16 to spare."""
    scale = y.shape[1] * np.finfo(np.float64).eps * float(np.abs(y).max(initial=0.0))
    return 16.0 * y.shape[0] * dimension * scale * scale


def _above(ss: float, floor: float) -> float:
    """``ss``, or 0 where it is within rounding (``<= floor``)."""
    return ss if ss > floor else 0.0


NO_ERROR_VARIANCE = "no error variance: the error sum of squares is within rounding of 0"
"""Why a stratum without error variance has no sphericity test and no epsilons."""

TOO_FEW_SUBJECTS = (
    "fewer error degrees of freedom than contrasts: the error matrix is singular whatever the "
    "data, so neither Mauchly's test nor the epsilons estimate anything"
)
"""Why a stratum with ``n < d`` has no sphericity test and no epsilons."""

SINGULAR = (
    "singular error matrix: W = 0, its chi-square statistic infinite, and Mauchly's p not "
    "reported; the epsilons are"
)
"""Why a stratum with a singular error matrix has ``W = 0`` and no Mauchly p."""


class _Sphericity(NamedTuple):
    """The fields of :class:`Sphericity` as computed, an epsilon infinite or NaN where it is
    (the record holds ``None`` for both), before the corrected p-values."""

    mauchly_w: float
    mauchly: Probability
    gg_epsilon: float
    hf_epsilon: float
    gg: Probability
    hf: Probability
    reason: str | None = None


def _sphericity(stratum: _Stratum, n: int, shape: tuple[int, int], floor: float) -> _Sphericity:
    """Mauchly's test and both epsilons of one stratum's error SSCP matrix ``E`` (``d x d``)
    on ``n`` degrees of freedom, in a design of ``shape = (S, C)``: ``S`` subjects, ``C``
    within cells; ``floor`` is the stratum's rounding floor (:func:`_rounding_floor`). The
    p-values of the corrections are filled in by :func:`_effect_row`.

    What is undefined is NaN, with the reason (see the module docstring): everything where the
    error sum of squares is rounding (``stratum.error_ss`` is 0, as the F test takes it) or
    ``n < d``; Mauchly's p where ``E`` is singular, with ``W = 0``.

    ``E`` is singular when its smallest computed eigenvalue is at most ``floor + 16 (S + d)
    eps tr(E)`` (``S`` subjects, ``eps`` the machine epsilon): for a unit ``u`` with ``E u =
    0`` in exact arithmetic, the computed residuals ``R`` (``S x d``) give ``|R u|^2 <= floor``
    (their rounding, as for any sum of squares of the stratum), forming ``R' R`` adds at most
    ``S eps tr(E)`` to ``u' E u`` (inner products of length ``S``; Higham 2002, §3.1) and the
    symmetric eigensolver at most ``O(d) eps |E|_2 <= d eps tr(E)`` to each eigenvalue, so the
    smallest eigenvalue of the computed matrix lies below the bound (with a factor of 16 to
    spare). A non-singular ``E`` that small relative to its trace (``S = 2000``: a condition
    number past 1e11) is singular to working precision: its ``W`` would be rounding too.
    """
    sscp = stratum.error_sscp
    d = sscp.shape[0]
    nan = Probability(p=math.nan, log10_p=math.nan)
    undefined = {"mauchly_w": math.nan, "mauchly": nan, "gg": nan, "hf": nan}
    if not stratum.error_ss > 0:
        return _Sphericity(
            **undefined, gg_epsilon=math.nan, hf_epsilon=math.nan, reason=NO_ERROR_VARIANCE
        )
    if n < d:
        return _Sphericity(
            **undefined, gg_epsilon=math.nan, hf_epsilon=math.nan, reason=TOO_FEW_SUBJECTS
        )
    trace = float(np.trace(sscp))
    gg = trace**2 / (d * float(np.sum(sscp * sscp)))
    hf = ((n + 1) * d * gg - 2) / (d * (n - d * gg)) if n > d * gg else math.inf
    subjects, cells = shape
    singular_below = floor + 16.0 * (subjects + d) * np.finfo(np.float64).eps * trace
    sign, log_det = np.linalg.slogdet(sscp)
    if float(np.linalg.eigvalsh(sscp)[0]) <= singular_below or sign <= 0:
        return _Sphericity(
            **{**undefined, "mauchly_w": 0.0}, gg_epsilon=gg, hf_epsilon=hf, reason=SINGULAR
        )
    log_w = float(log_det) - d * math.log(trace / d)
    rho = 1 - (2 * d * d + d + 2) / (6 * d * n)
    w2 = (
        (d + 2)
        * (d - 1)
        * (d - 2)
        * (2 * d**3 + 6 * d * d + 3 * cells + 2)
        / (288 * (d * n * rho) ** 2)
    )
    statistic = -n * rho * log_w
    f = d * (d + 1) / 2 - 1
    (p1, log10_p1), (p2, log10_p2) = chi2_tail(statistic, f), chi2_tail(statistic, f + 4)
    log10_p = log10_p1 + math.log10((1 - w2) + w2 * 10 ** (log10_p2 - log10_p1))
    return _Sphericity(
        mauchly_w=math.exp(log_w),
        mauchly=Probability(p=float(p1 + w2 * (p2 - p1)), log10_p=log10_p),
        gg_epsilon=gg,
        hf_epsilon=hf,
        gg=nan,
        hf=nan,
    )


def _effect_row(
    measure: str,
    effect: str,
    ss: float,
    df1: int,
    error_ss: float,
    df2: int,
    error_total: float,
    sphericity: _Sphericity | None,
) -> AnovaEffect:
    # Without error variance F is infinite, unless the effect has none either: 0 / 0.
    without_error = math.inf if ss > 0 else math.nan
    f_value = (ss / df1) / (error_ss / df2) if error_ss > 0 else without_error
    p, log10_p = f_tail(f_value, df1, df2)
    tested = None
    if sphericity is not None:
        corrected = {}
        for name, epsilon in (("gg", sphericity.gg_epsilon), ("hf", sphericity.hf_epsilon)):
            if math.isnan(epsilon):  # no epsilon, no corrected p
                corrected[name] = Probability(p=math.nan, log10_p=math.nan)
                continue
            if name == "hf":
                epsilon = min(1.0, epsilon)  # capped at 1 for its p
            q, log10_q = f_tail(f_value, epsilon * df1, epsilon * df2)
            corrected[name] = Probability(p=q, log10_p=log10_q)
        tested = Sphericity(**sphericity._replace(**corrected)._asdict())
    return AnovaEffect(
        measure=measure,
        effect=effect,
        df1=df1,
        df2=df2,
        SS=ss,
        MS=ss / df1,
        F=f_value,
        p=p,
        log10_p=log10_p,
        np2=_share(ss, ss + error_ss),
        ges=_share(ss, ss + error_total),
        sphericity=tested,
    )


def _share(part: float, whole: float) -> float:
    """``part / whole``, an effect size; undefined (NaN) where there is no variance at all."""
    return part / whole if whole > 0 else math.nan
