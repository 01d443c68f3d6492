"""Record checks (DESIGN.md section 7) and the JSON-schema subset they rest on."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_logs_helpers import make_record

from cirl_study.logs import record_faults
from cirl_study.logs.json_schema import compile_validator, schema_errors, unsupported_keywords
from cirl_study.logs.schemas import (
    DEMONSTRATION_SCHEMA,
    DEPLOYMENT_SCHEMA,
    GRID_SCHEMA,
    TRIAL_SCHEMA,
)

REQUIRED = [
    "trial_id", "run_id", "block", "subject", "policy", "num_features", "rationality", "eta",
    "seed", "grid", "start", "learning_steps", "deployment_steps", "features", "theta",
    "theta_hat", "demonstration", "measures",
]  # fmt: skip


def test_schema_requires_exactly_the_design_fields() -> None:
    assert TRIAL_SCHEMA["required"] == REQUIRED


@pytest.mark.parametrize(
    "schema", [TRIAL_SCHEMA, DEMONSTRATION_SCHEMA, DEPLOYMENT_SCHEMA, GRID_SCHEMA]
)
def test_schemas_use_only_keywords_the_validator_checks(schema: dict[str, Any]) -> None:
    assert unsupported_keywords(schema) == set()


def test_unsupported_keywords_are_found() -> None:
    schema = {"type": "object", "properties": {"a": {"pattern": "x", "items": {"oneOf": []}}}}
    assert unsupported_keywords(schema) == {"pattern", "oneOf"}


@pytest.mark.parametrize(
    ("value", "schema", "valid"),
    [
        (True, {"type": "number"}, False),
        (True, {"type": "integer"}, False),
        (2.0, {"type": "integer"}, True),
        (2.5, {"type": "integer"}, False),
        (None, {"type": ["number", "null"], "exclusiveMinimum": 0}, True),
        (0, {"type": ["number", "null"], "exclusiveMinimum": 0}, False),
        (-1, {"type": "number", "minimum": -1, "maximum": 1}, True),
        (1.0000001, {"type": "number", "minimum": -1, "maximum": 1}, False),
        ([1, 2, 3], {"type": "array", "maxItems": 2}, False),
        ([], {"type": "array", "minItems": 1}, False),
        ("", {"type": "string", "minLength": 1}, False),
        ("N", {"enum": ["N", "S"]}, True),
        ("W", {"enum": ["N", "S"]}, False),
        (1, {"enum": [True]}, False),
        ({"a": 1}, {"type": "object", "required": ["a", "b"]}, False),
        ({"a": "x"}, {"type": "object", "properties": {"a": {"type": "integer"}}}, False),
        (
            [[0, 1], [0, "1"]],
            {"type": "array", "items": {"type": "array", "items": {"type": "integer"}}},
            False,
        ),
    ],
)
def test_schema_subset(value: Any, schema: dict[str, Any], valid: bool) -> None:
    assert (schema_errors(value, schema) == []) is valid
    assert compile_validator(schema)(value) is valid


JSON = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-2, 12)
    | st.floats(-2, 2, allow_nan=False)
    | st.sampled_from(["", "N", "expert", "rbf", "main"]),
    lambda inner: (
        st.lists(inner, max_size=3) | st.dictionaries(st.sampled_from(REQUIRED), inner, max_size=2)
    ),
    max_leaves=6,
)


def _locations(value: Any, path: tuple = ()) -> list[tuple]:
    """Every key/index path inside a JSON value."""
    found = [path]
    if isinstance(value, dict):
        for key, item in value.items():
            found += _locations(item, (*path, key))
    elif isinstance(value, list):
        for index, item in enumerate(value):
            found += _locations(item, (*path, index))
    return found


@settings(max_examples=300, deadline=None)
@given(
    data=st.data(), replacement=JSON, operation=st.sampled_from(["set", "grow", "shrink", "drop"])
)
def test_fast_validator_agrees_with_the_explained_one(
    data: st.DataObject, replacement: Any, operation: str
) -> None:
    record = make_record(1, "best_response")
    location = data.draw(st.sampled_from(_locations(record)[1:]))
    *parents, last = location
    target = record
    for key in parents:
        target = target[key]
    value = target[last]
    if operation == "grow" and isinstance(value, list):
        value.append(value[-1] if value else replacement)
    elif operation == "shrink" and isinstance(value, list) and value:
        value.pop()
    elif operation == "drop" and isinstance(target, dict):
        del target[last]
    else:
        target[last] = replacement
    for schema in (TRIAL_SCHEMA, DEMONSTRATION_SCHEMA, GRID_SCHEMA):
        assert compile_validator(schema)(record) is (schema_errors(record, schema) == [])


def test_errors_name_the_path() -> None:
    record = make_record(1)
    record["demonstration"]["states"][2] = [1, "2"]
    assert record_faults(record) == [
        "record.demonstration.states[2][1]: expected integer, got string"
    ]


@pytest.mark.parametrize("field", REQUIRED)
def test_every_missing_field_is_a_fault(field: str) -> None:
    record = make_record(1)
    del record[field]
    assert record_faults(record) == [f"record: missing field {field!r}"]


def _set(path: str, value: Any) -> Callable[[dict[str, Any]], None]:
    def change(record: dict[str, Any]) -> None:
        *parents, last = path.split(".")
        target = record
        for key in parents:
            target = target[int(key)] if isinstance(target, list) else target[key]
        if isinstance(target, list):
            target[int(last)] = value
        else:
            target[last] = value

    return change


def _append_theta(record: dict[str, Any]) -> None:
    record["theta"].append(0.5)


def _shorten_demo(record: dict[str, Any]) -> None:
    record["demonstration"]["states"].pop()
    record["demonstration"]["actions"].pop()


def _wrong_action(record: dict[str, Any]) -> None:
    actions = record["demonstration"]["actions"]
    actions[1] = next(a for a in ("stay", "N") if a != actions[1])


def _reverse_deploy(record: dict[str, Any]) -> None:
    record["deployment"]["paths"][0].reverse()


INCONSISTENT = {
    "eta for the expert": (_set("eta", 0.5), "eta is 0.5 for policy expert"),
    "no eta for best response": (
        lambda r: r.update(policy="best_response"),
        "eta is None for policy best_response",
    ),
    "theta too long": (_append_theta, "theta has 4 entries, num_features is 3"),
    "num_features off": (_set("num_features", 4), "theta has 3 entries, num_features is 4"),
    "start outside": (_set("start", [5, 1]), "start [5, 1] is outside the 5x4 grid"),
    "demonstration too short": (_shorten_demo, "demonstration.states has 4 cells"),
    "demonstration elsewhere": (_set("demonstration.states.0", [0, 0]), "starts at [0, 0]"),
    "wrong action": (_wrong_action, "demonstration.actions[1] is"),
    "learning_steps off": (_set("learning_steps", 5), "has 5 cells, expected 5 steps + 1"),
    "deployment reversed": (_reverse_deploy, "deployment.paths[0] starts at"),
    "negative regret": (_set("measures.regret", -0.1), "measures.regret is -0.1 < 0"),
    "negative kl": (_set("measures.kl", -1e-6), "measures.kl is -1e-06 < 0"),
    "reward_l2 off": (_set("measures.reward_l2", 1.0), "measures.reward_l2 is 1.0 but"),
}


@pytest.mark.parametrize("case", sorted(INCONSISTENT))
def test_inconsistent_records_are_faults(case: str) -> None:
    change, expected = INCONSISTENT[case]
    record = make_record(2)
    change(record)
    faults = record_faults(record)
    assert any(expected in fault for fault in faults), faults


def test_a_path_that_jumps_is_a_fault() -> None:
    record = make_record(1, learning_steps=3)
    states = record["demonstration"]["states"]
    states[2] = [states[1][0] + 2, states[1][1]] if states[1][0] < 2 else [0, states[1][1]]
    assert any("jumps from" in fault for fault in record_faults(record))


def test_rounding_below_zero_is_tolerated() -> None:
    record = make_record(1)
    record["measures"]["kl"] = -1e-12
    assert record_faults(record) == []


def test_records_of_both_policies_pass() -> None:
    for policy in ("expert", "best_response"):
        for k in (1, 3, 10):
            assert record_faults(make_record(4, policy, num_features=k)) == []


def test_the_documented_example_record_is_valid() -> None:
    text = (Path(__file__).parents[1] / "docs" / "log-format.md").read_text()
    example = json.loads(text.split("```json\n", 1)[1].split("```", 1)[0])
    assert list(example)[: len(REQUIRED)] == REQUIRED
    assert record_faults(example) == []
