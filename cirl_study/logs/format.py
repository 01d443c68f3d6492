"""Fixed names, encodings and the time layout of the study's MCAP log files.

A run directory holds one or more complete files ``*.mcap``. A file being written lives
under the temporary name ``<final name>.tmp`` in the same directory and is renamed to its
final name only when it is complete, so a reader that lists ``*.mcap`` never sees a partial
file.

Topics (all JSON messages described by JSON schemas, see :mod:`cirl_study.logs.schemas`;
every payload is canonical JSON, :func:`cirl_study.record.encode`, so equal messages give
equal bytes):

* ``/cirl/trial`` (``cirl_study.Trial``): one message per trial, the record of
  docs/design.md §7 (:class:`cirl_study.record.TrialRecord`).
* ``/cirl/demonstration`` (``cirl_study.DemonstrationStep``): the human's path, one message
  per step ``t = 0..T_learn``.
* ``/cirl/deployment`` (``cirl_study.DeploymentStep``): the robot's deployment rollouts from a
  few start cells, one message per step ``t = 0..T_deploy`` holding every rollout's cell.
* ``/cirl/reward/true`` and ``/cirl/reward/map`` (``foxglove.Grid``): the reward maps
  ``r_theta(s) = theta . phi(s)`` and ``r_theta_hat(s)`` over all cells.

Time layout: trial ``k`` of a file occupies the interval starting at ``start_k`` with
``start_0 = 0`` and ``start_{k+1} = start_k + (T_learn + T_deploy + 2) * STEP_NS``. The trial
message and both reward maps are logged at ``start_k``, demonstration step ``t`` at
``start_k + t * STEP_NS`` and deployment step ``t`` at
``start_k + (T_learn + 1 + t) * STEP_NS``. Times therefore depend only on the sequence of
records in the file, never on the wall clock.
"""

from __future__ import annotations

from pathlib import Path

TRIAL_TOPIC = "/cirl/trial"
DEMONSTRATION_TOPIC = "/cirl/demonstration"
DEPLOYMENT_TOPIC = "/cirl/deployment"
TRUE_REWARD_TOPIC = "/cirl/reward/true"
MAP_REWARD_TOPIC = "/cirl/reward/map"

TRIAL_SCHEMA_NAME = "cirl_study.Trial"
DEMONSTRATION_SCHEMA_NAME = "cirl_study.DemonstrationStep"
DEPLOYMENT_SCHEMA_NAME = "cirl_study.DeploymentStep"
GRID_SCHEMA_NAME = "foxglove.Grid"

SCHEMA_ENCODING = "jsonschema"
MESSAGE_ENCODING = "json"

PROVENANCE_METADATA_NAME = "provenance"
TRIAL_INDEX_METADATA_NAME = "trial_index"
"""Metadata record closing every file: ``{"trial_ids": <the file's trial ids, one per line,
in order>}``; readers check it against the file's records, which alone decide what the file
holds."""
TRIAL_INDEX_KEY = "trial_ids"
PIPELINE_NAME_KEY = "pipeline_name"
RUN_ID_KEY = "run_id"
PIPELINE_FILE_KEY = "pipeline_file"
PIPELINE_TEXT_KEY = "pipeline_toml"
PIPELINE_SHA_KEY = "pipeline_sha256"
LOG_FORMAT_KEY = "log_format"
DEMONSTRATIONS_TEXT_KEY = "participants_csv"
DEMONSTRATIONS_SHA_KEY = "participants_sha256"
"""The file of demonstrations of a run with participants, and the SHA-256 of its UTF-8 text:
part of the run's identity where the pipeline has ``[participants]``."""
IDENTITY_KEYS = (
    RUN_ID_KEY,
    PIPELINE_NAME_KEY,
    PIPELINE_FILE_KEY,
    PIPELINE_TEXT_KEY,
    PIPELINE_SHA_KEY,
)
"""Keys of the ``provenance`` record that identify the run
(:class:`cirl_study.logs.provenance.RunIdentity`)."""

#: One game step lasts one second of log time, so Foxglove replays an episode at 1 step/s.
STEP_NS = 1_000_000_000

MAX_DEMONSTRATIONS_BYTES = 32 << 20
"""Largest file of participants' demonstrations read, as a file or as the text a log's
provenance carries (32 MiB: some 800,000 moves; Ho et al.'s whole study of 58 participants is
some 4,000)."""

MAX_PIPELINE_BYTES = 1 << 20
"""Largest pipeline file read, as a file or as the text a log's provenance carries (every log
file of a run carries the whole text)."""

LOG_SUFFIX = ".mcap"
TEMP_SUFFIX = ".tmp"


def temp_path(path: Path) -> Path:
    """The temporary name under which the file ``path`` is written until it is complete."""
    return path.with_name(path.name + TEMP_SUFFIX)


def log_files(run_dir: Path) -> list[Path]:
    """The complete log files of a run directory, sorted by name: every entry named
    ``*.mcap``, whatever it is, so that a reader refuses or reports one that is no regular
    file (a link, a FIFO, a directory) instead of passing over it
    (:func:`cirl_study.logs.bounds.read_log`)."""
    return sorted(run_dir.glob(f"*{LOG_SUFFIX}"))


def temp_files(run_dir: Path) -> list[Path]:
    """Unfinished (temporary) log files left in a run directory by an interrupted run: every
    entry named ``*.mcap.tmp``, whatever it is (see :func:`log_files`)."""
    return sorted(run_dir.glob(f"*{LOG_SUFFIX}{TEMP_SUFFIX}"))


def trial_duration_ns(learning_steps: int, deployment_steps: int) -> int:
    """Length of a trial's interval of log time (see the module docstring)."""
    return (learning_steps + deployment_steps + 2) * STEP_NS
