"""The log formats this version reads, and how a log of an earlier one is read as the current.

A log file states its format in its provenance (``log_format``). This version reads each format
of :data:`READABLE` by renaming what a file holds to the current names before anything is
checked or decoded: the pipeline's table (the TOML as parsed), each trial record's JSON and
the trial ids of the file's index. The hashes and the run id stay those of the text as it was
logged, so a run keeps its identity.

Format 6 gave each concept one name where format 5 had two; a log of format 5 is renamed so:

===================================== ========================== ==========================
what                                  format 5                   format 6
===================================== ========================== ==========================
the robot of the literal likelihood   ``literal``                ``literal_observer``
pipeline key, multiverse axis         ``centres``                ``centers``
universe id (and a trial id's end)    ``...,centres=shared,...`` ``...,centers=shared,...``
===================================== ========================== ==========================

``literal`` stays the name of the Boltzmann-rational human.

Format 7 added fields, renaming none: the robot ``gradient_ascent``, whose record carries its
settings (``gradient_ascent``: ``steps``, ``learning_rate``) and whose ``theta_hat`` may leave
the box, so the schema no longer bounds ``theta_hat`` (the record checks do, for every other
robot); and the second reading of regret, ``measures.regret_under_estimate``. A record of
format 5 or 6 has neither: ``gradient_ascent`` reads as ``null``.

Format 8 logs every measure of the registry (:data:`cirl_study.measure_registry.MEASURES`):
``measures`` is a mapping of their names, checked against the registry, where format 7 declared
a type of four numbers. A record of an earlier format reads every registered measure it lacks
as ``null`` (missing, not recomputed: see :func:`record_payload`), ``regret_under_estimate``
before format 7 among them: the trial table shows it as NaN and the analysis leaves it out.

Format 8 added games of other feature kinds (a record's ``features`` is tagged by its
``kind``, ``rbf`` as before or ``tiles``), goal cells that end an episode (``goals``) and
named tasks (``task``), and hypothesis spaces the pipeline lists (``teaching.listed``); a
record of an earlier format reads ``goals`` as ``[]`` (a fixed horizon), ``task`` as ``null``
and ``teaching.listed`` as ``[]`` (drawn hypotheses).

Format 9 calls the player who demonstrates the *human* everywhere, where format 8 and earlier
called it ``policy``; a log of format 8 or earlier is renamed so:

===================================== ========================== ==========================
what                                  format 5 to 8              format 9
===================================== ========================== ==========================
a trial record's player who shows     ``policy``                 ``human``
the pipeline's humans                 ``main.policies``          ``main.humans``
===================================== ========================== ==========================

Format 10 added people, renaming none: a trial of the ``recorded`` human carries the
participant's demonstration (``recorded``: ``participant``, ``condition``, ``path`` and, where
the file had them, ``seconds`` and ``order``), and the provenance of a run with participants
its file of demonstrations (``participants_csv``, ``participants_sha256``), with which its
pipeline is read; a record of an earlier format reads ``recorded`` as ``null``.

The episode topics (``/cirl/demonstration``, ``/cirl/deployment``) are replay views that no
reader decodes; their messages keep the name they were logged with.

A run of format 5 is read, validated and analysed; it is resumed only by the version that wrote
it (its pipeline text is of that version).
"""

from __future__ import annotations

from typing import Any

import msgspec

from cirl_study.measure_registry import MEASURES

LOG_FORMAT = "10"
"""The format this version writes: 10 the ``recorded`` human's demonstrations and the run's
file of them (see the module docstring); 9 the player who demonstrates named ``human`` (see the
module docstring); 8 ``measures`` by the measure registry, games of any
feature kind (``features.kind`` ``tiles``) with goal cells (``goals``) and named tasks
(``task``); 7 the ``gradient_ascent`` robot and its settings, and
``measures.regret_under_estimate``; 6 one name per concept (see the module docstring); 5 the
record's ``teaching`` (hypothesis space), and ``seed`` shared by the robots of one
demonstration; 4 the record's ``demonstrator_stays``, ``deployment_start`` and ``universe``;
3 the run's identity and pipeline text in every file; 2 the typed record."""

READABLE = ("5", "6", "7", "8", "9", LOG_FORMAT)
"""The formats this version reads."""

_RENAMING = ("5",)
"""The formats whose names :data:`_ROBOTS` and :data:`_AXES` rename."""

_HUMAN_SINCE = 9
"""The first format naming the player who demonstrates ``human`` (``policy`` before)."""

_ROBOTS = {"literal": "literal_observer"}
_AXES = {"centres": "centers"}

_SORTED = msgspec.json.Encoder(order="sorted")
"""The records' canonical JSON (:func:`cirl_study.record.encode`): keys sorted, no spaces."""


def readable(log_format: str) -> bool:
    """Whether this version reads logs of ``log_format``."""
    return log_format in READABLE


