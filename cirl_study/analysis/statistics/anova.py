"""The repeated-measures ANOVA of any factorial design: within factors of any number of levels,
any number of crossed between factors, type II or type III sums of squares, sphericity tested
and corrected.

Notation: the between factors ``B_1, ..., B_k`` (``K_j`` levels each) cross into ``K`` cells,
cell ``c`` holding ``n_c >= 1`` subjects, ``N`` in all (one cell when there is no between
factor). Subject ``s``, in cell ``c(s)``, is observed once in each of the ``C`` cells of the
crossed within factors ``W_1, ..., W_m`` (``L_i`` levels each): its row ``y_s in R^C``. For a
set ``T`` of within factors, the contrast matrix ``M_T = (x)_i A_i`` (Kronecker product, in
factor order) takes ``A_i = P_i``, an orthonormal basis of the contrasts of ``W_i`` (``L_i x
(L_i - 1)``), for ``W_i in T`` and ``A_i = 1 / sqrt(L_i)`` otherwise, so ``z_s = M_T' y_s``
has ``d_T = prod_{i in T} (L_i - 1)`` coordinates.

In the stratum ``T`` the rows follow the multivariate linear model ``Z = X B + E`` (``Z`` is
``N x d_T``), ``X`` the full factorial between design in sum-to-zero coding: for every term
``A``, a set of between factors (the intercept ``{}``, each main effect, each interaction),
the columns ``(x)_j (P_j if B_j in A else 1)``. ``X`` has rank ``K`` and fits the cell means
``zbar_c``. With ``V = (X'X)^-1``, ``Bhat = V X'Z`` and ``L`` selecting the coefficient rows
of some terms, ``H(L) = (L Bhat)' (L V L')^-1 (L Bhat)``, and ``tr H(L)`` is how much the
residual sum of squares grows when those terms are dropped. For each term ``A``:

* type III: ``SS_A = tr H(A)``;
* type II (``car``'s ``Anova.II.mlm``): ``SS_A = tr H(A and the terms containing A) - tr H(the
  terms containing A)``. The intercept lies in every term: ``SS = N |zbar|^2`` whatever the
  between design, ``zbar`` the mean over all subjects.

Both compare two nested fits of the cell means ``Zbar`` (``K x d_T``) weighted by the cells'
sizes: on ``O``, the terms the hypothesis keeps (type III: every other term; type II: the terms
not containing ``A``), and on ``O`` with ``A``. Their difference is a single projection,
``SS_A = |Q_A' diag(n)^(1/2) Zbar|^2``, ``Q_A`` the columns of ``A`` in the orthonormal factor
of the QR decomposition of ``diag(n)^(1/2) [X_O X_A]`` (``X_S`` the columns of the terms
``S``, a row for each cell), not a difference of two sums of squares; with the intercept in
``O`` the means are centred first, so a large mean costs no accuracy. With one between factor
the type II ``SS`` are ``N |zbar|^2`` and ``sum_g n_g |zbar_g - zbar|^2`` (the means weighted
by size, as ``pingouin.mixed_anova`` weighs them), computed so; type III weighs the cell means
alike. In a balanced design the types agree.

The effects of the stratum ``T``: its intercept is the within effect ``T`` (``d_T`` degrees
of freedom; for ``T`` empty, the grand mean, not reported); a between term ``A`` is the
interaction ``T:A``, on ``d_T prod_{j in A} (K_j - 1)``. Their error term is the residual
SSCP ``E_T = sum_s (z_s - zbar_{c(s)}) (z_s - zbar_{c(s)})'``, ``SS = tr E_T`` on ``(N - K)
d_T``; ``T`` empty is the between-subjects stratum, the between terms against subjects within
cells.

``F = MS_effect / MS_error``; partial eta squared ``np2 = SS / (SS + SS_error)``; generalised
eta squared ``ges = SS / (SS + sum of every error term's SS)`` (Olejnik & Algina 2003, every
factor manipulated).

Sphericity, for every stratum with ``d_T >= 2``, from ``E_T`` on ``n = N - K`` degrees of
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
  every effect of the stratum takes the same epsilons.

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
from typing import Literal, NamedTuple

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
    between: Sequence[str] = (),
    subject: str = "subject",
    sums_of_squares: Literal[2, 3] = 2,
) -> list[AnovaEffect]:
    """The ANOVA table of ``measure``: within factors ``within``, crossed between factors
    ``between``, type II or III sums of squares (the module docstring).

    Args:
        frame: one row per observation, with the columns ``subject``, ``measure``, every
            factor of ``within`` and of ``between``.
        measure: the dependent variable.
        within: the within-subjects factors, each with at least two levels (their levels
            sorted); none gives the between-subjects ANOVA of ``between``.
        between: the between-subjects factors (each subject in one level of each), crossed in
            full: every cell of their levels needs a subject, in any numbers. A factor of one
            level has no effect and adds no row.
        subject: the subject column.
        sums_of_squares: ``2`` (type II, as ``car::Anova`` and ``afex::aov_ez(type = 2)``)
            or ``3`` (type III, sum-to-zero contrasts, as ``afex``'s default); they differ
            only with unequal cells.

    Returns:
        For every set of within factors, by size and then in the order of ``within`` (the
        empty set first), the within effect (none for the empty set), then its interaction
        with every term of the between factors, by size and then in the order of
        ``between``: effect names join the within factors and then the term's between
        factors with ``:`` (``human``, ``human:group``, ``group:cohort``,
        ``human:group:cohort``).

    Raises:
        TypeError: ``between`` is a string, not a sequence of factors.
        ValueError: a subject misses a within cell or has two observations in one, a
            subject lies in two levels of a between factor, a between cell has no subject,
            a within factor has one level, an error term has no degrees of freedom, or
            ``sums_of_squares`` is neither 2 nor 3.
        UserError: a value of ``measure`` is not a finite number (NaN or infinite), naming
            its trial (:func:`refuse_non_finite`): it would turn every sum of squares into
            NaN; leave a missing value's subject out first.

    Examples:
        >>> rng = np.random.default_rng(0)
        >>> rows = [
        ...     {"subject": f"{g}-{s}", "group": g, "a": a, "y": rng.normal() + a}
        ...     for g in (0, 1) for s in range(5) for a in (0, 1, 2)
        ... ]
        >>> table = repeated_measures_anova(pd.DataFrame(rows), "y", ["a"], ["group"])
        >>> [(row.effect, row.df1, row.df2) for row in table]
        [('group', 1, 8), ('a', 2, 16), ('a:group', 2, 16)]
        >>> table[1].sphericity.gg_epsilon <= 1
        True

        Two between factors, cells of 2, 3, 3 and 4 subjects, type III:

        >>> sizes = {(0, 0): 2, (0, 1): 3, (1, 0): 3, (1, 1): 4}
        >>> rows = [
        ...     {"subject": f"{g}{c}-{s}", "g": g, "c": c, "a": a, "y": rng.normal() + a * g}
        ...     for (g, c), n in sizes.items() for s in range(n) for a in (0, 1)
        ... ]
        >>> frame = pd.DataFrame(rows)
        >>> table = repeated_measures_anova(frame, "y", ["a"], ["g", "c"], sums_of_squares=3)
        >>> [(row.effect, row.df1, row.df2) for row in table]  # doctest: +NORMALIZE_WHITESPACE
        [('g', 1, 8), ('c', 1, 8), ('g:c', 1, 8),
         ('a', 1, 8), ('a:g', 1, 8), ('a:c', 1, 8), ('a:g:c', 1, 8)]
    """
    if isinstance(between, str):
        raise TypeError(f"between is a sequence of factors, not a string: ({between!r},)?")
    if sums_of_squares not in (2, 3):
        raise ValueError(f"sums_of_squares is 2 or 3, not {sums_of_squares!r}")
    refuse_non_finite(frame, measure)
    y, design = _subject_rows(frame, measure, list(within), list(between), subject)
    error_df = len(y) - len(design.sizes)
    if error_df < 1:
        raise ValueError(f"{measure}: no degrees of freedom left for the error terms")
    strata = []
    for size in range(len(within) + 1):
        for chosen in itertools.combinations(range(len(within)), size):
            matrix = _contrast_matrix(design.within_levels, chosen)
            strata.append((chosen, _stratum(y, design, matrix, sums_of_squares)))
    error_total = sum(stratum.error_ss for _, stratum in strata)
    rows: list[AnovaEffect] = []
    for chosen, stratum in strata:
        d = stratum.dimension
        sphericity = (
            _sphericity(stratum, error_df, y.shape, _rounding_floor(y, d)) if d >= 2 else None
        )
        for term, ss in zip(design.terms, stratum.term_ss, strict=True):
            if not chosen and not term:  # the grand mean
                continue
            label = ":".join([*(within[i] for i in chosen), *(between[j] for j in term)])
            df1 = d * math.prod(design.between_levels[j] - 1 for j in term)
            rows.append(
                _effect_row(
                    measure, label, ss, df1, stratum.error_ss, error_df * d, error_total,
                    sphericity,
                )
            )  # fmt: skip
    return rows


class _Design(msgspec.Struct, frozen=True):
    """The factors of a design: the within factors' level counts; the between factors' level
    counts, every subject's between cell (in the C order of the factors' sorted levels), the
    cells' sizes, and the between terms (the intercept ``()`` first, by size and then in
    factor order; none of a factor of one level) with their columns in the cell space."""

    within_levels: list[int]
    between_levels: list[int]
    cells: NDArray[np.intp]
    sizes: NDArray[np.float64]
    terms: list[tuple[int, ...]]
    columns: list[NDArray[np.float64]]


class _Stratum(msgspec.Struct, frozen=True):
    dimension: int
    term_ss: list[float]
    error_ss: float
    error_sscp: NDArray[np.float64]


def _subject_rows(
    frame: pd.DataFrame, measure: str, within: list[str], between: list[str], subject: str
) -> tuple[NDArray[np.float64], _Design]:
    """``y`` (subjects x cells, cells in the C order of the within factors' sorted levels,
    subjects sorted) and the design."""
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
    codes, between_levels = [], []
    for factor in between:
        membership = frame.groupby(subject, sort=True)[factor].unique()
        if (membership.map(len) != 1).any():
            raise ValueError(f"{measure}: a subject lies in two levels of {factor}")
        level_of = membership.map(lambda values: values[0])
        names = sorted(level_of.unique())
        codes.append(level_of.map({level: i for i, level in enumerate(names)}).to_numpy(np.intp))
        between_levels.append(names)
    shape = [len(names) for names in between_levels]
    subject_cells = (
        np.ravel_multi_index(codes, shape) if between else np.zeros(len(y), dtype=np.intp)
    )
    cell_sizes = np.bincount(subject_cells, minlength=math.prod(shape))
    if not cell_sizes.all():
        empty = np.unravel_index(int(np.argmin(cell_sizes)), shape)
        named = ", ".join(
            f"{factor}={names[i]}"
            for factor, names, i in zip(between, between_levels, empty, strict=True)
        )
        raise ValueError(
            f"{measure}: no subject in the between cell {named}; the crossed between factors "
            "need a subject in every cell"
        )
    terms = [
        term
        for size in range(len(between) + 1)
        for term in itertools.combinations(range(len(between)), size)
        if all(shape[j] >= 2 for j in term)
    ]
    design = _Design(
        within_levels=counts,
        between_levels=shape,
        cells=subject_cells,
        sizes=cell_sizes.astype(np.float64),
        terms=terms,
        columns=[_contrast_matrix(shape, term) for term in terms],
    )
    return y, design


def _contrast_matrix(levels: list[int], chosen: tuple[int, ...]) -> NDArray[np.float64]:
    """``M_T``: contrasts for the factors in ``chosen``, the normalised mean for the others.
    Of the between factors, the columns of the term ``chosen`` in the cell space: ``X``'s
    (module docstring) scaled, spanning the same fits."""
    matrix = np.ones((1, 1))
    for i, count in enumerate(levels):
        part = contrasts(count) if i in chosen else np.full((count, 1), 1 / math.sqrt(count))
        matrix = np.kron(matrix, part)
    return matrix


def _stratum(
    y: NDArray[np.float64], design: _Design, matrix: NDArray[np.float64], sums_of_squares: int
) -> _Stratum:
    """The sums of squares of one stratum ``z = y M_T`` (see the module docstring), one for
    each term of ``design`` in its order.

    A sum of squares within the rounding of ``z`` is 0. Each entry of ``z`` is a sum over the
    ``C`` cells of ``y`` times contrasts of at most 1 in size, so it is off by at most about
    ``C eps max|y|``, and where ``z`` is rounding alone, ``|z|^2``, a sum of ``S d`` squares,
    is at most ``S d (C eps max|y|)^2``. Every sum of squares of the stratum is at most
    ``|z|^2``, whatever the term, the type and the between cells: each is the squared norm of
    an orthogonal projection (which enlarges no norm) of the cell means weighted by
    ``sqrt(n_c)``, centred or not, whose squared norm is at most ``|z|^2``; the error, of the
    residuals ``z - zbar_{c(s)}``, too. The QR factorisation adds rounding relative to those
    small inputs. Below that bound (:func:`_rounding_floor`) an effect is indistinguishable
    from none; its F is then 0 / 0, undefined, not a ratio of rounding errors.
    """
    z = y @ matrix
    sizes = design.sizes
    cell_means = np.zeros((len(sizes), z.shape[1]))
    np.add.at(cell_means, design.cells, z)
    cell_means /= sizes[:, None]
    grand = z.mean(axis=0)
    residual = z - cell_means[design.cells]
    sscp = residual.T @ residual
    floor = _rounding_floor(y, z.shape[1])
    everything = frozenset(design.terms)
    weight = np.sqrt(sizes)[:, None]

    def projected(kept: frozenset[tuple[int, ...]], term: tuple[int, ...]) -> float:
        """``SS_A`` for ``A = term``: the squared norm of the part of the weighted cell means
        that the columns of ``term`` add to those of ``kept``, read off the last columns of
        a QR factorisation (one projection, no difference of two fits)."""
        x = [c for t, c in zip(design.terms, design.columns, strict=True) if t in kept]
        added = design.columns[design.terms.index(term)]
        basis = np.linalg.qr(weight * np.hstack([*x, added]))[0][:, -added.shape[1] :]
        # With the intercept kept, the centred means (those of a larger mean lose less).
        target = cell_means - grand if () in kept else cell_means
        return float(np.sum((basis.T @ (weight * target)) ** 2))

    term_ss = []
    for term in design.terms:
        if sums_of_squares == 3:
            kept = everything - {term}
        else:
            kept = frozenset(t for t in design.terms if not set(term) <= set(t))
        if not kept:  # the within effect, type II or without between factors: N |zbar|^2
            ss = float(len(z) * grand @ grand)
        elif kept == {()} and kept | {term} == everything:  # one between factor: the
            # projection off the intercept leaves the centred means as they are
            ss = float(sizes @ np.sum((cell_means - grand) ** 2, axis=1))
        else:
            ss = projected(kept, term)
        term_ss.append(_above(ss, floor))
    return _Stratum(
        dimension=z.shape[1],
        term_ss=term_ss,
        error_ss=_above(float(np.trace(sscp)), floor),
        error_sscp=sscp,
    )


def _rounding_floor(y: NDArray[np.float64], dimension: int) -> float:
    """The largest sum of squares of a stratum of ``dimension`` contrasts of ``y`` that rounding
    alone can make, with a factor of 16 to spare: the bound of ``|z|^2``, and so of every sum
    of squares of the stratum, of either type and whatever the between cells (:func:`_stratum`)."""
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
