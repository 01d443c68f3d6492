"""The message types of the log topics and their JSON schemas (schema encoding ``jsonschema``).

The trial record's schema is generated from :class:`cirl_study.record.TrialRecord`, and the
replay steps' from :class:`DemonstrationStep` and :class:`DeploymentStep`, so a schema can never
disagree with the messages written under it. :data:`GRID_SCHEMA` is Foxglove's
``foxglove.Grid`` message in its JSON form, so Foxglove draws the reward maps in its 3D panel.
It is written out here because the official ``foxglove-sdk`` package ships protobuf
descriptors only; ``tests/test_logs_foxglove.py`` holds it to the SDK's descriptor field by
field, and every logged grid to the SDK's own ``Grid`` type.
:data:`CHANNELS` lists every channel a log file registers.
"""

from __future__ import annotations

from typing import Any

import msgspec

from cirl_study.logs.format import (
    DEMONSTRATION_SCHEMA_NAME,
    DEMONSTRATION_TOPIC,
    DEPLOYMENT_SCHEMA_NAME,
    DEPLOYMENT_TOPIC,
    GRID_SCHEMA_NAME,
    MAP_REWARD_TOPIC,
    TRIAL_SCHEMA_NAME,
    TRIAL_TOPIC,
    TRUE_REWARD_TOPIC,
)
from cirl_study.record import TRIAL_SCHEMA, Action, Cell


class DemonstrationStep(msgspec.Struct, frozen=True, kw_only=True):
    """The human's cell at step ``t`` of the learning phase (0 = the start cell), and the move
    into it (``None`` at ``t = 0``)."""

    trial_id: str
    human: str
    step: int
    cell: Cell
    action: Action | None


class DeploymentStep(msgspec.Struct, frozen=True, kw_only=True):
    """The robot's cell at step ``t`` of each deployment rollout (``record.deployment``), and the
    moves into them (all ``None`` at ``t = 0``)."""

    trial_id: str
    human: str
    step: int
    cells: tuple[Cell, ...]
    actions: tuple[Action | None, ...]


FLOAT32 = 7
"""Foxglove's ``NumericType`` value for a little-endian 32-bit float."""

_XYZ = {axis: {"type": "number"} for axis in ("x", "y", "z")}

GRID_SCHEMA: dict[str, Any] = {
    "title": "foxglove.Grid",
    "description": "A 2D grid of data",
    "type": "object",
    "properties": {
        "timestamp": {
            "type": "object",
            "title": "time",
            "properties": {
                "sec": {"type": "integer", "minimum": 0},
                "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999},
            },
        },
        "frame_id": {"type": "string"},
        "pose": {
            "title": "foxglove.Pose",
            "type": "object",
            "properties": {
                "position": {"title": "foxglove.Vector3", "type": "object", "properties": _XYZ},
                "orientation": {
                    "title": "foxglove.Quaternion",
                    "type": "object",
                    "properties": {**_XYZ, "w": {"type": "number"}},
                },
            },
        },
        "column_count": {"type": "integer", "minimum": 0},
        "cell_size": {
            "title": "foxglove.Vector2",
            "type": "object",
            "properties": {"x": {"type": "number"}, "y": {"type": "number"}},
        },
        "row_stride": {"type": "integer", "minimum": 0},
        "cell_stride": {"type": "integer", "minimum": 0},
        "fields": {
            "type": "array",
            "items": {
                "title": "foxglove.PackedElementField",
                "type": "object",
                "properties": {
                    "name": {"type": "string"},
                    "offset": {"type": "integer", "minimum": 0},
                    "type": {
                        "title": "foxglove.NumericType",
                        "type": "integer",
                        "enum": list(range(9)),
                        "description": "0 UNKNOWN, 1 UINT8, 2 INT8, 3 UINT16, 4 INT16, "
                        "5 UINT32, 6 INT32, 7 FLOAT32, 8 FLOAT64",
                    },
                },
            },
        },
        "data": {"type": "string", "contentEncoding": "base64"},
    },
}


CHANNELS: tuple[tuple[str, str, dict[str, Any]], ...] = (
    (TRIAL_TOPIC, TRIAL_SCHEMA_NAME, TRIAL_SCHEMA),
    (TRUE_REWARD_TOPIC, GRID_SCHEMA_NAME, GRID_SCHEMA),
    (MAP_REWARD_TOPIC, GRID_SCHEMA_NAME, GRID_SCHEMA),
    (DEMONSTRATION_TOPIC, DEMONSTRATION_SCHEMA_NAME, msgspec.json.schema(DemonstrationStep)),
    (DEPLOYMENT_TOPIC, DEPLOYMENT_SCHEMA_NAME, msgspec.json.schema(DeploymentStep)),
)
"""(topic, schema name, JSON schema) of every channel, in the order they are registered."""
