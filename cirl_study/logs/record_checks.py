"""Is a logged trial payload a record (its types), and is the record consistent (the game's rules)?

Types and ranges are checked by decoding into :class:`~cirl_study.record.TrialRecord`
(:func:`decode_trial`). Consistency, in docs/design.md's notation: ``len(theta) =
len(theta_hat) = K`` = the number of features (:mod:`cirl_study.features`, each kind with
rules of its own); ``theta_hat`` lies in the box ``[-1, 1]^K`` unless its robot is
``gradient_ascent`` (whose estimate may leave it), which alone has, and must have, its
settings (``gradient_ascent``); the start cell ``s_0`` and the goals lie on the grid; the
demonstration is a path ``(s_0, ..., s_T_learn)`` of available moves from ``s_0`` with
``T_learn`` actions (with goals: at most ``T_learn``, ending on entering its first goal),
each the move between consecutive cells, none of them ``stay`` unless
``demonstrator_stays``; every deployment rollout is such a path of ``T_deploy`` moves from its
start, which is the demonstration's start when ``deployment_start`` says so; the measures are
the registered ones, each finite, in its range (up to rounding) and ``null`` only where its
measure allows (:func:`~cirl_study.measure_registry.measure_faults`);
``reward_l2 = ||Phi theta - Phi theta_hat||_2`` recomputed from the record (here, not by the
code that logged it; the records of one grid and ``K`` in one array product). The human and the
robot are registered ones (:data:`~cirl_study.core.players.HUMANS`,
:data:`~cirl_study.core.players.ROBOTS`), ``eta`` is null exactly for a human without a
trade-off, and a record with a teaching human or robot has its hypothesis space (``teaching``).
A record's grid and feature matrix are bounded (:data:`MAX_GRID_CELLS`,
:data:`MAX_FEATURE_ENTRIES`) before anything is computed per cell; a record past a bound, or
nested too deep to decode, has a :class:`BoundFault`.
"""

from __future__ import annotations

import functools
import math
from collections import defaultdict
from collections.abc import Iterable, Iterator, Sequence

import msgspec
import numpy as np
from numpy.typing import NDArray

from cirl_study.core.gridworld import (
    ACTION_STEPS,
    ACTIONS,
    Gridworld,
    action_between,
)
from cirl_study.core.players import ROBOTS, player_faults
from cirl_study.features import Features, feature_matrix
from cirl_study.measure_registry import measure_faults
from cirl_study.record import (
    Cell,
    DecodeError,
    Grid,
    NestedTooDeep,
    TrialRecord,
    decode,
    setting_faults,
)

L2_TOLERANCE = 1e-9
"""Relative and absolute tolerance when recomputing ``reward_l2``."""

MAX_GRID_CELLS = 1 << 18
"""Most cells a record's grid may have (262,144): checking a record computes its reward map
over every cell. No pipeline the study's ``check_resources`` admits has more than about
153,000 (its batch memory budget, at the shortest horizons and one feature)."""

MAX_FEATURE_ENTRIES = 1 << 18
"""Most entries (cells times features) of the feature matrix checking a record's
``reward_l2`` computes (2 MiB of floats); ``check_resources`` admits at most about 195,000
(the budget holds ``K^2`` floats per cell and step)."""

_MOVE_TABLE_CELLS = 4096
"""Grids of at most this many cells have their moves tabulated, once per grid, so a sound
record's paths are walked through the table (:func:`_inconsistencies`); a record of a larger
grid is checked step by step, which costs its paths' length, not its grid's size."""

_CACHED_FEATURE_ENTRIES = 4096
"""Feature matrices of at most this many entries (32 KiB) are kept for the other trials of
their subject (:func:`_feature_matrix`); larger ones are computed for each record, so the
cache stays within 4096 matrices of this size whatever the records claim."""

_STACKED_ENTRIES = 1 << 22
"""Most feature-matrix entries of records stacked into one array product (32 MiB of
floats) by :func:`_reward_l2_faults`."""


class BoundFault(str):
    """A fault that is a bound passed (the record nests too deep, its grid is too large), not
    an inconsistency: a reader takes such a record as damage of its file, which
    ``--partial`` passes over, rather than as content it cannot trust. Shown as the string
    it is."""


