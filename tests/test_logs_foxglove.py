"""The reward maps are Foxglove's official ``foxglove.Grid``, checked against the definitions
the ``foxglove-sdk`` package ships (its protobuf descriptor), not only against our own copy.

Foxglove's JSON form of a message is its protobuf message with the same field names (bytes
base64-encoded, ``google.protobuf.Timestamp`` written as ``{sec, nsec}``). The JSON schema
``GRID_SCHEMA`` is kept by hand, in the JSON form Foxglove's 3D panel reads, because the SDK
ships only the protobuf descriptors; these tests hold it to them field by field, and hold
every logged grid to the SDK's own ``Grid`` type.
"""

from __future__ import annotations

import base64
import json
from pathlib import Path
from typing import Any

import pytest
from foxglove.messages import (
    Grid,
    PackedElementField,
    PackedElementFieldNumericType,
    Pose,
    Quaternion,
    Timestamp,
    Vector2,
    Vector3,
)
from google.protobuf import descriptor_pb2
from mcap.reader import make_reader

from cirl_study.logs.format import MAP_REWARD_TOPIC, TRUE_REWARD_TOPIC
from cirl_study.logs.schemas import FLOAT32, GRID_SCHEMA

F = descriptor_pb2.FieldDescriptorProto
JSON_TYPES = {
    F.TYPE_DOUBLE: "number",
    F.TYPE_FLOAT: "number",
    F.TYPE_FIXED32: "integer",
    F.TYPE_UINT32: "integer",
    F.TYPE_INT32: "integer",
    F.TYPE_INT64: "integer",
    F.TYPE_ENUM: "integer",
    F.TYPE_STRING: "string",
    F.TYPE_BYTES: "string",  # base64 in JSON
    F.TYPE_MESSAGE: "object",
}
TIMESTAMP_JSON = {"seconds": "sec", "nanos": "nsec"}
"""Foxglove's JSON names of ``google.protobuf.Timestamp``'s fields."""


def official_messages() -> dict[str, descriptor_pb2.DescriptorProto]:
    """Every message of the SDK's ``foxglove.Grid`` descriptor set, by full name."""
    files = descriptor_pb2.FileDescriptorSet.FromString(Grid.get_schema().data)
    return {f"{file.package}.{m.name}": m for file in files.file for m in file.message_type}


def _check(schema: dict[str, Any], message: str, messages: dict, where: str) -> None:
    fields = {field.name: field for field in messages[message].field}
    if message == "google.protobuf.Timestamp":
        fields = {TIMESTAMP_JSON[name]: field for name, field in fields.items()}
    assert set(schema["properties"]) == set(fields), where
    for name, property_schema in schema["properties"].items():
        field = fields[name]
        expected = JSON_TYPES[field.type]
        if field.label == F.LABEL_REPEATED:
            assert property_schema["type"] == "array", f"{where}.{name}"
            property_schema = property_schema["items"]
        assert property_schema["type"] == expected, f"{where}.{name}"
        if field.type == F.TYPE_BYTES:
            assert property_schema.get("contentEncoding") == "base64", f"{where}.{name}"
        if field.type == F.TYPE_MESSAGE:
            _check(property_schema, field.type_name.lstrip("."), messages, f"{where}.{name}")
        if field.type == F.TYPE_ENUM:
            enum = next(
                e for m in messages.values() for e in m.enum_type
                if field.type_name.endswith(f".{e.name}")
            )  # fmt: skip
            assert property_schema["enum"] == [value.number for value in enum.value]


def test_the_grid_schema_is_foxgloves_field_for_field() -> None:
    messages = official_messages()
    assert GRID_SCHEMA["title"] == "foxglove.Grid"
    _check(GRID_SCHEMA, "foxglove.Grid", messages, "foxglove.Grid")
    assert PackedElementFieldNumericType.Float32.value == FLOAT32


def logged_grids(run: Path) -> list[dict[str, Any]]:
    grids = []
    for path in sorted(run.glob("*.mcap"))[:3]:
        with path.open("rb") as stream:
            for _, _, message in make_reader(stream).iter_messages(
                topics=[TRUE_REWARD_TOPIC, MAP_REWARD_TOPIC]
            ):
                grids.append(json.loads(message.data))
    return grids


NUMERIC_TYPES = {
    member.value: member
    for member in (getattr(PackedElementFieldNumericType, name) for name in ("Float32", "Float64"))
}


def as_sdk_grid(grid: dict[str, Any]) -> Grid:
    """The SDK's ``Grid`` holding a logged grid's values (its constructor checks the types)."""
    pose = grid["pose"]
    return Grid(
        timestamp=Timestamp(sec=grid["timestamp"]["sec"], nsec=grid["timestamp"]["nsec"]),
        frame_id=grid["frame_id"],
        pose=Pose(
            position=Vector3(**pose["position"]), orientation=Quaternion(**pose["orientation"])
        ),
        column_count=grid["column_count"],
        cell_size=Vector2(**grid["cell_size"]),
        row_stride=grid["row_stride"],
        cell_stride=grid["cell_stride"],
        fields=[
            PackedElementField(
                name=field["name"],
                offset=field["offset"],
                type=NUMERIC_TYPES[field["type"]],
            )
            for field in grid["fields"]
        ],
        data=base64.b64decode(grid["data"]),
    )


def test_every_logged_grid_is_an_sdk_grid(smoke_run: Path) -> None:
    grids = logged_grids(smoke_run)
    assert grids
    for grid in grids:
        encoded = as_sdk_grid(grid).encode()
        assert encoded  # the SDK serialises it
        rows = len(base64.b64decode(grid["data"])) // grid["row_stride"]
        assert rows * grid["row_stride"] == len(base64.b64decode(grid["data"]))
        assert grid["row_stride"] == grid["column_count"] * grid["cell_stride"]


@pytest.mark.parametrize("broken", [{"column_count": -1}, {"row_stride": "4"}])
def test_the_sdk_refuses_what_the_schema_refuses(smoke_run: Path, broken: dict) -> None:
    grid = {**logged_grids(smoke_run)[0], **broken}
    with pytest.raises((TypeError, ValueError, OverflowError)):
        as_sdk_grid(grid)
