"""Is a logged trial payload a record (its types), and is the record consistent (the game's rules)?

Types and ranges are checked by decoding into :class:`~cirl_study.record.TrialRecord`
(:func:`decode_trial`). Consistency, in docs/design.md's notation: ``len(theta) =
len(theta_hat) = K`` = number of RBF centres; the start cell ``s_0`` lies on the grid; the
demonstration is a path ``(s_0, ..., s_T_learn)`` of available moves from ``s_0`` with
``T_learn`` actions, each the move between consecutive cells, none of them ``stay`` unless
``demonstrator_stays``; every deployment rollout is such a path of ``T_deploy`` moves from its
start, which is the demonstration's start when ``deployment_start`` says so; ``regret >= 0``
and ``kl >= 0`` (up to rounding);
``reward_l2 = ||Phi theta - Phi theta_hat||_2`` recomputed from the record. The policy and the
robot are registered ones (:data:`~cirl_study.core.players.HUMANS`,
:data:`~cirl_study.core.players.ROBOTS`), ``eta`` is null exactly for a policy without a
trade-off, and a record with a teaching human or robot has its hypothesis space (``teaching``).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Iterator, Sequence

import msgspec
import numpy as np
from numpy.typing import NDArray

from cirl_study.core.gridworld import Gridworld, action_between, rbf_features
from cirl_study.core.measures import reward_l2
from cirl_study.core.players import HUMANS, ROBOTS
from cirl_study.record import DecodeError, Grid, RBFFeatures, TrialRecord, decode

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
    try:
        record = decode(data)
    except DecodeError as error:
        return None, [f"not a trial record: {error}"]
    return record, record_faults(record)


def record_faults(record: TrialRecord) -> list[str]:
    """Every inconsistency of a decoded trial record (empty for a sound one)."""
    return list(_inconsistencies(record))


def _inconsistencies(r: TrialRecord) -> Iterator[str]:
    human = HUMANS.get(r.policy)
    if human is None:
        yield f"policy {r.policy!r} is not a known human policy ({', '.join(HUMANS)})"
    elif (r.eta is None) == human.takes_eta:
        yield (
            f"eta is {r.eta} for policy {r.policy} (null exactly for a policy without a trade-off)"
        )
    robot = ROBOTS.get(r.robot)
    if robot is None:
        yield f"robot {r.robot!r} is not a known robot ({', '.join(ROBOTS)})"
    teaches = [
        name for name, player in ((r.policy, human), (r.robot, robot)) if player and player.teaches
    ]
    if teaches and r.teaching is None:
        yield f"{' and '.join(teaches)} need a hypothesis space, and teaching is null"
    k = r.num_features
    lengths = {
        "theta": len(r.theta),
        "theta_hat": len(r.theta_hat),
        "features.centers": len(r.features.centers),
    }
    for name, length in lengths.items():
        if length != k:
            yield f"{name} has {length} entries, num_features is {k}"
    grid = _gridworld(r.grid)
    if not grid.contains(*r.start):
        yield f"start {list(r.start)} is outside the {grid.width}x{grid.height} grid"
    states, actions = r.demonstration.states, r.demonstration.actions
    yield from _path_faults("demonstration.states", states, r.start, r.learning_steps, grid)
    if len(actions) != r.learning_steps:
        yield f"demonstration has {len(actions)} actions, learning_steps is {r.learning_steps}"
    for t, (action, cell, next_cell) in enumerate(zip(actions, states, states[1:], strict=False)):
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
            yield from _path_faults(f"deployment.paths[{i}]", path, start, r.deployment_steps, grid)
    for name in ("regret", "kl"):
        value = getattr(r.measures, name)
        if value < -NEGATIVE_TOLERANCE:
            yield f"measures.{name} is {value} < 0"
    if all(length == k for length in lengths.values()):
        features = _feature_matrix(r.grid, r.features)[None]
        expected = float(reward_l2(features, np.array([r.theta]), np.array([r.theta_hat]))[0])
        if not math.isclose(
            r.measures.reward_l2, expected, rel_tol=L2_TOLERANCE, abs_tol=L2_TOLERANCE
        ):
            yield (
                f"measures.reward_l2 is {r.measures.reward_l2} but "
                f"||Phi theta - Phi theta_hat|| = {expected}"
            )


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
    if len(path) == steps + 1 and tuple(path[0]) == tuple(start) and _walks(path, grid):
        return
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


def _walks(path: Sequence[Sequence[int]], grid: Gridworld) -> bool:
    """Whether every cell of a non-empty ``path`` is on ``grid`` and each step moves at most
    one cell along one axis: a sound path's check in one pass (the reader's most frequent)."""
    width, height = grid.width, grid.height
    cells = iter(path)
    last_x, last_y = next(cells)
    if not (0 <= last_x < width and 0 <= last_y < height):
        return False
    for x, y in cells:
        if not (0 <= x < width and 0 <= y < height) or abs(x - last_x) + abs(y - last_y) > 1:
            return False
        last_x, last_y = x, y
    return True
