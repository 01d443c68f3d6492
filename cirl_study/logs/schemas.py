"""JSON schemas of the log topics (schema encoding ``jsonschema``).

:data:`TRIAL_SCHEMA` is the trial record of DESIGN.md section 7: every field listed there is
required; more fields (``irl``, ``deployment``) are allowed. :data:`GRID_SCHEMA` is Foxglove's
``foxglove.Grid`` message in its JSON form, so Foxglove draws the reward maps in its 3D panel.
"""

from __future__ import annotations

from typing import Any

from cirl_study.gridworld import ACTIONS

_DRAFT = "https://json-schema.org/draft/2020-12/schema"

CELL: dict[str, Any] = {
    "description": "a grid cell [x, y], 0 <= x < width, 0 <= y < height",
    "type": "array",
    "items": {"type": "integer", "minimum": 0},
    "minItems": 2,
    "maxItems": 2,
}

_POINT: dict[str, Any] = {
    "type": "array",
    "items": {"type": "number"},
    "minItems": 2,
    "maxItems": 2,
}

_WEIGHTS: dict[str, Any] = {
    "type": "array",
    "items": {"type": "number", "minimum": -1, "maximum": 1},
    "minItems": 1,
}

_PATH: dict[str, Any] = {"type": "array", "items": CELL, "minItems": 1}

TRIAL_SCHEMA: dict[str, Any] = {
    "$schema": _DRAFT,
    "title": "cirl_study.Trial",
    "description": "One trial (episode) of the CIRL gridworld study (DESIGN.md section 7).",
    "type": "object",
    "required": [
        "trial_id",
        "run_id",
        "block",
        "subject",
        "policy",
        "num_features",
        "rationality",
        "eta",
        "seed",
        "grid",
        "start",
        "learning_steps",
        "deployment_steps",
        "features",
        "theta",
        "theta_hat",
        "demonstration",
        "measures",
    ],
    "properties": {
        "trial_id": {"description": "stable id of the trial", "type": "string", "minLength": 1},
        "run_id": {"description": "id of the run", "type": "string", "minLength": 1},
        "block": {"type": "string", "enum": ["main", "eta_cv", "lambda_sweep"]},
        "subject": {
            "description": "reward-draw id, unique across feature levels",
            "type": "string",
            "minLength": 1,
        },
        "policy": {"type": "string", "enum": ["expert", "best_response"]},
        "num_features": {"description": "K", "type": "integer", "minimum": 1},
        "rationality": {"description": "lambda", "type": "number", "exclusiveMinimum": 0},
        "eta": {
            "description": "best-response weight eta; null for the expert",
            "type": ["number", "null"],
            "exclusiveMinimum": 0,
        },
        "seed": {"description": "seed of the trial's generator", "type": "integer", "minimum": 0},
        "grid": {
            "type": "object",
            "required": ["width", "height"],
            "properties": {
                "width": {"type": "integer", "minimum": 1},
                "height": {"type": "integer", "minimum": 1},
            },
        },
        "start": CELL,
        "learning_steps": {"description": "T_learn", "type": "integer", "minimum": 1},
        "deployment_steps": {"description": "T_deploy", "type": "integer", "minimum": 1},
        "features": {
            "type": "object",
            "required": ["kind", "centers", "sigma"],
            "properties": {
                "kind": {"type": "string", "enum": ["rbf"]},
                "centers": {"type": "array", "items": _POINT, "minItems": 1},
                "sigma": {"type": "number", "exclusiveMinimum": 0},
            },
        },
        "theta": _WEIGHTS,
        "theta_hat": _WEIGHTS,
        "demonstration": {
            "type": "object",
            "required": ["states", "actions"],
            "properties": {
                "states": _PATH,
                "actions": {"type": "array", "items": {"type": "string", "enum": list(ACTIONS)}},
            },
        },
        "measures": {
            "type": "object",
            "required": ["regret", "kl", "reward_l2"],
            "properties": {
                "regret": {"type": "number"},
                "kl": {"type": "number"},
                "reward_l2": {"type": "number", "minimum": 0},
            },
        },
        "irl": {
            "type": "object",
            "properties": {
                "log_likelihood": {"type": "number"},
                "iterations": {"type": "integer", "minimum": 0},
                "converged": {"type": "boolean"},
            },
        },
        "deployment": {
            "description": "robot rollouts under the MAP reward from a few start cells",
            "type": "object",
            "required": ["starts", "paths"],
            "properties": {
                "starts": {"type": "array", "items": CELL},
                "paths": {"type": "array", "items": _PATH},
            },
        },
    },
}

_ACTION_OR_NULL: dict[str, Any] = {"type": ["string", "null"], "enum": [*ACTIONS, None]}

DEMONSTRATION_SCHEMA: dict[str, Any] = {
    "$schema": _DRAFT,
    "title": "cirl_study.DemonstrationStep",
    "description": "The human's cell at step t of the learning phase.",
    "type": "object",
    "required": ["trial_id", "policy", "step", "cell", "action"],
    "properties": {
        "trial_id": {"type": "string"},
        "policy": {"type": "string"},
        "step": {"description": "t, 0 = start cell", "type": "integer", "minimum": 0},
        "cell": CELL,
        "action": {**_ACTION_OR_NULL, "description": "the move into this cell; null at t = 0"},
    },
}

DEPLOYMENT_SCHEMA: dict[str, Any] = {
    "$schema": _DRAFT,
    "title": "cirl_study.DeploymentStep",
    "description": "The robot's cell at step t of each deployment rollout (record.deployment).",
    "type": "object",
    "required": ["trial_id", "policy", "step", "cells", "actions"],
    "properties": {
        "trial_id": {"type": "string"},
        "policy": {"type": "string"},
        "step": {"description": "t, 0 = start cells", "type": "integer", "minimum": 0},
        "cells": {"description": "cell of rollout i at step t", "type": "array", "items": CELL},
        "actions": {
            "description": "move of rollout i into its cell; all null at t = 0",
            "type": "array",
            "items": _ACTION_OR_NULL,
        },
    },
}

#: Foxglove's ``NumericType`` value for a little-endian 32-bit float.
FLOAT32 = 7

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
