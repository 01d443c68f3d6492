"""Writing log files: round trip through mcap's own reader, determinism, atomic rename."""

from __future__ import annotations

import base64
import json
import random
from pathlib import Path

import msgspec
import numpy as np
import pytest
from mcap.reader import make_reader
from test_logs_helpers import brute_force_reward, make_record, make_study, provenance_for

from cirl_study.logs.format import (
    DEMONSTRATION_TOPIC,
    DEPLOYMENT_TOPIC,
    MAP_REWARD_TOPIC,
    STEP_NS,
    TRIAL_TOPIC,
    TRUE_REWARD_TOPIC,
)
from cirl_study.logs.provenance import RunIdentity, collect_provenance
from cirl_study.logs.writer import TrialLogWriter
from cirl_study.record import TrialRecord, decode, encode
from cirl_study.study.pipeline_file import logged_pipeline

PROVENANCE = provenance_for()


def write(path: Path, records: list[TrialRecord], **kwargs) -> Path:
    with TrialLogWriter(path, PROVENANCE, **kwargs) as log:
        for record in records:
            log.write(record)
    return path


def messages(path: Path) -> dict[str, list]:
    """``topic -> [(schema, channel, message)]`` read by mcap's reader, CRCs checked."""
    by_topic: dict[str, list] = {}
    with path.open("rb") as stream:
        for schema, channel, message in make_reader(stream, validate_crcs=True).iter_messages():
            by_topic.setdefault(channel.topic, []).append((schema, channel, message))
    return by_topic


def test_round_trip_through_mcap_reader(tmp_path: Path) -> None:
    records = make_study(subjects=2)
    path = write(tmp_path / "a.mcap", records, chunk_size=4096)
    topics = messages(path)
    trials = topics[TRIAL_TOPIC]
    assert [decode(m.data) for _, _, m in trials] == records
    schema, channel, _ = trials[0]
    assert (schema.name, schema.encoding, channel.message_encoding) == (
        "cirl_study.Trial",
        "jsonschema",
        "json",
    )
    trial_schema = json.loads(schema.data)["$defs"]["TrialRecord"]
    assert trial_schema["required"][:3] == ["trial_id", "run_id", "block"]
    with path.open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        metadata = list(reader.iter_metadata())
    assert summary.statistics.chunk_count > 1
    assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
    assert [(m.name, m.metadata) for m in metadata] == [
        ("provenance", PROVENANCE),
        ("trial_index", {"trial_ids": "\n".join(r.trial_id for r in records)}),
    ]
    steps = sum(r.learning_steps + 1 for r in records)
    assert len(topics[DEMONSTRATION_TOPIC]) == steps
    assert len(topics[DEPLOYMENT_TOPIC]) == sum(r.deployment_steps + 1 for r in records)
    assert len(topics[TRUE_REWARD_TOPIC]) == len(topics[MAP_REWARD_TOPIC]) == len(records)


def test_payloads_are_canonical_json_whatever_the_key_order(tmp_path: Path) -> None:
    record = make_record(7, "best_response")
    plain = json.loads(encode(record))
    shuffled = dict(random.Random(1).sample(sorted(plain.items()), len(plain)))
    assert list(shuffled) != list(plain)
    rebuilt = msgspec.json.decode(json.dumps(shuffled), type=TrialRecord)
    first = write(tmp_path / "a.mcap", [make_record(1), record])
    second = write(tmp_path / "b.mcap", [rebuilt])
    payload_a = messages(first)[TRIAL_TOPIC][1][2].data
    payload_b = messages(second)[TRIAL_TOPIC][0][2].data
    expected = json.dumps(plain, sort_keys=True, separators=(",", ":"), allow_nan=False)
    assert payload_a == payload_b == encode(shuffled)
    assert json.loads(payload_a) == json.loads(expected)


def test_same_records_give_identical_files(tmp_path: Path) -> None:
    records = make_study(subjects=2)
    first = write(tmp_path / "a.mcap", records).read_bytes()
    second = write(tmp_path / "b.mcap", records).read_bytes()
    assert first == second


def test_nan_is_refused(tmp_path: Path) -> None:
    record = make_record(1)
    broken = msgspec.structs.replace(record, theta_hat=(float("nan"), *record.theta_hat[1:]))
    path = tmp_path / "a.mcap"
    with TrialLogWriter(path, PROVENANCE) as log:
        with pytest.raises(ValueError, match="cannot be logged"):
            log.write(broken)
        log.write(record)
    assert [decode(m.data) for _, _, m in messages(path)[TRIAL_TOPIC]] == [record]


def test_time_layout_depends_only_on_position(tmp_path: Path) -> None:
    short = make_record(1, learning_steps=2, deployment_steps=1)
    long = make_record(2, learning_steps=5, deployment_steps=4)
    topics = messages(write(tmp_path / "a.mcap", [short, long, short]))
    assert [m.log_time for _, _, m in topics[TRIAL_TOPIC]] == [0, 5 * STEP_NS, 16 * STEP_NS]
    demo = [(m.log_time, json.loads(m.data)) for _, _, m in topics[DEMONSTRATION_TOPIC]]
    assert [t for t, step in demo if step["trial_id"] == long.trial_id] == [
        (5 + t) * STEP_NS for t in range(6)
    ]
    deploy = [m.log_time for _, _, m in topics[DEPLOYMENT_TOPIC]][:2]
    assert deploy == [3 * STEP_NS, 4 * STEP_NS]
    assert all(m.log_time == m.publish_time for ms in topics.values() for _, _, m in ms)


