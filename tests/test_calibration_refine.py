"""The refinement of a calibration: the coordinate search by hand and as properties on
synthetic distances (``cirl_study.analysis.refine``)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from cirl_study.analysis.refine import (
    MIN_STEP,
    SearchAxis,
    coordinate_search,
    neighbours,
    round_significant,
)
from cirl_study.study.pipeline_file import parse_pipeline
from cirl_study.study.spec import AXES

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_multiverse import multiverse_text  # noqa: E402

SIGMA = SearchAxis("sigma", False, lambda v: 0.02 <= v <= 1000)
STEPS = SearchAxis("ascent_steps", True, lambda v: 1 <= v <= 100_000)


def _log_bowl(*optimum: float):
    """A distance with its minimum 0 at ``optimum``: the squared log distance to it."""
    return lambda point: sum(math.log(x / o) ** 2 for x, o in zip(point, optimum, strict=True))


# ---- the search, by hand -------------------------------------------------------------------


def test_the_search_halves_to_the_optimum_and_stops_there_at_distance_0() -> None:
    bowl = _log_bowl(1.5)
    search = coordinate_search((0.75,), [SIGMA], bowl, known={(0.75,): bowl((0.75,))})
    # s = 2: 0.375 is farther, 1.5 is at 0: taken, and nothing is nearer than 0.
    assert [(e.point, e.step, e.accepted) for e in search.evaluations] == [
        ((0.375,), 2.0, False),
        ((1.5,), 2.0, True),
    ]
    assert search.point == (1.5,) and search.distance == 0
    assert search.stop == "exact" and search.probes == 2


def test_the_search_shrinks_its_step_and_stops_when_the_distance_stops_falling() -> None:
    bowl = _log_bowl(1.6)
    known = {(0.75,): bowl((0.75,)), (3.0,): bowl((3.0,))}
    search = coordinate_search((0.75,), [SIGMA], bowl, known=known)
    # s = 2 from 0.75: 0.375, 1.5 (taken); from 1.5: 0.75 (measured), 3 (known, the run's);
    # s = sqrt 2: 1.06, 2.12; s = 2^(1/4): 1.26, 1.78; none nearer than 1.5: converged.
    assert [e.point[0] for e in search.evaluations] == [0.375, 1.5, 3.0, 1.06, 2.12, 1.26, 1.78]
    assert [e.probed for e in search.evaluations] == [True, True, False, True, True, True, True]
    assert [e.step for e in search.evaluations] == pytest.approx(
        [2, 2, 2, 2**0.5, 2**0.5, MIN_STEP, MIN_STEP]
    )
    assert [e.point for e in search.evaluations if e.accepted] == [(1.5,)]
    assert search.point == (1.5,) and search.stop == "converged" and search.probes == 6
    assert search.distance == pytest.approx(math.log(1.5 / 1.6) ** 2)


def test_the_search_moves_one_axis_at_a_time_and_takes_the_nearer_neighbour() -> None:
    bowl = _log_bowl(4.0, 7)
    search = coordinate_search((1.0, 30), [SIGMA, STEPS], bowl, known={(1.0, 30): bowl((1.0, 30))})
    accepted = [e.point for e in search.evaluations if e.accepted]
    assert accepted[:2] == [(2.0, 30), (2.0, 15)]  # sigma first, then steps, in one sweep
    assert search.point == (4.0, 7) and search.stop == "exact"


def test_the_budget_stops_the_search_at_the_last_point_it_could_afford() -> None:
    bowl = _log_bowl(1.6)
    search = coordinate_search((0.75,), [SIGMA], bowl, known={(0.75,): bowl((0.75,))}, max_probes=1)
    assert [e.point for e in search.evaluations] == [(0.375,)]
    assert search.stop == "budget" and search.point == (0.75,) and search.probes == 1


def test_a_point_that_cannot_be_ranked_is_never_taken() -> None:
    search = coordinate_search(
        (1.0,), [SIGMA], lambda point: None, known={(1.0,): 0.5}, max_probes=50
    )
    assert search.point == (1.0,) and search.stop == "converged" and search.probes == 6
    assert all(e.distance is None and not e.accepted for e in search.evaluations)


def test_neighbours_keep_to_integers_and_to_the_constraint() -> None:
    assert neighbours(30, STEPS, 2.0) == [15, 60]
    assert neighbours(30, STEPS, MIN_STEP) == [25, 36]
    assert neighbours(2, STEPS, MIN_STEP) == [1, 3]  # at least one step either way
    assert neighbours(1, STEPS, 2.0) == [2]  # 0 is not a step budget
    assert neighbours(1.5, SIGMA, 2**0.5) == [1.06, 2.12]  # three significant digits
    assert neighbours(800.0, SIGMA, 2.0) == [400.0]  # 1600 passes sigma's bound
    assert round_significant(1.0606601717798212) == 1.06


# ---- the search, as properties ---------------------------------------------------------------

REAL = parse_pipeline(multiverse_text("[multiverse]\n"), Path("mv.toml"))
"""A 5x5 game, whose sigma may be 0.02 to 1000 grid diagonals."""

REAL_AXES = [
    SearchAxis(name, name == "ascent_steps", AXES[name].levels(REAL.game)[0])
    for name in ("sigma", "ascent_steps", "learning_rate")
]


@settings(max_examples=60, deadline=None)
@given(
    start=st.tuples(
        st.floats(0.02, 5000).map(round_significant),
        st.integers(1, 100_000),
        st.floats(1e-12, 100).map(round_significant),
    ),
    optimum=st.tuples(st.floats(1e-3, 1e5), st.floats(0.1, 1e6), st.floats(1e-14, 1e4)),
    budget=st.integers(1, 30),
)
def test_the_search_keeps_to_each_settings_constraint_and_budget(start, optimum, budget) -> None:
    """Whatever the optimum (often outside a setting's range), every point measured is a
    valid level of each setting, the probes stay within the budget, the distance never
    rises, the same inputs give the same probes, and a converged search ends at a point no
    neighbour at the smallest step is nearer than."""
    if not all(axis.valid(value) for axis, value in zip(REAL_AXES, start, strict=True)):
        return
    bowl = _log_bowl(*optimum)
    search = coordinate_search(
        start, REAL_AXES, bowl, known={start: bowl(start)}, max_probes=budget
    )
    for e in search.evaluations:
        assert all(axis.valid(v) for axis, v in zip(REAL_AXES, e.point, strict=True)), e
        assert isinstance(e.point[1], int)
    assert search.probes == len(search.evaluations) <= budget
    assert search.distance <= bowl(start)
    moved = [e.distance for e in search.evaluations if e.accepted]
    assert moved == sorted(moved, reverse=True)
    again = coordinate_search(start, REAL_AXES, bowl, known={start: bowl(start)}, max_probes=budget)
    assert again == search
    if search.stop == "converged":
        for index, axis in enumerate(REAL_AXES):
            for value in neighbours(search.point[index], axis, MIN_STEP):
                point = search.point[:index] + (value,) + search.point[index + 1 :]
                assert bowl(point) >= search.distance
