"""The gridworld of the paper's navigation experiment (section 4.1).

A cell is ``[x, y]`` with ``0 <= x < width`` and ``0 <= y < height``; its flat
index is ``y * width + x``. The actions are ``stay``, ``N`` (y+1), ``S`` (y-1),
``E`` (x+1) and ``W`` (x-1), in that fixed order. A move that would leave the
grid is *unavailable* in that cell (it is not turned into ``stay``), so an
action sequence and a state path determine each other.

Rewards are linear in radial-basis features whose centers ``c_k`` and width
``sigma`` are common knowledge:

.. math::

    \\phi_k(s) = \\exp\\left(-\\frac{\\lVert s - c_k \\rVert^2}{2\\sigma^2}\\right),
    \\qquad r_\\theta(s) = \\theta^\\top \\phi(s).

The feature counts of a path :math:`\\tau = (s_0, \\dots, s_T)` are
:math:`\\phi(\\tau) = \\sum_{t=1}^{T} \\phi(s_t)` (the start cell is not counted).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cirl_study.features import feature_matrix as features_of
from cirl_study.features import grid_coordinates, rbf_exponents
from cirl_study.record import TrialSpec

ACTIONS: tuple[str, ...] = ("stay", "N", "S", "E", "W")
"""Action names, in the order used by every array indexed by action."""

ACTION_STEPS: tuple[tuple[int, int], ...] = ((0, 0), (0, 1), (0, -1), (1, 0), (-1, 0))
"""The ``(dx, dy)`` displacement of each action in :data:`ACTIONS`."""

UNAVAILABLE = -1
"""Successor index marking a move that would leave the grid."""

_ACTION_OF_STEP: dict[tuple[int, int], str] = dict(zip(ACTION_STEPS, ACTIONS, strict=True))


def action_between(cell: Sequence[int], next_cell: Sequence[int]) -> str | None:
    """The action that moves ``cell = [x, y]`` to ``next_cell``, ``None`` if no single one does."""
    return _ACTION_OF_STEP.get((next_cell[0] - cell[0], next_cell[1] - cell[1]))


@dataclass(frozen=True)
class Gridworld:
    """A ``width x height`` grid with deterministic moves."""

    width: int
    height: int

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise ValueError(f"grid must be at least 1x1, got {self.width}x{self.height}")

    @property
    def num_cells(self) -> int:
        """Number of cells ``S = width * height``."""
        return self.width * self.height

    def contains(self, x: int, y: int) -> bool:
        """Whether cell ``[x, y]`` lies on the grid."""
        return 0 <= x < self.width and 0 <= y < self.height

    def index(self, x: int, y: int) -> int:
        """Flat index ``y * width + x`` of cell ``[x, y]``."""
        if not self.contains(x, y):
            raise ValueError(f"cell [{x}, {y}] is outside the {self.width}x{self.height} grid")
        return y * self.width + x

    def coords(self, index: int) -> tuple[int, int]:
        """Cell ``[x, y]`` of a flat index."""
        return int(index) % self.width, int(index) // self.width

    def cell_coordinates(self) -> NDArray[np.float64]:
        """``(S, 2)`` array of every cell's ``[x, y]``, in flat-index order."""
        return grid_coordinates(self.width, self.height)

    @cached_property
    def successors(self) -> NDArray[np.int64]:
        """``(S, 5)`` next-cell index of each action, :data:`UNAVAILABLE` off the grid."""
        coords = self.cell_coordinates().astype(np.int64)
        steps = np.asarray(ACTION_STEPS, dtype=np.int64)
        target = coords[:, None, :] + steps[None, :, :]
        inside = (
            (target[..., 0] >= 0)
            & (target[..., 0] < self.width)
            & (target[..., 1] >= 0)
            & (target[..., 1] < self.height)
        )
        flat = target[..., 1] * self.width + target[..., 0]
        return np.where(inside, flat, UNAVAILABLE)

    def demonstrator_moves(self, stays: bool) -> NDArray[np.int64]:
        """The successor table of the learning phase: :attr:`successors`, less ``stay``
        unless the human may stay (``TrialSpec.demonstrator_stays``)."""
        if stays:
            return self.successors
        moves = self.successors.copy()
        moves[:, ACTIONS.index("stay")] = UNAVAILABLE
        return moves


def rbf_features(grid: Gridworld, centers: ArrayLike, sigma: float) -> NDArray[np.float64]:
    """Radial-basis features of every cell, :math:`\\phi_k(s) = \\exp(-\\|s - c_k\\|^2 /
    (2 \\sigma^2))` (:func:`cirl_study.features.rbf_exponents`), each the C library's
    ``exp`` (:func:`cirl_study.core.elementwise.exp`): bitwise the same on every CPU, whichever
    SIMD variants of its loops numpy would dispatch to.

    Args:
        grid: the gridworld.
        centers: ``(K, 2)`` centers, or ``(B, K, 2)`` for a batch of feature sets.
        sigma: the common width ``sigma > 0``.

    Returns:
        ``(S, K)`` (or ``(B, S, K)``) array with ``phi_k(s)``.
    """
    # The compiler loads with the first trial played, not with the log reader.
    from cirl_study.core.elementwise import exp

    return exp(rbf_exponents(grid.width, grid.height, np.asarray(centers, np.float64), sigma))


def gridworld(spec: TrialSpec) -> Gridworld:
    """The gridworld of a trial."""
    return Gridworld(spec.grid.width, spec.grid.height)


def feature_matrix(spec: TrialSpec) -> NDArray[np.float64]:
    """``Phi``, the ``(width * height, K)`` features of every cell of a trial, by flat index
    (:func:`cirl_study.features.feature_matrix` with the C library's ``exp``)."""
    from cirl_study.core.elementwise import exp

    return features_of(spec.grid.width, spec.grid.height, spec.features, exp)


def paths_actions(grid: Gridworld, paths: NDArray[np.int64]) -> list[tuple[str, ...]]:
    """The action sequence of each path of ``paths``, ``(B, T + 1)`` cell indices: at step
    ``t`` the first action ``a`` (in :data:`ACTIONS` order) with ``successors[s_t, a] =
    s_{t+1}``.

    Raises:
        ValueError: two consecutive cells of a path are not one move apart.
    """
    moves = grid.successors[paths[:, :-1]] == paths[:, 1:, None]  # (B, T, actions)
    possible = moves.any(axis=2)
    if not possible.all():
        b, t = np.argwhere(~possible)[0]
        raise ValueError(f"cells {paths[b, t]} and {paths[b, t + 1]} are not one move apart")
    return [tuple(ACTIONS[a] for a in row) for row in moves.argmax(axis=2).tolist()]


def paths_cells(grid: Gridworld, paths: NDArray[np.int64]) -> list[tuple[tuple[int, int], ...]]:
    """The ``[x, y]`` cells of each path of ``paths``, ``(B, T + 1)`` cell indices."""
    ys, xs = np.divmod(paths, grid.width)
    return [tuple(zip(x, y, strict=True)) for x, y in zip(xs.tolist(), ys.tolist(), strict=True)]
