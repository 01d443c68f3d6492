"""Small dense linear algebra in a fixed order of operations.

Compiled kernels without ``fastmath``: every sum is a loop in a fixed order, and the compiler
neither reorders nor fuses floating-point operations, so a result is a function of the
operands' bits alone, bitwise the same on every x86-64 CPU, whatever BLAS or LAPACK kernel numpy
would have picked. They are meant for the small matrices of a sampler (a few dozen rows),
where LAPACK's blocking buys nothing.

* :func:`cholesky`: the lower factor :math:`L L^\\top = A` of a positive definite :math:`A`
  (row by row, Cholesky-Banachiewicz).
* :func:`symmetric_eigen`: :math:`A = V \\Lambda V^\\top` by cyclic Jacobi rotations; an
  off-diagonal entry is rotated away unless :math:`|a_{pq}| \\le \\epsilon
  \\sqrt{|a_{pp}|}\\sqrt{|a_{qq}|}` (Demmel & Veselić, 1992), which keeps the small eigenvalues
  of a positive semi-definite matrix to their relative accuracy; sweeps stop when one rotates
  nothing.
* :func:`symmetric_lstsq`: the minimum-norm least-squares solution of :math:`A x = b` for a
  symmetric :math:`A`, :math:`x = \\sum_{|\\lambda_i| > c} v_i v_i^\\top b / \\lambda_i` with
  :math:`c = \\epsilon\\, n \\max_i |\\lambda_i|`: the singular values of a symmetric matrix are
  its :math:`|\\lambda_i|`, so this is ``np.linalg.lstsq(A, b, rcond=None)``'s solution and
  cutoff, rank-deficient :math:`A` included.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

EPSILON = float(np.finfo(np.float64).eps)
"""Machine epsilon of float64, :math:`2^{-52}`."""

MAX_SWEEPS = 60
"""Cap on Jacobi sweeps (convergence is quadratic: about ten for a 21 x 21 matrix)."""


@njit(cache=True)
def cholesky(matrix):  # pragma: no cover - compiled
    """The lower-triangular :math:`L` with :math:`L L^\\top =` ``matrix`` (positive definite;
    only its lower triangle is read). Raises ``ValueError`` if a pivot is not positive."""
    n = matrix.shape[0]
    lower = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1):
            total = matrix[i, j]
            for m in range(j):
                total -= lower[i, m] * lower[j, m]
            if i == j:
                if not total > 0.0:
                    raise ValueError("the matrix is not positive definite")
                lower[i, i] = math.sqrt(total)
            else:
                lower[i, j] = total / lower[j, j]
    return lower


@njit(cache=True)
def symmetric_eigen(matrix):  # pragma: no cover - compiled
    """Eigenvalues ``(n,)`` and eigenvectors ``(n, n)`` (columns) of the symmetric ``matrix``."""
    n = matrix.shape[0]
    a = matrix.copy()
    vectors = np.eye(n)
    for _ in range(MAX_SWEEPS):
        rotated = False
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq = a[p, q]
                if abs(apq) <= EPSILON * math.sqrt(abs(a[p, p])) * math.sqrt(abs(a[q, q])):
                    continue
                rotated = True
                theta = (a[q, q] - a[p, p]) / (2.0 * apq)
                if abs(theta) > 1e150:
                    t = 0.5 / theta
                else:
                    t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
                    if theta < 0.0:
                        t = -t
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for r in range(n):
                    if r != p and r != q:
                        arp, arq = a[r, p], a[r, q]
                        a[r, p] = c * arp - s * arq
                        a[p, r] = a[r, p]
                        a[r, q] = s * arp + c * arq
                        a[q, r] = a[r, q]
                a[p, p] -= t * apq
                a[q, q] += t * apq
                a[p, q] = 0.0
                a[q, p] = 0.0
                for r in range(n):
                    vrp, vrq = vectors[r, p], vectors[r, q]
                    vectors[r, p] = c * vrp - s * vrq
                    vectors[r, q] = s * vrp + c * vrq
        if not rotated:
            break
    values = np.empty(n)
    for i in range(n):
        values[i] = a[i, i]
    return values, vectors


@njit(cache=True)
def symmetric_lstsq(matrix, rhs):  # pragma: no cover - compiled
    """``(n, m)`` minimum-norm least-squares solution of ``matrix @ x = rhs`` (see the module
    docstring: ``np.linalg.lstsq``'s, with its ``rcond=None`` cutoff)."""
    n, m = rhs.shape
    values, vectors = symmetric_eigen(matrix)
    largest = 0.0
    for i in range(n):
        largest = max(largest, abs(values[i]))
    cutoff = EPSILON * n * largest
    solution = np.zeros((n, m))
    for i in range(n):
        if abs(values[i]) <= cutoff:
            continue
        for col in range(m):
            projection = 0.0
            for r in range(n):
                projection += vectors[r, i] * rhs[r, col]
            projection /= values[i]
            for r in range(n):
                solution[r, col] += vectors[r, i] * projection
    return solution
