"""Is a logged trial payload a record (its types), and is the record consistent (the game's rules)?

Types and ranges are checked by decoding into :class:`~cirl_study.record.TrialRecord`
(:func:`decode_trial`). Consistency, in docs/design.md's notation: ``len(theta) =
len(theta_hat) = K`` = number of RBF centres; the start cell ``s_0`` lies on the grid; the
demonstration is a path ``(s_0, ..., s_T_learn)`` of available moves from ``s_0`` with
``T_learn`` actions, each the move between consecutive cells, none of them ``stay`` unless
``demonstrator_stays``; every deployment rollout is such a path of ``T_deploy`` moves from its
start, which is the demonstration's start when ``deployment_start`` says so; ``regret >= 0``
and ``kl >= 0`` (up to rounding);
``reward_l2 = ||Phi theta - Phi theta_hat||_2`` recomputed from the record (here, not by the
code that logged it; the records of one grid and ``K`` in one array product). The policy and the
robot are registered ones (:data:`~cirl_study.core.players.HUMANS`,
:data:`~cirl_study.core.players.ROBOTS`), ``eta`` is null exactly for a policy without a
trade-off, and a record with a teaching human or robot has its hypothesis space (``teaching``).
"""

from __future__ import annotations

import functools
import math
from collections import defaultdict
from collections.abc import Iterable, Iterator, Sequence

import msgspec
import numpy as np
from numpy.typing import NDArray

from cirl_study.core.gridworld import ACTION_STEPS, ACTIONS, Gridworld, action_between, rbf_features
from cirl_study.core.players import player_faults
from cirl_study.record import (
    Cell,
    DecodeError,
    Grid,
    RBFFeatures,
    TrialRecord,
    decode,
    setting_faults,
)

NEGATIVE_TOLERANCE = 1e-9
"""Rounding allowed below zero for measures that are non-negative in exact arithmetic."""

L2_TOLERANCE = 1e-9
"""Relative and absolute tolerance when recomputing ``reward_l2``."""


class _Labelled(msgspec.Struct):
    trial_id: str


def payload_trial_id(data: bytes) -> str | None:
    """The ``trial_id`` of a payload that may not be a valid record, if it has one."""
    try:
        return msgspec.json.decode(data, type=_Labelled).trial_id
    except msgspec.DecodeError:
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
        (r, next(faults)) if isinstance(r, TrialRecord) else (None, [f"not a trial record: {r}"])
        for r in decoded
    ]


def record_faults(record: TrialRecord) -> list[str]:
    """Every inconsistency of a decoded trial record (empty for a sound one)."""
    return records_faults([record])[0]


def records_faults(records: Sequence[TrialRecord]) -> list[list[str]]:
    """:func:`record_faults` of every record; the ``reward_l2`` checks are one array
    product per grid and ``K`` (:func:`_reward_l2_faults`) instead of one per record."""
    faults = [list(_inconsistencies(r)) for r in records]
    for index, fault in _reward_l2_faults(records):
        faults[index].append(fault)
    return faults


def _inconsistencies(r: TrialRecord) -> Iterator[str]:
    """Every inconsistency of ``r`` but its ``reward_l2``, each named.

    Each rule is written once. A path is first walked through the grid's move table
    (:func:`_walk`, one lookup per step: the case of a sound record, which the reader meets
    most); only a path that fails it is examined cell by cell (:func:`_path_faults`) to name
    what breaks.
    """
    yield from player_faults(r.policy, r.robot, r.eta, r.teaching is not None)
    yield from setting_faults(r)
    if len(r.theta_hat) != r.num_features:
        yield f"theta_hat has {len(r.theta_hat)} entries, num_features is {r.num_features}"
    grid = _gridworld(r.grid)
    moves = _moves(r.grid)
    states, actions = r.demonstration.states, r.demonstration.actions
    walked = _walk(states, r.start, r.learning_steps, moves)
    if walked is None:
        yield from _path_faults("demonstration.states", states, r.start, r.learning_steps, grid)
    if len(actions) != r.learning_steps:
        yield f"demonstration has {len(actions)} actions, learning_steps is {r.learning_steps}"
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
    if r.deployment is not None:
        starts, paths = r.deployment.starts, r.deployment.paths
        if r.deployment_start == "demonstration" and any(s != r.start for s in starts):
            yield f"a deployment rollout starts away from the demonstration's start {list(r.start)}"
        if len(starts) != len(paths):
            yield f"deployment has {len(starts)} starts and {len(paths)} paths"
        for i, (start, path) in enumerate(zip(starts, paths, strict=False)):
            if _walk(path, start, r.deployment_steps, moves) is None:
                yield from _path_faults(
                    f"deployment.paths[{i}]", path, start, r.deployment_steps, grid
                )
    for name in ("regret", "kl"):
        value = getattr(r.measures, name)
        if value < -NEGATIVE_TOLERANCE:
            yield f"measures.{name} is {value} < 0"


def _walk(
    path: Sequence[Cell], start: Cell, steps: int, moves: dict[tuple[Cell, Cell], str]
) -> tuple[str, ...] | None:
    """The actions of ``path`` if it is a walk of ``steps`` available moves from ``start``
    (``steps >= 1``), else ``None`` (also for cells that are not tuples)."""
    if steps < 1 or len(path) != steps + 1 or path[0] != start:
        return None
    try:
        return tuple(map(moves.__getitem__, zip(path, path[1:], strict=False)))
    except (KeyError, TypeError):
        return None


def _sized(r: TrialRecord) -> bool:
    """Whether ``theta``, ``theta_hat`` and the centres all have ``num_features`` entries."""
    return len(r.theta) == len(r.theta_hat) == len(r.features.centers) == r.num_features


def _reward_l2_faults(records: Sequence[TrialRecord]) -> Iterator[tuple[int, str]]:
    """``(index, fault)`` for every record whose ``reward_l2`` is not ``||Phi theta - Phi
    theta_hat||_2`` recomputed (records with ``K`` weights and centres only); records of one
    grid and ``K`` are computed together."""
    together: dict[tuple[Grid, int], list[int]] = defaultdict(list)
    for index, r in enumerate(records):
        if _sized(r):
            together[r.grid, r.num_features].append(index)
    for indices in together.values():
        chosen = [records[i] for i in indices]
        features = np.stack([_feature_matrix(r.grid, r.features) for r in chosen])
        theta = np.array([r.theta for r in chosen], dtype=np.float64)
        theta_hat = np.array([r.theta_hat for r in chosen], dtype=np.float64)
        expected = np.linalg.norm(np.einsum("bsk,bk->bs", features, theta - theta_hat), axis=1)
        for index, r, value in zip(indices, chosen, expected.tolist(), strict=True):
            logged = r.measures.reward_l2
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


@functools.lru_cache(maxsize=4096)
def _feature_matrix(grid: Grid, features: RBFFeatures) -> NDArray[np.float64]:
    """``Phi`` of a grid and its features, computed once for all the trials of a subject."""
    matrix = rbf_features(_gridworld(grid), features.centers, features.sigma)
    matrix.flags.writeable = False
    return matrix


def _path_faults(
    name: str,
    path: Sequence[Sequence[int]],
    start: Sequence[int],
    steps: int,
    grid: Gridworld,
) -> Iterator[str]:
    """Faults of ``path`` as a walk of ``steps`` available moves from ``start``."""
    if len(path) != steps + 1:
        yield f"{name} has {len(path)} cells, expected {steps} steps + 1"
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
