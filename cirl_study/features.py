"""Feature kinds: how a game's cells carry the ``K`` features its rewards are linear in.

A kind is a record type (a frozen :class:`msgspec.Struct` tagged by its ``kind``) that knows
its number of features and turns a ``width x height`` grid into the ``(S, K)`` matrix
:math:`\\Phi` by flat cell index (``y * width + x``; docs/design.md §1). :func:`feature_matrix`
is the one function every stage uses (play, record checks, figures, reports), and
:data:`FEATURE_KINDS` the registry: a new kind is one class here and one entry there.

* ``rbf`` (the paper): :math:`\\phi_k(s) = \\exp(-\\lVert s - c_k \\rVert^2 / (2\\sigma^2))`.
* ``tiles``: an ASCII layout, one character per cell, whose characters name features by a
  legend (one-hot: :math:`\\phi_k(s) = 1` iff the legend names feature ``k`` for the
  character of ``s``), and optionally a per-move feature, 1 in every cell: every move enters
  one cell, so its count is the path's length and a negative weight on it is a step cost.

This module imports numpy only: readers and checkers of logs use it without the compiler.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, ClassVar, Union

import msgspec
import numpy as np
from numpy.typing import NDArray

Exp = Callable[[NDArray[np.float64]], NDArray[np.float64]]
"""An elementwise exponential (numpy's, or the C library's of
:func:`cirl_study.core.elementwise.exp`, the same bits on every CPU)."""

_STRUCT = {"frozen": True, "kw_only": True, "gc": False, "tag_field": "kind"}

FeatureName = Annotated[
    str, msgspec.Meta(min_length=1, max_length=64, pattern=r"^[A-Za-z_][\w-]*$")
]
"""A named feature of a tile layout: a letter or ``_`` then letters, digits, ``_`` or ``-``."""

Symbol = Annotated[str, msgspec.Meta(min_length=1, max_length=1, pattern=r"^[!-~]$")]
"""One printable ASCII character of a tile layout (not a space)."""


def grid_coordinates(width: int, height: int) -> NDArray[np.float64]:
    """``(S, 2)`` every cell's ``[x, y]``, in flat-index order."""
    ys, xs = np.divmod(np.arange(width * height), width)
    return np.stack([xs, ys], axis=1).astype(np.float64)


def rbf_exponents(
    width: int, height: int, centers: NDArray[np.float64], sigma: float
) -> NDArray[np.float64]:
    """The exponents :math:`-\\lVert s - c_k \\rVert^2 / (2\\sigma^2)` of the ``rbf`` kind.

    ``centers`` is ``(K, 2)``, or ``(B, K, 2)`` for a batch of feature sets; the result is
    ``(S, K)`` (or ``(B, S, K)``). The squared distance is ``dx*dx + dy*dy`` on ``(S, K)``
    arrays: the same sum as numpy's reduction over the coordinate axis, to the bit, without
    its slow reduction over an axis of length 2.
    """
    if sigma <= 0:
        raise ValueError(f"sigma must be positive, got {sigma}")
    cells = grid_coordinates(width, height)
    centers = np.asarray(centers, dtype=np.float64)
    dx = cells[:, 0, None] - centers[..., None, :, 0]
    dy = cells[:, 1, None] - centers[..., None, :, 1]
    return -(dx * dx + dy * dy) / (2.0 * sigma**2)


class RBFFeatures(msgspec.Struct, tag="rbf", **_STRUCT):
    """Radial-basis features ``phi_k(s) = exp(-||s - c_k||^2 / (2 sigma^2))``, centres ``c_k``
    and width ``sigma`` common knowledge."""

    kind: ClassVar[str] = "rbf"
    centers: Annotated[tuple[tuple[float, float], ...], msgspec.Meta(min_length=1)]
    sigma: Annotated[float, msgspec.Meta(gt=0)]

    @property
    def count(self) -> int:
        """``K``, one feature per centre."""
        return len(self.centers)

    @property
    def names(self) -> tuple[str, ...]:
        """``phi1 .. phiK``."""
        return tuple(f"phi{k + 1}" for k in range(self.count))

    def faults(self, width: int, height: int) -> list[str]:
        """Rules the types cannot state (none: any centre and width make features)."""
        return []

    def matrix(self, width: int, height: int, exp: Exp) -> NDArray[np.float64]:
        """``(S, K)`` :math:`\\Phi`, each entry ``exp`` of :func:`rbf_exponents`."""
        return exp(np.ascontiguousarray(rbf_exponents(width, height, self.centers, self.sigma)))