def test_replay_steps_follow_the_record(tmp_path: Path) -> None:
    record = make_record(3, "best_response", rollouts=3)
    topics = messages(write(tmp_path / "a.mcap", [record]))
    demo = [json.loads(m.data) for _, _, m in topics[DEMONSTRATION_TOPIC]]
    assert [tuple(step["cell"]) for step in demo] == list(record.demonstration.states)
    assert [step["action"] for step in demo] == [None, *record.demonstration.actions]
    assert {step["human"] for step in demo} == {"best_response"}
    deploy = [json.loads(m.data) for _, _, m in topics[DEPLOYMENT_TOPIC]]
    paths = record.deployment.paths
    assert [step["cells"] for step in deploy] == [
        [list(cell) for cell in cells] for cells in zip(*paths, strict=True)
    ]
    moves = {(0, 0): "stay", (0, 1): "N", (0, -1): "S", (1, 0): "E", (-1, 0): "W"}
    for t, step in enumerate(deploy[1:], start=1):
        expected = [moves[(p[t][0] - p[t - 1][0], p[t][1] - p[t - 1][1])] for p in paths]
        assert step["actions"] == expected
    assert deploy[0]["actions"] == [None, None, None]


@pytest.mark.parametrize(
    ("topic", "weights"), [(TRUE_REWARD_TOPIC, "theta"), (MAP_REWARD_TOPIC, "theta_hat")]
)
def test_reward_maps_are_foxglove_grids_of_theta_dot_phi(
    tmp_path: Path, topic: str, weights: str
) -> None:
    record = make_record(5, width=6, height=3)
    ((schema, _, message),) = messages(write(tmp_path / "a.mcap", [record]))[topic]
    assert (schema.name, schema.encoding) == ("foxglove.Grid", "jsonschema")
    grid = json.loads(message.data)
    assert grid["column_count"] == 6
    assert (grid["cell_stride"], grid["row_stride"]) == (4, 24)
    assert grid["fields"] == [{"name": "reward", "offset": 0, "type": 7}]
    values = np.frombuffer(base64.b64decode(grid["data"]), dtype="<f4")
    expected = [
        brute_force_reward(json.loads(encode(record.features)), getattr(record, weights), x, y)
        for y in range(3)
        for x in range(6)
    ]
    np.testing.assert_allclose(values, expected, rtol=1e-6, atol=1e-6)


def test_file_appears_only_when_complete(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    temp = tmp_path / "a.mcap.tmp"
    with TrialLogWriter(path, PROVENANCE) as log:
        log.write(make_record(1))
        assert temp.exists()
        assert not path.exists()
    assert path.exists()
    assert not temp.exists()


def test_an_exception_leaves_only_the_temporary_file(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    with pytest.raises(RuntimeError, match="killed"), TrialLogWriter(path, PROVENANCE) as log:
        log.write(make_record(1))
        raise RuntimeError("killed")
    assert not path.exists()
    assert (tmp_path / "a.mcap.tmp").exists()


def test_an_existing_file_is_never_overwritten(tmp_path: Path) -> None:
    path = write(tmp_path / "a.mcap", [make_record(1)])
    before = path.read_bytes()
    with pytest.raises(FileExistsError), TrialLogWriter(path, PROVENANCE):
        pass
    assert path.read_bytes() == before


@pytest.mark.parametrize(
    ("provenance", "error"),
    [({"pipeline_sha256": "x"}, ValueError), ({"pipeline_name": "p", "seed": 1}, TypeError)],
)
def test_provenance_is_checked(tmp_path: Path, provenance: dict, error: type) -> None:
    with pytest.raises(error):
        TrialLogWriter(tmp_path / "a.mcap", provenance)


def test_collect_provenance() -> None:
    identity = RunIdentity("smoke-69b1f260376d", "smoke", "smoke.toml", 'name = "smoke"\n')
    provenance = collect_provenance(identity)
    assert all(isinstance(k, str) and isinstance(v, str) for k, v in provenance.items())
    assert provenance["pipeline_name"] == "smoke" and provenance["run_id"] == identity.run_id
    assert provenance["pipeline_toml"] == 'name = "smoke"\n'
    assert provenance["log_format"] == "10"
    # sha256 of the 15 bytes above, computed independently with `sha256sum`
    assert provenance["pipeline_sha256"] == (
        "69b1f260376d9e58171da83a305b3b2da7f22ab722ca729c9af53174ce8cd422"
    )
    # A provenance states an identity whose text the study judges: it must be a valid pipeline.
    with pytest.raises(ValueError, match="provenance's pipeline_toml: description is missing"):
        logged_pipeline(RunIdentity.of(provenance))
    valid = provenance_for("smoke")
    assert RunIdentity.of(valid).provenance() == valid
    assert logged_pipeline(RunIdentity.of(valid)).run_id == valid["run_id"]
    with pytest.raises(ValueError, match="not the hash of its pipeline_toml"):
        RunIdentity.of({**provenance, "pipeline_toml": 'name = "smoke2"\n'})
    with pytest.raises(ValueError, match="provenance lacks run_id"):
        RunIdentity.of({k: v for k, v in provenance.items() if k != "run_id"})
    for key in (
        "cirl_study_version",
        "git_commit",
        "python_version",
        "numpy_version",
        "mcap_version",
    ):
        assert provenance[key]
