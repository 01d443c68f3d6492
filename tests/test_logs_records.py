"""Trial payloads: decoded into the typed record (docs/design.md §7), then checked."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgspec
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_logs_helpers import brute_force_reward, make_record

from cirl_study.logs import record_checks
from cirl_study.logs.record_checks import decode_trial, decode_trials
from cirl_study.logs.schemas import CHANNELS
from cirl_study.record import TRIAL_SCHEMA, TrialRecord, encode

REQUIRED = [
    "trial_id", "run_id", "block", "subject", "human", "num_features", "rationality", "eta",
    "seed", "grid", "start", "learning_steps", "deployment_steps", "features", "theta",
    "theta_hat", "demonstration", "measures",
]  # fmt: skip


def faults_of(record: dict[str, Any]) -> list[str]:
    """The faults :func:`decode_trial` finds in the JSON of ``record``."""
    return decode_trial(json.dumps(record).encode())[1]


def plain_record(*args: Any, **kwargs: Any) -> dict[str, Any]:
    """A fabricated record as the plain JSON object the log holds."""
    return json.loads(encode(make_record(*args, **kwargs)))


def test_schema_requires_exactly_the_design_fields() -> None:
    definition = TRIAL_SCHEMA["$defs"]["TrialRecord"]
    assert sorted(definition["required"]) == sorted(REQUIRED)
    assert {"robot", "irl", "deployment"} <= set(definition["properties"]) - set(REQUIRED)


def test_every_channel_declares_a_json_schema() -> None:
    for topic, name, schema in CHANNELS:
        assert topic.startswith("/cirl/") and name
        assert json.loads(encode(schema)) == schema


def test_a_sound_record_round_trips_byte_for_byte() -> None:
    record = make_record(1, "best_response")
    data = encode(record)
    assert decode_trial(data) == (record, [])
    assert encode(msgspec.json.decode(data, type=TrialRecord)) == data


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
def test_any_damage_is_a_fault_or_a_record_that_round_trips(
    data: st.DataObject, replacement: Any, operation: str
) -> None:
    """Whatever a payload holds, decoding never raises: it names a fault, or gives a record
    whose canonical JSON decodes to the same record."""
    record = plain_record(1, "best_response")
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
    decoded, faults = decode_trial(json.dumps(record).encode())
    if decoded is None:
        assert len(faults) == 1 and faults[0].startswith("not a trial record: ")
    else:
        assert decode_trial(encode(decoded))[0] == decoded


def test_errors_name_the_path() -> None:
    record = plain_record(1)
    record["demonstration"]["states"][2] = [1, "2"]
    assert faults_of(record) == [
        "not a trial record: Expected `int`, got `str` - at `$.demonstration.states[2][1]`"
    ]


@pytest.mark.parametrize("field", REQUIRED)
def test_every_missing_field_is_a_fault(field: str) -> None:
    record = plain_record(1)
    del record[field]
    assert faults_of(record) == [f"not a trial record: Object missing required field `{field}`"]


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        ("human", "", "Expected `str` of length >= 1"),
        ("block", "warmup", "Invalid enum value 'warmup'"),
        ("rationality", 0.0, "Expected `float` > 0.0"),
        ("gradient_ascent", {"steps": 0, "learning_rate": 0.1}, "Expected `int` >= 1"),
        (
            "measures",
            {
                "regret": 1.0,
                "kl": 1.0,
                "reward_l2": -1.0,
                "regret_under_estimate": 1.0,
                "order_agreement": 0.5,
            },
            "measures.reward_l2 is -1.0 < 0",
        ),
        ("demonstration", {"states": [[2, 2]], "actions": ["up"]}, "Invalid enum value 'up'"),
        ("num_features", True, "Expected `int`, got `bool`"),
    ],
)
def test_values_out_of_range_are_faults(path: str, value: Any, message: str) -> None:
    record = plain_record(1)
    record[path] = value
    (fault,) = faults_of(record)
    assert message in fault, fault


def test_a_theta_hat_past_the_largest_double_has_no_record() -> None:
    record = plain_record(1)
    record["theta_hat"][0] = 12345.0
    text = json.dumps(record).replace("12345.0", "1e400", 1).encode()
    (fault,) = decode_trial(text)[1]
    assert fault == "not a trial record: Number out of range - at `$.theta_hat[0]`"


def test_not_a_number_has_no_record() -> None:
    text = encode(make_record(1)).replace(b'"kl":', b'"kl":NaN,"x":', 1)
    (fault,) = decode_trial(text)[1]
    assert fault.startswith("not a trial record: ")


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


def _stay_while_stays_are_off(record: dict[str, Any]) -> None:
    demonstration = record["demonstration"]
    demonstration["states"][1] = demonstration["states"][0]
    demonstration["states"][2:] = [demonstration["states"][0]] * (len(demonstration["states"]) - 2)
    demonstration["actions"] = ["stay"] * len(demonstration["actions"])
    record["demonstrator_stays"] = False


def _deploy_from_the_start_elsewhere(record: dict[str, Any]) -> None:
    record["deployment_start"] = "demonstration"


ASCENT = {"steps": 30, "learning_rate": 0.1}
"""The settings of a ``gradient_ascent`` record."""


def _estimated(record: dict[str, Any], theta_hat: list[float]) -> None:
    """``record`` with the estimate ``theta_hat`` and its ``reward_l2``."""
    difference = [a - b for a, b in zip(record["theta"], theta_hat, strict=True)]
    width, height = record["grid"]["width"], record["grid"]["height"]
    record["theta_hat"] = theta_hat
    record["measures"]["reward_l2"] = math.sqrt(
        math.fsum(
            brute_force_reward(record["features"], difference, x, y) ** 2
            for x in range(width)
            for y in range(height)
        )
    )


INCONSISTENT = {
    "unknown human": (_set("human", "oracle"), "human 'oracle' is not a known human"),
    "unknown robot": (_set("robot", "oracle"), "robot 'oracle' is not a known robot"),
    "eta for the expert": (_set("eta", 0.5), "eta is 0.5 for human expert"),
    "no eta for best response": (
        lambda r: r.update(human="best_response"),
        "eta is None for human best_response",
    ),
    "theta too long": (_append_theta, "theta has 4 entries, num_features is 3"),
    "theta_hat too short": (
        lambda r: r["theta_hat"].pop(),
        "theta_hat has 2 entries, num_features is 3",
    ),
    "num_features off": (_set("num_features", 4), "theta has 3 entries, num_features is 4"),
    "start outside": (_set("start", [5, 1]), "start [5, 1] is outside the 5x4 grid"),
    "demonstration too short": (_shorten_demo, "demonstration.states has 4 cells"),
    "demonstration elsewhere": (_set("demonstration.states.0", [0, 0]), "starts at [0, 0]"),
    "wrong action": (_wrong_action, "demonstration.actions[1] is"),
    "learning_steps off": (_set("learning_steps", 5), "has 5 cells, expected 5 steps + 1"),
    "deployment reversed": (_reverse_deploy, "deployment.paths[0] starts at"),
    "negative regret": (_set("measures.regret", -0.1), "measures.regret is -0.1 < 0"),
    "negative kl": (_set("measures.kl", -1e-6), "measures.kl is -1e-06 < 0"),
    "negative regret_under_estimate": (
        _set("measures.regret_under_estimate", -0.5),
        "measures.regret_under_estimate is -0.5 < 0",
    ),
    "reward_l2 off": (_set("measures.reward_l2", 1.0), "measures.reward_l2 is 1.0 but"),
    "a measure missing": (lambda r: r["measures"].pop("kl"), "measures has no kl"),
    "a measure not registered": (
        _set("measures.happiness", 1.0),
        "measures.happiness is not a registered measure",
    ),
    "a null regret": (
        _set("measures.regret", None),
        "measures.regret is null, but every record has a value of it",
    ),
    "a stay the game forbids": (_stay_while_stays_are_off, "demonstrator_stays is false"),
    "rollouts away from the start": (
        _deploy_from_the_start_elsewhere,
        "a deployment rollout starts away from the demonstration's start",
    ),
    "theta_hat outside the box": (
        lambda r: _estimated(r, [1.5, 0.0, -0.25]),
        "theta_hat[0] is 1.5, outside [-1, 1] (only a robot whose estimate may leave the box",
    ),
    "gradient_ascent settings for another robot": (
        _set("gradient_ascent", ASCENT),
        "gradient_ascent is given for robot map (given exactly for robot gradient_ascent)",
    ),
    "gradient_ascent without its settings": (
        _set("robot", "gradient_ascent"),
        "gradient_ascent is null for robot gradient_ascent",
    ),
}


@pytest.mark.parametrize("case", sorted(INCONSISTENT))
def test_inconsistent_records_are_faults(case: str) -> None:
    change, expected = INCONSISTENT[case]
    record = plain_record(2)
    change(record)
    faults = faults_of(record)
    assert any(expected in fault for fault in faults), faults


def test_a_path_that_jumps_is_a_fault() -> None:
    record = plain_record(1, learning_steps=3)
    states = record["demonstration"]["states"]
    states[2] = [states[1][0] + 2, states[1][1]] if states[1][0] < 2 else [0, states[1][1]]
    assert any("jumps from" in fault for fault in faults_of(record))


def test_a_gradient_ascent_estimate_may_leave_the_box() -> None:
    record = plain_record(2)
    record.update(robot="gradient_ascent", gradient_ascent=ASCENT)
    _estimated(record, [3.5, -12.0, 0.25])
    assert faults_of(record) == []
    record["robot"] = "map"
    del record["gradient_ascent"]
    assert [fault.split(",")[0] for fault in faults_of(record)] == ["theta_hat[0] is 3.5"]


def test_rounding_below_zero_is_tolerated() -> None:
    record = plain_record(1)
    record["measures"]["kl"] = -1e-12
    assert faults_of(record) == []


def test_records_of_both_humans_pass() -> None:
    for human in ("expert", "best_response"):
        for k in (1, 3, 10):
            assert faults_of(plain_record(4, human, num_features=k)) == []


def test_the_documented_example_record_is_valid() -> None:
    text = (Path(__file__).parents[1] / "docs" / "log-format.md").read_text()
    example = json.loads(text.split("```json\n", 1)[1].split("```", 1)[0])
    assert list(example)[: len(REQUIRED)] == REQUIRED
    assert faults_of(example) == []


def _cell(width: int, height: int) -> st.SearchStrategy[list[int]]:
    """A cell on a ``width x height`` grid or just off it."""
    return st.lists(st.integers(-1, max(width, height)), min_size=2, max_size=2)


@settings(max_examples=400, deadline=None)
@given(data=st.data(), human=st.sampled_from(["expert", "best_response"]))
def test_the_move_table_walk_agrees_with_the_named_path_faults(
    data: st.DataObject, human: str
) -> None:
    """The record checks walk each path through the grid's move table and name its faults
    cell by cell only when that walk fails: the walk fails exactly when the named checks find
    a fault, whatever cells, moves, steps or players the record holds."""
    record = plain_record(data.draw(st.integers(0, 50)), human, rollouts=2)
    width, height = record["grid"]["width"], record["grid"]["height"]
    demonstration, deployment = record["demonstration"], record["deployment"]
    for _ in range(data.draw(st.integers(0, 3))):
        change = data.draw(
            st.sampled_from(["cell", "action", "start", "steps", "player", "stays", "rollout"])
        )
        if change == "cell":
            path = data.draw(st.sampled_from([demonstration["states"], *deployment["paths"]]))
            path[data.draw(st.integers(0, len(path) - 1))] = data.draw(_cell(width, height))
        elif change == "action":
            actions = demonstration["actions"]
            actions[data.draw(st.integers(0, len(actions) - 1))] = data.draw(
                st.sampled_from(["stay", "N", "S", "E", "W"])
            )
        elif change == "start":
            record["start"] = data.draw(_cell(width, height))
        elif change == "steps":
            key = data.draw(st.sampled_from(["learning_steps", "deployment_steps"]))
            record[key] = data.draw(st.integers(1, 6))
        elif change == "player":
            record["human"] = data.draw(st.sampled_from(["expert", "best_response", "oracle"]))
            record["robot"] = data.draw(st.sampled_from(["map", "posterior_mean", "pragmatic"]))
            record["eta"] = data.draw(st.sampled_from([None, 0.5]))
        elif change == "stays":
            record["demonstrator_stays"] = data.draw(st.booleans())
            record["deployment_start"] = data.draw(st.sampled_from(["uniform", "demonstration"]))
        else:
            deployment["starts"][0] = data.draw(_cell(width, height))
    try:
        decoded = msgspec.json.decode(json.dumps(record).encode(), type=TrialRecord)
    except msgspec.ValidationError:
        return  # a coordinate below zero: a type fault, found before any consistency check
    moves, grid = record_checks._moves(decoded.grid), record_checks._gridworld(decoded.grid)
    paths = [
        (
            "demonstration.states",
            decoded.demonstration.states,
            decoded.start,
            decoded.learning_steps,
        )
    ]
    paths += [
        (f"deployment.paths[{i}]", path, start, decoded.deployment_steps)
        for i, (start, path) in enumerate(
            zip(decoded.deployment.starts, decoded.deployment.paths, strict=False)
        )
    ]
    for name, path, start, steps in paths:
        named = list(record_checks._path_faults(name, path, start, steps, grid, ()))
        assert (record_checks._walk(path, start, steps, moves, ()) is None) == bool(named), name


def test_reward_l2_is_checked_record_by_record_in_a_batch() -> None:
    """Records of several grids and feature counts are checked together, and each fault
    stays with its own record."""
    records = [
        plain_record(subject, human, num_features=k, width=width)
        for subject, (human, k, width) in enumerate(
            [("expert", 3, 5), ("best_response", 10, 5), ("expert", 3, 6), ("expert", 1, 5)]
        )
    ]
    records[1]["measures"]["reward_l2"] += 1e-6
    records[2]["theta"].append(0.5)
    batch = decode_trials(json.dumps(record).encode() for record in records)
    assert [faults for _, faults in batch] == [faults_of(record) for record in records]
    assert [len(faults) for _, faults in batch] == [0, 1, 1, 0]
    assert batch[1][1][0].startswith("measures.reward_l2 is")