class TileFeatures(msgspec.Struct, tag="tiles", **_STRUCT):
    """One-hot features of an ASCII layout, and optionally a per-move feature.

    ``layout`` holds the grid's rows from the top (``y = height - 1``) down to ``y = 0``, one
    character per cell, as a pipeline file writes them. ``names`` are the features in the
    order of :math:`\\theta`. ``legend`` pairs each character of the layout with the name of
    the feature its cells carry, or with ``None`` for a cell without one (a white tile, a
    goal); ``step``, when given, names the feature that is 1 in every cell.

    Examples:
        >>> tiles = TileFeatures(layout=("ab", ".b"), names=("a", "b", "step"),
        ...     legend=(("a", "a"), ("b", "b"), (".", None)), step="step")
        >>> tiles.matrix(2, 2, np.exp).tolist()   # cells [0,0], [1,0], [0,1], [1,1]
        [[0.0, 0.0, 1.0], [0.0, 1.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]]
    """

    kind: ClassVar[str] = "tiles"
    layout: Annotated[tuple[str, ...], msgspec.Meta(min_length=1)]
    names: Annotated[tuple[FeatureName, ...], msgspec.Meta(min_length=1)]
    legend: Annotated[tuple[tuple[Symbol, FeatureName | None], ...], msgspec.Meta(min_length=1)]
    step: FeatureName | None = None

    @property
    def count(self) -> int:
        """``K``, one feature per name."""
        return len(self.names)

    def faults(self, width: int, height: int) -> list[str]:
        """Every way the layout, legend and names disagree with each other or the grid."""
        faults = []
        if len(self.layout) != height or any(len(row) != width for row in self.layout):
            shape = f"{len(self.layout)} rows of {sorted({len(row) for row in self.layout})}"
            faults.append(f"the layout has {shape} characters, not {height} rows of {width}")
        symbols = [symbol for symbol, _ in self.legend]
        if len(set(symbols)) != len(symbols):
            faults.append("the legend names a character twice")
        if len(set(self.names)) != len(self.names):
            faults.append("a feature is named twice")
        unknown = sorted({char for row in self.layout for char in row} - set(symbols))
        if unknown:
            faults.append(f"the layout's characters {unknown} are not in the legend")
        named = {name for _, name in self.legend if name is not None}
        if self.step is not None:
            named.add(self.step)
            if self.step in {name for _, name in self.legend}:
                faults.append(f"the step feature {self.step!r} is also a tile's")
        if named != set(self.names):
            faults.append(
                f"the legend and step name the features {sorted(named)}, "
                f"not the names {sorted(self.names)}"
            )
        return faults

    def matrix(self, width: int, height: int, exp: Exp) -> NDArray[np.float64]:
        """``(S, K)`` :math:`\\Phi` of a sound layout (:meth:`faults` empty): 0 or 1."""
        column = {name: k for k, name in enumerate(self.names)}
        of_symbol = dict(self.legend)
        phi = np.zeros((width * height, self.count))
        for row, text in enumerate(self.layout):
            y = height - 1 - row
            for x, char in enumerate(text):
                name = of_symbol[char]
                if name is not None:
                    phi[y * width + x, column[name]] = 1.0
        if self.step is not None:
            phi[:, column[self.step]] = 1.0
        return phi

    def cells_of(self, symbols: str, width: int, height: int) -> tuple[tuple[int, int], ...]:
        """The ``[x, y]`` cells whose character is one of ``symbols``, by flat index."""
        found = [
            (x, height - 1 - row)
            for row, text in enumerate(self.layout)
            for x, char in enumerate(text)
            if char in symbols
        ]
        return tuple(sorted(found, key=lambda cell: (cell[1], cell[0])))


FEATURE_KINDS: tuple[type, ...] = (RBFFeatures, TileFeatures)
"""Every feature kind, told apart by its ``kind`` tag: a new kind is one line here."""

Features = Union[FEATURE_KINDS]  # type: ignore[valid-type]  # noqa: UP007
"""A game's features, of any kind in :data:`FEATURE_KINDS` (the union a record's
``features`` decodes into)."""


def feature_matrix(
    width: int, height: int, features: Features, exp: Exp = np.exp
) -> NDArray[np.float64]:
    """``(width * height, K)`` :math:`\\Phi` of ``features`` on a ``width x height`` grid.

    ``exp`` is the exponential of a kind that takes one (``rbf``): numpy's, within an ulp of
    the C library's, for readers; the trial's play passes the C library's
    (:func:`cirl_study.core.elementwise.exp`) so the same trial has the same features, to the
    bit, on every CPU.
    """
    return features.matrix(width, height, exp)
