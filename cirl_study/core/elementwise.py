"""Elementwise functions of the C library, the same bits on every x86-64 CPU.

numpy's float64 ``exp`` has SIMD variants (AVX512F) chosen by the CPU at run time, whose last
bits differ from the C library's; a compiled loop without ``fastmath`` calls the C library's
``exp`` on every element on every CPU. Kept apart from :mod:`cirl_study.core.gridworld` so that
reading and checking logs, which import the gridworld, do not load the compiler.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def exp(exponents):  # pragma: no cover - compiled
    """Elementwise ``math.exp`` of a C-contiguous array."""
    out = np.empty_like(exponents)
    flat, values = out.reshape(-1), exponents.reshape(-1)
    for i in range(values.size):
        flat[i] = math.exp(values[i])
    return out
