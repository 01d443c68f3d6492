"""The fixed-order linear algebra (``cirl_study.core.linalg``) against numpy's LAPACK.

The matrices are Gram matrices :math:`X^\\top X` of 21 columns, like the posterior robot's
control-variate design ``[1, u, theta]``: well conditioned, rank-deficient (a repeated column,
a combination of columns, a zero column) and nearly singular (columns equal to others up to
1e-7, a condition number near 1e14). The least-squares solutions agree with
``np.linalg.lstsq(rcond=None)`` to 1e-11 relative to the largest coefficient, the fitted values
``X x`` to 1e-12 of the largest.
"""

import numpy as np
import pytest

from cirl_study.core.linalg import cholesky, symmetric_eigen, symmetric_lstsq

COLUMNS, ROWS, RIGHT_SIDES = 21, 400, 10


def _design(kind: str, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    design = rng.standard_normal((ROWS, COLUMNS)) * rng.uniform(0.1, 10.0, COLUMNS)
    if kind == "repeated":
        design[:, 5] = design[:, 3]
        design[:, 7] = 2.0 * design[:, 2] - design[:, 1]
    elif kind == "zero column":
        design[:, 4] = 0.0
    elif kind == "nearly singular":
        design[:, 10:20] = design[:, :10] + 1e-7 * rng.standard_normal((ROWS, 10))
    return design


def _gram(kind: str, seed: int) -> np.ndarray:
    design = _design(kind, seed)
    return design.T @ design


KINDS = ("well conditioned", "repeated", "zero column", "nearly singular")


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("seed", range(5))
def test_least_squares_matches_lapack(kind, seed):
    design = _design(kind, seed)
    gram = design.T @ design
    rhs = design.T @ np.random.default_rng(seed + 100).standard_normal((ROWS, RIGHT_SIDES))
    expected = np.linalg.lstsq(gram, rhs, rcond=None)[0]
    solution = symmetric_lstsq(gram, rhs)
    scale = np.abs(expected).max()
    np.testing.assert_allclose(solution, expected, rtol=0, atol=1e-11 * scale)
    fitted, reference = design @ solution, design @ expected
    np.testing.assert_allclose(fitted, reference, rtol=0, atol=1e-12 * np.abs(reference).max())


@pytest.mark.parametrize("kind", KINDS)
def test_eigen_decomposition_matches_lapack(kind):
    gram = _gram(kind, 7)
    values, vectors = symmetric_eigen(gram)
    largest = np.abs(values).max()
    np.testing.assert_allclose(np.sort(values), np.linalg.eigvalsh(gram), atol=1e-13 * largest)
    np.testing.assert_allclose(vectors.T @ vectors, np.eye(COLUMNS), atol=1e-13)
    np.testing.assert_allclose((vectors * values) @ vectors.T, gram, rtol=0, atol=1e-13 * largest)


def test_cholesky_matches_lapack_and_refuses_an_indefinite_matrix():
    gram = _gram("well conditioned", 3)
    lower = cholesky(gram)
    np.testing.assert_allclose(lower, np.linalg.cholesky(gram), rtol=0, atol=1e-12 * lower.max())
    assert np.all(np.triu(lower, 1) == 0)
    with pytest.raises(ValueError):
        cholesky(np.array([[1.0, 2.0], [2.0, 1.0]]))
