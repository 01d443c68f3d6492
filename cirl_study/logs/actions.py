"""The path/action relation of the gridworld (DESIGN.md section 1), for checking logged paths.

``N`` is ``y + 1``, ``S`` is ``y - 1``, ``E`` is ``x + 1``, ``W`` is ``x - 1``. A move that
would leave the grid is unavailable, so a state path determines its action sequence and
vice versa.
"""

from __future__ import annotations

from collections.abc import Sequence

from cirl_study.gridworld import ACTION_STEPS, ACTIONS

_ACTION_OF_STEP: dict[tuple[int, int], str] = dict(zip(ACTION_STEPS, ACTIONS, strict=True))


def action_between(cell: Sequence[int], next_cell: Sequence[int]) -> str | None:
    """The action that moves ``cell`` to ``next_cell``, or ``None`` if no single action does."""
    return _ACTION_OF_STEP.get((next_cell[0] - cell[0], next_cell[1] - cell[1]))


def inside(cell: Sequence[int], width: int, height: int) -> bool:
    """Whether ``cell = [x, y]`` lies on the ``width x height`` grid."""
    return 0 <= cell[0] < width and 0 <= cell[1] < height