class _Labelled(msgspec.Struct):
    trial_id: str


def payload_trial_id(data: bytes) -> str | None:
    """The ``trial_id`` of a payload that may not be a valid record, if it has one."""
    try:
        return msgspec.json.decode(data, type=_Labelled).trial_id
    except (msgspec.DecodeError, RecursionError):  # see cirl_study.record.decode
        return None


def decode_trial(data: bytes) -> tuple[TrialRecord | None, list[str]]:
    """The record in a ``/cirl/trial`` payload and its faults (a type fault leaves no record)."""
    return decode_trials([data])[0]


def decode_trials(payloads: Iterable[bytes]) -> list[tuple[TrialRecord | None, list[str]]]:
    """:func:`decode_trial` of every payload, their ``reward_l2`` checked together."""
    decoded: list[TrialRecord | DecodeError] = []
    for data in payloads:
        try:
            decoded.append(decode(data))
        except DecodeError as error:
            decoded.append(error)
    records = [r for r in decoded if isinstance(r, TrialRecord)]
    faults = iter(records_faults(records))
    return [
        (r, next(faults)) if isinstance(r, TrialRecord) else (None, [_decode_fault(r)])
        for r in decoded
    ]


def _decode_fault(error: DecodeError) -> str:
    fault = f"not a trial record: {error}"
    return BoundFault(fault) if isinstance(error, NestedTooDeep) else fault


def record_faults(record: TrialRecord) -> list[str]:
    """Every inconsistency of a decoded trial record (empty for a sound one)."""
    return records_faults([record])[0]


def records_faults(records: Sequence[TrialRecord]) -> list[list[str]]:
    """:func:`record_faults` of every record; the ``reward_l2`` checks are one array
    product per grid and ``K`` (:func:`_reward_l2_faults`) instead of one per record, of the
    records whose measures are sound (a ``reward_l2`` missing or out of its range is its own
    fault)."""
    measured = [measure_faults(r.measures) for r in records]
    faults = [
        _size_faults(r) or [*_inconsistencies(r), *measure]
        for r, measure in zip(records, measured, strict=True)
    ]
    for index, fault in _reward_l2_faults(records, [not measure for measure in measured]):
        faults[index].append(fault)
    return faults


def _size_faults(r: TrialRecord) -> list[str]:
    """A grid or feature matrix past its bound (nothing else of such a record is checked)."""
    cells = r.grid.width * r.grid.height
    shape = f"{r.grid.width}x{r.grid.height}"
    if cells > MAX_GRID_CELLS:
        bound = f"more than the {MAX_GRID_CELLS} a record may"
        return [BoundFault(f"grid {shape} has {cells} cells, {bound}")]
    if cells * r.num_features > MAX_FEATURE_ENTRIES:
        return [
            BoundFault(
                f"grid {shape} and {r.num_features} features make {cells * r.num_features} "
                f"feature values, more than the {MAX_FEATURE_ENTRIES} a record may"
            )
        ]
    return []


def _ends_right(path: Sequence[Cell], steps: int, goals: tuple[Cell, ...]) -> bool:
    """Whether ``path`` has the length of its phase: ``steps`` moves, or with ``goals`` at
    most ``steps``, ending on its first goal."""
    if not goals:
        return len(path) == steps + 1
    return (
        2 <= len(path) <= steps + 1
        and tuple(path[-1]) in goals
        and not any(tuple(cell) in goals for cell in path[:-1])
    )


def _walk(
    path: Sequence[Cell],
    start: Cell,
    steps: int,
    moves: dict[tuple[Cell, Cell], str],
    goals: tuple[Cell, ...],
) -> tuple[str, ...] | None:
    """The actions of ``path`` if it is a walk of ``steps`` available moves from ``start``
    (``steps >= 1``; at most ``steps`` to its first goal with ``goals``), else ``None`` (also
    for cells that are not tuples: the detailed checks then decide)."""
    if steps < 1 or path[0] != start or not _ends_right(path, steps, goals):
        return None
    try:
        return tuple(map(moves.__getitem__, zip(path, path[1:], strict=False)))
    except (KeyError, TypeError):
        return None


