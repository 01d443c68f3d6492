"""The refinement of a calibration: a coordinate search of the numeric settings for the
universe nearest a target (``docs/multiverse.md``, *Refinement*).

:func:`coordinate_search` knows nothing of games or runs: a point is a tuple of values, one
per :class:`SearchAxis`, and the distance a callable (``cirl-study calibrate --refine`` plays
each probe as a run of its own and measures its distance to the target). With :math:`D(x)`
the distance of point :math:`x` (``None``, a point that cannot be ranked, counts as
:math:`+\\infty`), the search starts at the nearest universe :math:`x_0` with the step factor
:math:`s = s_0 =` :data:`FIRST_STEP` and repeats *sweeps*:

* for each axis :math:`a` in order, the neighbours of :math:`x` along :math:`a` at step
  :math:`s` are :math:`x` with :math:`x_a` replaced by :math:`\\rho(x_a / s)` and
  :math:`\\rho(x_a s)` (:math:`\\rho` rounds to :data:`SIGNIFICANT_DIGITS` significant
  digits), or for an integer axis by :math:`\\min(\\mathrm{round}(x_a / s), x_a - 1)` and
  :math:`\\max(\\mathrm{round}(x_a s), x_a + 1)` (round: to the nearest integer); a
  neighbour outside the setting's own constraint is dropped. An axis may leave its value to
  be chosen by the point's other settings (:attr:`SearchAxis.chosen`: a cross-validated eta,
  ``None`` in the point); :math:`x_a` is then the value chosen at :math:`x`, and its
  neighbours fix the setting. Each neighbour's distance is
  measured (once per point: a point measured before, or known beforehand, is not measured
  again), and the nearer of the two,
  :math:`y^*` (the lower value on a tie), becomes the new :math:`x` if
  :math:`D(y^*) < D(x)`;
* after a sweep that moved, the next sweep keeps :math:`s`; after one that did not, the step
  shrinks to :math:`\\sqrt s`, down to :math:`s_{min} = s_0^{2^{-H}}` with :math:`H =`
  :data:`STEP_HALVINGS` (:data:`MIN_STEP`, 19% for :math:`s_0 = 2`).

It stops when the distance stops falling, on the first of: :math:`D(x) = 0` (nothing is
nearer; ``"exact"``), a sweep at :math:`s_{min}` that does not move (``"converged"``), or a
point to probe once ``max_probes`` have been (``"budget"``). Each move lowers :math:`D`
strictly, so no point is visited twice, and a point measured and passed over is never taken
later (the distance of :math:`x` only falls). The search is deterministic: the same start,
axes and distances give the same probes in the same order.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

FIRST_STEP = 2.0
"""The first step factor :math:`s_0`: a neighbour is the value halved or doubled."""

STEP_HALVINGS = 2
"""How often the step's logarithm is halved before the search may stop: :math:`s = 2,
\\sqrt 2, 2^{1/4}`."""

MIN_STEP = FIRST_STEP ** (0.5**STEP_HALVINGS)
"""The smallest step factor :math:`s_{min}` (about 1.19)."""

SIGNIFICANT_DIGITS = 3
"""Digits a probed real value keeps: readable universe ids (as the eta grid's), and a search
that returns to a level such as 1.5 exactly."""

DEFAULT_MAX_PROBES = 40
"""Probes a refinement measures at most, by default: a search over one setting takes 6 to
10 (two neighbours at each of the three steps, and two more after each move), over sigma and
the eta of two feature levels about 20."""

Point = tuple[Any, ...]
"""A point of the search: one value per axis, in the axes' order."""


@dataclass(frozen=True)
class SearchAxis:
    """One setting the search moves: its name, whether its values are integers, the
    setting's own constraint (``valid``: whether a value is a level of it) and, for a setting
    a point may leave to its other settings to choose (``None`` in the point), ``chosen``:
    the value chosen at a point, asked of measured points only."""

    name: str
    integer: bool
    valid: Callable[[Any], bool]
    chosen: Callable[[Point], Any] | None = None


@dataclass(frozen=True)
class Evaluation:
    """A point the search measured, in the order measured: the point it was proposed from
    (``origin``), the axis and step factor of that move, its distance (``None``: it cannot be
    ranked), whether it was ``probed`` (else its distance was known beforehand: a universe of
    the run) and whether the search moved to it."""

    point: Point
    origin: Point
    axis: str
    step: float
    distance: float | None
    probed: bool
    accepted: bool


@dataclass(frozen=True)
class Search:
    """What :func:`coordinate_search` found: every point measured, the final point and its
    distance, the probes measured and why the search stopped (``"exact"``, ``"converged"``
    or ``"budget"``)."""

    evaluations: tuple[Evaluation, ...]
    point: Point
    distance: float
    probes: int
    stop: str


def round_significant(value: float, digits: int = SIGNIFICANT_DIGITS) -> float:
    """``value`` rounded to ``digits`` significant digits."""
    return float(f"{value:.{digits - 1}e}")


def neighbours(value: Any, axis: SearchAxis, step: float) -> list[Any]:
    """The values next to ``value`` along ``axis`` at step factor ``step``, down then up, each
    within the setting's constraint and unlike ``value`` (see the module docstring)."""
    if axis.integer:
        candidates = [min(round(value / step), value - 1), max(round(value * step), value + 1)]
    else:
        candidates = [round_significant(value / step), round_significant(value * step)]
    return [v for v in dict.fromkeys(candidates) if v != value and axis.valid(v)]


class _BudgetSpent(Exception):
    """A point to probe beyond the budget: the search stops."""


def coordinate_search(
    start: Point,
    axes: Sequence[SearchAxis],
    distance: Callable[[Point], float | None],
    *,
    known: Mapping[Point, float | None],
    max_probes: int = DEFAULT_MAX_PROBES,
) -> Search:
    """The coordinate search of the module docstring from ``start``, over ``axes``.

    Args:
        start: the first point; its distance must be in ``known``, and finite.
        axes: the settings the search moves, in the order a sweep visits them.
        distance: the distance of a point not in ``known`` (one probe each).
        known: the distances known beforehand, not counted as probes (the run's universes).
        max_probes: the most points ``distance`` is asked for.
    """
    if len(start) != len(axes):
        raise ValueError("a point has one value per axis")
    first = known[start]
    if first is None or not math.isfinite(first):
        raise ValueError("the search starts at a point with a finite distance")
    measured: dict[Point, float] = {start: first}
    evaluations: list[Evaluation] = []
    accepted: set[Point] = set()  # no point is measured twice, so a point names its evaluation
    probes = 0

    def measure(point: Point, origin: Point, axis: str, step: float) -> float:
        nonlocal probes
        if point in measured:
            return measured[point]
        probed = point not in known
        if probed and probes >= max_probes:
            raise _BudgetSpent
        value = distance(point) if probed else known[point]
        probes += probed
        evaluations.append(Evaluation(point, origin, axis, step, value, probed, accepted=False))
        measured[point] = math.inf if value is None else value
        return measured[point]

    point, halvings, stop = start, 0, "exact"
    try:
        while measured[point] > 0:
            step = FIRST_STEP ** (0.5**halvings)
            moved = False
            for index, axis in enumerate(axes):
                value = point[index]
                if value is None and axis.chosen is not None:
                    value = axis.chosen(point)
                options = [
                    point[:index] + (near,) + point[index + 1 :]
                    for near in neighbours(value, axis, step)
                ]
                scored = [(measure(option, point, axis.name, step), option) for option in options]
                nearest = min(scored, key=lambda pair: pair[0], default=(math.inf, point))
                if nearest[0] < measured[point]:
                    point, moved = nearest[1], True
                    accepted.add(point)
                    if nearest[0] == 0:
                        break
            if not moved:
                if halvings == STEP_HALVINGS:
                    stop = "converged"
                    break
                halvings += 1
    except _BudgetSpent:
        stop = "budget"
    return Search(
        evaluations=tuple(replace(e, accepted=e.point in accepted) for e in evaluations),
        point=point,
        distance=measured[point],
        probes=probes,
        stop=stop,
    )
