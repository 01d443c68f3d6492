"""Reward maps of a trial record: ``r_theta(s) = theta . phi(s)`` on every cell (DESIGN.md s1).

``phi_k(s) = exp(-||s - c_k||^2 / (2 sigma^2))`` with ``s = [x, y]`` the cell's coordinates
and ``c_k`` the record's RBF centres. Cells are ordered by flat index ``y * width + x``.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import Any

import numpy as np


@functools.lru_cache(maxsize=16)
def _cell_coordinates(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """``(x, y)`` of every cell, by flat index (read-only arrays, shared between calls)."""
    ys, xs = np.divmod(np.arange(width * height, dtype=float), width)
    xs.flags.writeable = False
    ys.flags.writeable = False
    return xs, ys


def feature_matrix(record: Mapping[str, Any]) -> np.ndarray:
    """``Phi``, the ``(width * height, K)`` matrix of RBF features of every cell."""
    xs, ys = _cell_coordinates(record["grid"]["width"], record["grid"]["height"])
    centers = np.asarray(record["features"]["centers"], dtype=float).reshape(-1, 2)
    sigma = float(record["features"]["sigma"])
    squared = (xs[:, None] - centers[:, 0]) ** 2 + (ys[:, None] - centers[:, 1]) ** 2
    return np.exp(squared / (-2.0 * sigma**2))


def reward_l2(record: Mapping[str, Any]) -> float:
    """``||Phi theta - Phi theta_hat||_2`` over all cells (DESIGN.md section 4)."""
    difference = np.asarray(record["theta"], float) - np.asarray(record["theta_hat"], float)
    return float(np.linalg.norm(feature_matrix(record) @ difference))