def _inconsistencies(r: TrialRecord) -> Iterator[str]:
    """Every inconsistency of ``r`` but its measures', each named.

    Each rule is written once. A path is first walked through the grid's move table
    (:func:`_walk`, one lookup per step: the case of a sound record, which the reader meets
    most); only a path that fails it is examined cell by cell (:func:`_path_faults`) to name
    what breaks.
    """
    yield from player_faults(r.human, r.robot, r.eta, r.teaching is not None)
    yield from setting_faults(r)
    if len(r.theta_hat) != r.num_features:
        yield f"theta_hat has {len(r.theta_hat)} entries, num_features is {r.num_features}"
    robot = ROBOTS.get(r.robot)
    if robot is not None and not robot.leaves_box:
        for i, value in enumerate(r.theta_hat):
            if not -1.0 <= value <= 1.0:
                yield (
                    f"theta_hat[{i}] is {value}, outside [-1, 1] (only a robot whose estimate "
                    "may leave the box, such as gradient_ascent, may)"
                )
                break
    grid = _gridworld(r.grid)
    moves = _moves(r.grid) if r.grid.width * r.grid.height <= _MOVE_TABLE_CELLS else None
    states, actions = r.demonstration.states, r.demonstration.actions
    walked = None if moves is None else _walk(states, r.start, r.learning_steps, moves, r.goals)
    if walked is None:
        yield from _path_faults(
            "demonstration.states", states, r.start, r.learning_steps, grid, r.goals
        )
    if len(actions) != len(states) - 1:
        yield f"demonstration has {len(actions)} actions for {len(states)} cells"
    if walked != actions:
        for t, (action, cell, next_cell) in enumerate(
            zip(actions, states, states[1:], strict=False)
        ):
            if action != action_between(cell, next_cell):
                yield (
                    f"demonstration.actions[{t}] is {action} but the path moves "
                    f"{list(cell)} -> {list(next_cell)}"
                )
                break
    if not r.demonstrator_stays and "stay" in actions:
        yield "the demonstration stays put, but demonstrator_stays is false"
    if r.recorded is not None and r.recorded.path != states:
        yield "demonstration.states is not the participant's recorded path"
    if r.deployment is not None:
        starts, paths = r.deployment.starts, r.deployment.paths
        if r.deployment_start == "demonstration" and any(s != r.start for s in starts):
            yield f"a deployment rollout starts away from the demonstration's start {list(r.start)}"
        if len(starts) != len(paths):
            yield f"deployment has {len(starts)} starts and {len(paths)} paths"
        for i, (start, path) in enumerate(zip(starts, paths, strict=False)):
            if moves is None or _walk(path, start, r.deployment_steps, moves, r.goals) is None:
                yield from _path_faults(
                    f"deployment.paths[{i}]", path, start, r.deployment_steps, grid, r.goals
                )


def _sized(r: TrialRecord) -> bool:
    """Whether ``theta``, ``theta_hat`` and the centers all have ``num_features`` entries."""
    return len(r.theta) == len(r.theta_hat) == r.features.count == r.num_features


