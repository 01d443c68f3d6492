"""The messages that log one trial: its record, its reward maps and its per-step replay.

See :mod:`cirl_study.logs.format` for the topics and the time layout. Everything here is a
pure function of the record and the trial's start time, so equal records logged at the same
position of a file give byte-identical messages.
"""

from __future__ import annotations

import base64
from dataclasses import dataclass
from typing import Any

import numpy as np

from cirl_study.core.gridworld import action_between, feature_matrix
from cirl_study.logs.format import (
    DEMONSTRATION_TOPIC,
    DEPLOYMENT_TOPIC,
    MAP_REWARD_TOPIC,
    STEP_NS,
    TRIAL_TOPIC,
    TRUE_REWARD_TOPIC,
)
from cirl_study.logs.schemas import FLOAT32, DemonstrationStep, DeploymentStep
from cirl_study.record import TrialRecord

GRID_FRAME = "grid"
"""Frame of reference of the reward maps: cell [x, y] is centered on the point (x, y)."""


@dataclass(frozen=True)
class LogMessage:
    """One message to log: its topic, its log time in nanoseconds and its payload."""

    topic: str
    log_time: int
    payload: Any


def episode_messages(record: TrialRecord, start_ns: int) -> list[LogMessage]:
    """All messages of one trial, in log-time order, for a trial starting at ``start_ns``."""
    features = feature_matrix(record)
    messages = [
        LogMessage(TRIAL_TOPIC, start_ns, record),
        LogMessage(
            TRUE_REWARD_TOPIC, start_ns, reward_grid(record, features, record.theta, start_ns)
        ),
        LogMessage(
            MAP_REWARD_TOPIC, start_ns, reward_grid(record, features, record.theta_hat, start_ns)
        ),
    ]
    actions = record.demonstration.actions
    for t, cell in enumerate(record.demonstration.states):
        step = DemonstrationStep(
            trial_id=record.trial_id,
            human=record.human,
            step=t,
            cell=cell,
            action=actions[t - 1] if t > 0 else None,
        )
        messages.append(LogMessage(DEMONSTRATION_TOPIC, start_ns + t * STEP_NS, step))
    offset_ns = start_ns + (record.learning_steps + 1) * STEP_NS
    paths = record.deployment.paths if record.deployment is not None else ()
    for t in range(min((len(path) for path in paths), default=0)):
        step = DeploymentStep(
            trial_id=record.trial_id,
            human=record.human,
            step=t,
            cells=tuple(path[t] for path in paths),
            actions=tuple(
                action_between(path[t - 1], path[t]) if t > 0 else None for path in paths
            ),
        )
        messages.append(LogMessage(DEPLOYMENT_TOPIC, offset_ns + t * STEP_NS, step))
    return messages


def replay_counts(record: TrialRecord) -> dict[str, int]:
    """How many messages :func:`episode_messages` logs on each topic besides the trial's."""
    paths = record.deployment.paths if record.deployment is not None else ()
    return {
        TRUE_REWARD_TOPIC: 1,
        MAP_REWARD_TOPIC: 1,
        DEMONSTRATION_TOPIC: len(record.demonstration.states),
        DEPLOYMENT_TOPIC: min((len(path) for path in paths), default=0),
    }


def reward_grid(
    record: TrialRecord, features: np.ndarray, weights: tuple[float, ...], time_ns: int
) -> dict[str, Any]:
    """A ``foxglove.Grid`` of the cell rewards ``Phi w`` for the weights ``w``.

    ``features`` is ``Phi`` (:func:`~cirl_study.core.gridworld.feature_matrix`); the values
    are float32, by flat index ``y * width + x``, i.e. rows from ``y = 0`` upwards.

    The grid's corner is placed at ``(-0.5, -0.5)`` so that cell ``[x, y]`` is centered on the
    point ``(x, y)`` of the ``grid`` frame, the coordinates the RBF centers use.
    """
    width = record.grid.width
    values = (features @ np.asarray(weights, dtype=float)).astype("<f4")
    return {
        "timestamp": {"sec": time_ns // 1_000_000_000, "nsec": time_ns % 1_000_000_000},
        "frame_id": GRID_FRAME,
        "pose": {
            "position": {"x": -0.5, "y": -0.5, "z": 0.0},
            "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
        },
        "column_count": width,
        "cell_size": {"x": 1.0, "y": 1.0},
        "row_stride": 4 * width,
        "cell_stride": 4,
        "fields": [{"name": "reward", "offset": 0, "type": FLOAT32}],
        "data": base64.b64encode(values.tobytes()).decode("ascii"),
    }
