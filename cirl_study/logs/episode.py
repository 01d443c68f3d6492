"""The messages that log one trial: its record, its reward maps and its per-step replay.

See :mod:`cirl_study.logs.format` for the topics and the time layout. Everything here is a
pure function of the record and the trial's start time, so equal records logged at the same
position of a file give byte-identical messages.
"""

from __future__ import annotations

import base64
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from cirl_study.logs.actions import action_between
from cirl_study.logs.format import (
    DEMONSTRATION_TOPIC,
    DEPLOYMENT_TOPIC,
    MAP_REWARD_TOPIC,
    STEP_NS,
    TRIAL_TOPIC,
    TRUE_REWARD_TOPIC,
)
from cirl_study.logs.rewards import feature_matrix
from cirl_study.logs.schemas import FLOAT32

#: Frame of reference of the reward maps: cell [x, y] is centred on the point (x, y).
GRID_FRAME = "grid"


@dataclass(frozen=True)
class LogMessage:
    """One message to log: its topic, its log time in nanoseconds and its JSON payload."""

    topic: str
    log_time: int
    payload: Mapping[str, Any]


def episode_messages(record: Mapping[str, Any], start_ns: int) -> list[LogMessage]:
    """All messages of one trial, in log-time order, for a trial starting at ``start_ns``."""
    features = feature_matrix(record)
    messages = [
        LogMessage(TRIAL_TOPIC, start_ns, record),
        LogMessage(TRUE_REWARD_TOPIC, start_ns, reward_grid(record, features, "theta", start_ns)),
        LogMessage(
            MAP_REWARD_TOPIC, start_ns, reward_grid(record, features, "theta_hat", start_ns)
        ),
    ]
    actions = record["demonstration"]["actions"]
    for t, cell in enumerate(record["demonstration"]["states"]):
        step = {
            "trial_id": record["trial_id"],
            "policy": record["policy"],
            "step": t,
            "cell": cell,
            "action": actions[t - 1] if t > 0 else None,
        }
        messages.append(LogMessage(DEMONSTRATION_TOPIC, start_ns + t * STEP_NS, step))
    if "deployment" in record:
        offset_ns = start_ns + (record["learning_steps"] + 1) * STEP_NS
        paths = record["deployment"]["paths"]
        for t in range(min((len(path) for path in paths), default=0)):
            step = {
                "trial_id": record["trial_id"],
                "policy": record["policy"],
                "step": t,
                "cells": [path[t] for path in paths],
                "actions": [
                    action_between(path[t - 1], path[t]) if t > 0 else None for path in paths
                ],
            }
            messages.append(LogMessage(DEPLOYMENT_TOPIC, offset_ns + t * STEP_NS, step))
    return messages


def replay_counts(record: Mapping[str, Any]) -> dict[str, int]:
    """How many messages :func:`episode_messages` logs on each topic besides the trial's."""
    paths = record["deployment"]["paths"] if "deployment" in record else []
    return {
        TRUE_REWARD_TOPIC: 1,
        MAP_REWARD_TOPIC: 1,
        DEMONSTRATION_TOPIC: len(record["demonstration"]["states"]),
        DEPLOYMENT_TOPIC: min((len(path) for path in paths), default=0),
    }


def reward_grid(
    record: Mapping[str, Any], features: np.ndarray, weights: str, time_ns: int
) -> dict[str, Any]:
    """A ``foxglove.Grid`` of the cell rewards ``Phi w`` for ``w = record[weights]``.

    ``features`` is ``Phi`` (:func:`~cirl_study.logs.rewards.feature_matrix`); the values are
    float32, by flat index ``y * width + x``, i.e. rows from ``y = 0`` upwards.

    The grid's corner is placed at ``(-0.5, -0.5)`` so that cell ``[x, y]`` is centred on the
    point ``(x, y)`` of the ``grid`` frame, the coordinates the RBF centres use.
    """
    width = record["grid"]["width"]
    values = (features @ np.asarray(record[weights], dtype=float)).astype("<f4")
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