def _reward_l2_faults(
    records: Sequence[TrialRecord], measured: Sequence[bool]
) -> Iterator[tuple[int, str]]:
    """``(index, fault)`` for every record whose ``reward_l2`` is not ``||Phi theta - Phi
    theta_hat||_2`` recomputed (records with ``K`` weights and centers only, within the
    bounds, whose measures are sound: ``measured``); records of one grid and ``K`` are
    computed together, :data:`_STACKED_ENTRIES` feature values at a time."""
    together: dict[tuple[Grid, int], list[int]] = defaultdict(list)
    for index, (r, sound) in enumerate(zip(records, measured, strict=True)):
        if sound and _sized(r) and not _size_faults(r):
            together[r.grid, r.num_features].append(index)
    for (grid, k), group in together.items():
        step = max(1, _STACKED_ENTRIES // (grid.width * grid.height * k))
        for start in range(0, len(group), step):
            yield from _l2_faults(records, group[start : start + step])


def _l2_faults(records: Sequence[TrialRecord], indices: list[int]) -> Iterator[tuple[int, str]]:
    """:func:`_reward_l2_faults` of ``records[i]`` for ``i`` in ``indices`` (one grid and
    ``K``), in one array product."""
    chosen = [records[i] for i in indices]
    features = np.stack([_feature_matrix(r.grid, r.features) for r in chosen])
    theta = np.array([r.theta for r in chosen], dtype=np.float64)
    theta_hat = np.array([r.theta_hat for r in chosen], dtype=np.float64)
    expected = np.linalg.norm(np.einsum("bsk,bk->bs", features, theta - theta_hat), axis=1)
    for index, r, value in zip(indices, chosen, expected.tolist(), strict=True):
        logged = r.measures["reward_l2"]
        if not math.isclose(logged, value, rel_tol=L2_TOLERANCE, abs_tol=L2_TOLERANCE):
            yield (
                index,
                f"measures.reward_l2 is {logged} but ||Phi theta - Phi theta_hat|| = {value}",
            )


@functools.lru_cache(maxsize=64)
def _moves(grid: Grid) -> dict[tuple[Cell, Cell], str]:
    """Every move on ``grid`` as ``(cell, next cell) -> action``, ``stay`` included."""
    world = _gridworld(grid)
    return {
        ((x, y), (x + dx, y + dy)): action
        for x in range(world.width)
        for y in range(world.height)
        for action, (dx, dy) in zip(ACTIONS, ACTION_STEPS, strict=True)
        if world.contains(x + dx, y + dy)
    }


@functools.lru_cache(maxsize=64)
def _gridworld(grid: Grid) -> Gridworld:
    return Gridworld(grid.width, grid.height)


def _feature_matrix(grid: Grid, features: Features) -> NDArray[np.float64]:
    """``Phi`` of a grid and its features, computed once for all the trials of a subject when
    it is small (:data:`_CACHED_FEATURE_ENTRIES`)."""
    if grid.width * grid.height * features.count > _CACHED_FEATURE_ENTRIES:
        return _features(grid, features)
    return _cached_features(grid, features)


def _features(grid: Grid, features: Features) -> NDArray[np.float64]:
    """``Phi`` (:func:`cirl_study.features.feature_matrix`) by numpy's ``exp``: within an ulp
    of the trial's features (the C library's, :func:`~cirl_study.core.gridworld.feature_matrix`),
    far inside :data:`L2_TOLERANCE`, and it keeps the compiler out of the log reader."""
    matrix = feature_matrix(grid.width, grid.height, features)
    matrix.flags.writeable = False
    return matrix


_cached_features = functools.lru_cache(maxsize=4096)(_features)


def _path_faults(
    name: str,
    path: Sequence[Sequence[int]],
    start: Sequence[int],
    steps: int,
    grid: Gridworld,
    goals: tuple[Cell, ...],
) -> Iterator[str]:
    """Faults of ``path`` as a walk of ``steps`` available moves from ``start`` (with ``goals``,
    of at most ``steps`` moves ending on its first goal)."""
    if not goals and len(path) != steps + 1:
        yield f"{name} has {len(path)} cells, expected {steps} steps + 1"
    if goals and not 2 <= len(path) <= steps + 1:
        yield f"{name} has {len(path)} cells, expected 1 to {steps} steps + 1"
    if tuple(path[0]) != tuple(start):
        yield f"{name} starts at {list(path[0])}, not at {list(start)}"
    for t, cell in enumerate(path):
        if not grid.contains(*cell):
            yield f"{name}[{t}] = {list(cell)} is outside the {grid.width}x{grid.height} grid"
            return
    for t in range(1, len(path)):
        if action_between(path[t - 1], path[t]) is None:
            yield f"{name} jumps from {list(path[t - 1])} to {list(path[t])} at step {t}"
            return
    if goals and tuple(path[-1]) not in goals:
        yield f"{name} ends at {list(path[-1])}, which is not a goal"
    for t, cell in enumerate(path[:-1]):
        if goals and tuple(cell) in goals:
            yield f"{name} enters the goal {list(cell)} at step {t} and goes on"
            return
