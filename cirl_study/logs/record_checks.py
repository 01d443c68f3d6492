"""Is a trial record complete (the JSON schema) and consistent (the game's rules)?

Consistency, in DESIGN.md's notation: ``eta`` is null exactly for the expert;
``len(theta) = len(theta_hat) = K`` = number of RBF centres; the start cell ``s_0`` lies on
the grid; the demonstration is a path ``(s_0, ..., s_T_learn)`` of available moves from
``s_0`` with ``T_learn`` actions, each the move between consecutive cells; every deployment
rollout is such a path of ``T_deploy`` moves from its start; ``regret >= 0`` and ``kl >= 0``;
``reward_l2 = ||Phi theta - Phi theta_hat||_2`` recomputed from the record.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

from cirl_study.logs.actions import action_between, inside
from cirl_study.logs.json_schema import compile_validator, schema_errors
from cirl_study.logs.rewards import reward_l2
from cirl_study.logs.schemas import TRIAL_SCHEMA

_IS_TRIAL = compile_validator(TRIAL_SCHEMA)

#: Rounding allowed below zero for measures that are non-negative in exact arithmetic.
NEGATIVE_TOLERANCE = 1e-9
#: Relative and absolute tolerance when recomputing ``reward_l2``.
L2_TOLERANCE = 1e-9


def record_faults(record: Any) -> list[str]:
    """Every fault of a trial record: schema violations first, else inconsistencies."""
    if not _IS_TRIAL(record):
        return schema_errors(record, TRIAL_SCHEMA)
    return list(_inconsistencies(record))


def _inconsistencies(r: Mapping[str, Any]) -> Iterator[str]:
    if (r["eta"] is None) != (r["policy"] == "expert"):
        yield f"eta is {r['eta']} for policy {r['policy']} (null exactly for the expert)"
    k = r["num_features"]
    lengths = {
        "theta": len(r["theta"]),
        "theta_hat": len(r["theta_hat"]),
        "features.centers": len(r["features"]["centers"]),
    }
    for name, length in lengths.items():
        if length != k:
            yield f"{name} has {length} entries, num_features is {k}"
    width, height = r["grid"]["width"], r["grid"]["height"]
    if not inside(r["start"], width, height):
        yield f"start {r['start']} is outside the {width}x{height} grid"
    states = r["demonstration"]["states"]
    yield from _path_faults(
        "demonstration.states", states, r["start"], r["learning_steps"], width, height
    )
    actions = r["demonstration"]["actions"]
    if len(actions) != r["learning_steps"]:
        yield f"demonstration has {len(actions)} actions, learning_steps is {r['learning_steps']}"
    for t, (action, cell, next_cell) in enumerate(zip(actions, states, states[1:], strict=False)):
        if action != action_between(cell, next_cell):
            yield f"demonstration.actions[{t}] is {action} but the path moves {cell} -> {next_cell}"
            break
    if "deployment" in r:
        starts, paths = r["deployment"]["starts"], r["deployment"]["paths"]
        if len(starts) != len(paths):
            yield f"deployment has {len(starts)} starts and {len(paths)} paths"
        for i, (start, path) in enumerate(zip(starts, paths, strict=False)):
            yield from _path_faults(
                f"deployment.paths[{i}]", path, start, r["deployment_steps"], width, height
            )
    measures = r["measures"]
    for name in ("regret", "kl"):
        if measures[name] < -NEGATIVE_TOLERANCE:
            yield f"measures.{name} is {measures[name]} < 0"
    if all(length == k for length in lengths.values()):
        expected = reward_l2(r)
        if not math.isclose(
            measures["reward_l2"], expected, rel_tol=L2_TOLERANCE, abs_tol=L2_TOLERANCE
        ):
            yield (
                f"measures.reward_l2 is {measures['reward_l2']} but "
                f"||Phi theta - Phi theta_hat|| = {expected}"
            )


def _path_faults(
    name: str,
    path: Sequence[Sequence[int]],
    start: Sequence[int],
    steps: int,
    width: int,
    height: int,
) -> Iterator[str]:
    """Faults of ``path`` as a walk of ``steps`` available moves from ``start``."""
    if len(path) != steps + 1:
        yield f"{name} has {len(path)} cells, expected {steps} steps + 1"
    if path[0] != start:
        yield f"{name} starts at {path[0]}, not at {start}"
    for t, cell in enumerate(path):
        if not inside(cell, width, height):
            yield f"{name}[{t}] = {cell} is outside the {width}x{height} grid"
            return
    for t in range(1, len(path)):
        if action_between(path[t - 1], path[t]) is None:
            yield f"{name} jumps from {path[t - 1]} to {path[t]} at step {t}"
            return
