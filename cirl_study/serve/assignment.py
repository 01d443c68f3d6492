"""Who does what: each participant's conditions and order of tasks, from her arrival alone.

The ``i``-th participant to start (``i = 0, 1, ...``, her session's ``index``) is assigned by
functions of the pipeline's seed, ``i`` and the pipeline's conditions and tasks, so every
assignment is derivable from the run directory's sessions and the pipeline, and is logged in
each session's file besides:

* **Conditions, between participants** (``participants.design = "between"``): blocked
  randomisation. Participants ``b C .. b C + C - 1`` (``C`` conditions) form block ``b``, and
  take the conditions in the order of a shuffle of block ``b``; after any number of
  participants the conditions' counts differ by at most one.
* **Conditions, within participants**: every participant is in every condition, in the order
  of row ``i`` of a balanced Latin square of the conditions.
* **Tasks**: in the order of a row of a balanced Latin square (Williams: every task in every
  position once, and every task right after every other once, in ``n`` rows for an even
  number ``n`` of tasks, in ``2 n`` for an odd one) over the tasks in a shuffled order of the
  run. Between participants, a participant's row is her block ``b`` (she is the ``b``-th of
  her condition), so each condition cycles through the square; within, her index ``i``.

Shuffles are Fisher-Yates with each draw from SHA-256 of the seed and the draw's name
(:func:`shuffled`): they depend on no library's random generator, and so on no version.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from typing import TypeVar

import msgspec

Item = TypeVar("Item")


class Assignment(msgspec.Struct, frozen=True, kw_only=True):
    """A participant's place in the experiment: ``index``, her arrival (0 the first); the
    ``steps`` she does in order, each a condition and a task (between participants, one
    condition throughout)."""

    index: int
    steps: tuple[tuple[str, str], ...]

    @property
    def conditions(self) -> tuple[str, ...]:
        """Her conditions, in the order she meets them."""
        return tuple(dict.fromkeys(condition for condition, _ in self.steps))


def shuffled(items: Sequence[Item], seed: int, name: str) -> list[Item]:
    """``items`` in the order of a Fisher-Yates shuffle whose ``k``-th draw is SHA-256 of
    ``"<seed>/<name>/<k>"`` (big-endian) modulo ``k + 1``."""
    order = list(items)
    for k in range(len(order) - 1, 0, -1):
        digest = hashlib.sha256(f"{seed}/{name}/{k}".encode()).digest()
        j = int.from_bytes(digest, "big") % (k + 1)
        order[k], order[j] = order[j], order[k]
    return order


def latin_square(count: int) -> list[list[int]]:
    """The rows of a balanced Latin square of ``count`` items (Williams 1949): ``count`` rows
    for an even ``count``, ``2 count`` (each row and its reverse) for an odd one.

    >>> latin_square(4)
    [[0, 1, 3, 2], [1, 2, 0, 3], [2, 3, 1, 0], [3, 0, 2, 1]]
    >>> len(latin_square(3))
    6
    """
    first = [0]
    low, high = 1, count - 1
    while low <= high:
        first.append(low)
        low += 1
        if low <= high:
            first.append(high)
            high -= 1
    rows = [[(item + shift) % count for item in first] for shift in range(count)]
    return rows if count % 2 == 0 else rows + [row[::-1] for row in rows]


def assign(
    seed: int, index: int, conditions: Sequence[str], tasks: Sequence[str], within: bool
) -> Assignment:
    """The assignment of the ``index``-th participant (the module docstring)."""
    task_order = shuffled(tasks, seed, "tasks")
    task_rows = latin_square(len(tasks))
    if within:
        condition_rows = latin_square(len(conditions))
        row = condition_rows[index % len(condition_rows)]
        order = [task_order[t] for t in task_rows[index % len(task_rows)]]
        steps = tuple((conditions[c], task) for c in row for task in order)
        return Assignment(index=index, steps=steps)
    block, place = divmod(index, len(conditions))
    condition = shuffled(conditions, seed, f"conditions/{block}")[place]
    order = [task_order[t] for t in task_rows[block % len(task_rows)]]
    return Assignment(index=index, steps=tuple((condition, task) for task in order))