def pipeline_table(data: dict[str, Any], log_format: str) -> dict[str, Any]:
    """The parsed pipeline ``data`` of a log of ``log_format``, in the current names.

    >>> pipeline_table({"game": {"centres": "shared"}, "main": {"robots": ["literal"]}}, "5")
    {'game': {'centers': 'shared'}, 'main': {'robots': ['literal_observer']}}
    >>> pipeline_table({"main": {"policies": ["expert"], "robots": ["map"]}}, "8")
    {'main': {'humans': ['expert'], 'robots': ['map']}}
    """
    if not readable(log_format):  # refused by the reader, which names the format
        return data
    if log_format in _RENAMING:
        data = {key: _pipeline_value(key, value) for key, value in data.items()}
    main = data.get("main")
    if int(log_format) < _HUMAN_SINCE and isinstance(main, dict) and "policies" in main:
        humans = {("humans" if key == "policies" else key): value for key, value in main.items()}
        data = {**data, "main": humans}
    return data


def _pipeline_value(key: str, value: Any) -> Any:
    """``value`` of the pipeline key ``key`` (at any depth), renamed."""
    if key in ("robots", "robot"):
        if isinstance(value, str):
            return _ROBOTS.get(value, value)
        if isinstance(value, list):
            return [_ROBOTS.get(v, v) if isinstance(v, str) else v for v in value]
    if isinstance(value, dict):
        return {_AXES.get(k, k): _pipeline_value(k, v) for k, v in value.items()}
    if isinstance(value, list):
        return [_pipeline_value(key, v) for v in value]
    return value


_ADDED: dict[str, dict[str, Any]] = {
    "7": {"gradient_ascent": None},
    "8": {"goals": [], "task": None},
    "10": {"recorded": None},
}
"""The record's fields each format added, as a record of an earlier format reads them."""


def record_payload(data: bytes, log_format: str) -> bytes:
    """The JSON ``data`` of a trial record of a log of ``log_format``, in the current names,
    with the fields added since (:data:`_ADDED`) and every registered measure it lacks as
    ``null``, and canonical (keys sorted). Bytes that are not a JSON object, or of a format
    this version does not read, are returned as they are, for the decoder or the reader to
    report.

    A measure a record's format did not log is marked missing, not recomputed: recomputing
    ``regret_under_estimate`` would plan the deployment under both rewards for every record
    read, where the record checks recompute only what is linear in the record (``reward_l2``),
    and would load the numerical core into every reader; and a measure of a format's own has
    no value in its records to take.

    >>> msgspec.json.decode(record_payload(b'{"robot":"literal","universe":"centres=x"}', "5"))
    {'goals': [], 'gradient_ascent': None, 'recorded': None, 'robot': 'literal_observer', \
'task': None, 'universe': 'centers=x'}
    >>> msgspec.json.decode(record_payload(b'{"measures":{"kl":1.5,"regret":0.25}}', "6"))[
    ...     "measures"]
    {'kl': 1.5, 'order_agreement': None, 'regret': 0.25, 'regret_under_estimate': None, \
'reward_l2': None}
    >>> record_payload(b'{"robot":"map"}', "7")
    b'{"goals":[],"recorded":null,"robot":"map","task":null}'
    >>> record_payload(b'{"policy":"expert","robot":"map"}', "8")
    b'{"human":"expert","recorded":null,"robot":"map"}'
    """
    if log_format == LOG_FORMAT or not readable(log_format):
        return data  # the current names; or a format the reader refuses, naming it
    try:
        record = msgspec.json.decode(data)
    except (msgspec.DecodeError, RecursionError):
        return data
    if not isinstance(record, dict):
        return data
    added = {
        name: value
        for since, fields in _ADDED.items()
        if int(log_format) < int(since)
        for name, value in fields.items()
    }
    renamed = {**added, **record}
    if int(log_format) < _HUMAN_SINCE and "policy" in renamed:
        renamed["human"] = renamed.pop("policy")
    if int(log_format) < 8 and isinstance(record.get("teaching"), dict):
        renamed["teaching"] = {"listed": [], **record["teaching"]}
    if isinstance(record.get("measures"), dict):
        renamed["measures"] = {**dict.fromkeys(MEASURES), **record["measures"]}
    for key, rename in (("trial_id", trial_id), ("universe", _universe), ("robot", _robot)):
        if isinstance(renamed.get(key), str):
            renamed[key] = rename(renamed[key], log_format)
    return _SORTED.encode(renamed)


def trial_id(logged: str, log_format: str) -> str:
    """The trial id ``logged`` in a log of ``log_format``, in the current names: in format 5,
    ``block:subject:human:lambda=...:robot=...@universe`` with the robot and the universe
    renamed.

    >>> trial_id("main:main-k03-s0001:literal:lambda=1.0:robot=literal@centres=shared", "5")
    'main:main-k03-s0001:literal:lambda=1.0:robot=literal_observer@centers=shared'
    """
    if log_format not in _RENAMING:
        return logged
    trial, at, universe = logged.partition("@")
    parts = [
        "robot=" + _robot(p[len("robot=") :], log_format) if p.startswith("robot=") else p
        for p in trial.split(":")
    ]
    return ":".join(parts) + at + _universe(universe, log_format)


def _robot(name: str, log_format: str) -> str:
    return _ROBOTS.get(name, name) if log_format in _RENAMING else name


def _universe(universe: str, log_format: str) -> str:
    """A universe id ``axis=level,...`` with its axes and robots renamed."""
    if log_format not in _RENAMING or not universe:
        return universe
    choices = [choice.partition("=") for choice in universe.split(",")]
    return ",".join(
        _AXES.get(axis, axis) + eq + (_robot(level, log_format) if axis == "robot" else level)
        for axis, eq, level in choices
    )
