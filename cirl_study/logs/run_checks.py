"""Faults of a run as a whole (docs/design.md §5), across its log files.

* No trial id is logged twice; all files state one run (run id and pipeline file) and hold
  only its records.
* A subject is one reward draw: all its records agree on ``num_features``, ``theta``, the
  features, the grid and the start cell (so a subject lies at one feature level).
* The ``main`` block is non-empty, complete and within subjects: every subject in it has
  exactly one trial of every (robot, policy) pair the block plays.
* Cross-validation draws are disjoint from the test draws: no ``eta_cv`` subject appears in
  another block.

:func:`design_faults` is the one design check of the project: ``validate`` reports its faults
and ``analyze`` refuses a run that has any.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Iterable, Sequence
from pathlib import Path

from cirl_study.logs.provenance import RunIdentity
from cirl_study.record import ETA_CV, MAIN, TrialRecord

SUBJECT_FIELDS = ("num_features", "theta", "features", "grid", "start")
"""Record fields on which all trials of one subject must agree."""

EXAMPLES = 3
"""How many examples a fault message names before it only counts."""


def run_faults(
    files: Sequence[tuple[Path, list[TrialRecord], dict[str, str] | None]],
) -> list[str]:
    """Run-level faults of ``files``: ``(path, trial records, provenance)`` per log file.

    Besides the design's: a trial logged in two files; files stating different runs
    (:class:`~cirl_study.logs.provenance.RunIdentity`: run id and pipeline file); records
    of another run than their file's.
    """
    faults = _duplicate_faults(files)
    records = [record for _, file_records, _ in files for record in file_records]
    runs: dict[str, list[str]] = defaultdict(list)
    for path, file_records, provenance in files:
        try:
            identity = RunIdentity.of(provenance or {})
        except ValueError:
            continue  # a file fault already
        runs[f"{identity.run_id} (pipeline sha256 {identity.pipeline_sha256})"].append(path.name)
        foreign = sorted({r.run_id for r in file_records} - {identity.run_id})
        if foreign:
            faults.append(f"{path.name} holds records of run(s) {_examples(foreign)}")
    if len(runs) > 1:
        described = [f"{run} in {_examples(names)}" for run, names in runs.items()]
        faults.append(f"files of {len(runs)} runs: {'; '.join(described)}")
    unique = list({record.trial_id: record for record in records}.values())
    return faults + design_faults(unique)


def design_faults(records: Sequence[TrialRecord]) -> list[str]:
    """Faults of the study design held by ``records`` (see the module docstring)."""
    counts = Counter(record.trial_id for record in records)
    repeated = sorted(trial for trial, count in counts.items() if count > 1)
    faults = [f"{len(repeated)} trial id(s) repeated: {_examples(repeated)}"] if repeated else []
    return faults + _subject_faults(records) + _main_block_faults(records) + _shared_draws(records)


def _duplicate_faults(
    files: Sequence[tuple[Path, list[TrialRecord], dict[str, str] | None]],
) -> list[str]:
    first_file: dict[str, Path] = {}
    duplicates = []
    for path, records, _ in files:
        for record in records:
            trial_id = record.trial_id
            if trial_id in first_file and first_file[trial_id] != path:
                duplicates.append(f"{trial_id} in {first_file[trial_id].name} and {path.name}")
            first_file.setdefault(trial_id, path)
    if not duplicates:
        return []
    return [f"{len(duplicates)} trial id(s) logged in two files: {_examples(duplicates)}"]


def _subject_faults(records: Iterable[TrialRecord]) -> list[str]:
    first: dict[str, TrialRecord] = {}
    disagreeing: list[str] = []
    for record in records:
        reference = first.setdefault(record.subject, record)
        fields = [f for f in SUBJECT_FIELDS if getattr(record, f) != getattr(reference, f)]
        if fields:
            disagreeing.append(
                f"{record.subject} ({', '.join(fields)} of {record.trial_id} "
                f"differ from {reference.trial_id})"
            )
    if not disagreeing:
        return []
    return [
        f"{len(disagreeing)} record(s) disagree with their subject's draw: {_examples(disagreeing)}"
    ]


def _main_block_faults(records: Sequence[TrialRecord]) -> list[str]:
    if not any(record.block == MAIN for record in records):
        return ["no trials in the main block: the policy x num_features study is missing"]
    cells, incomplete = incomplete_main_subjects(records)
    if not incomplete:
        return []
    described = [
        f"{subject} has {dict(sorted(count.items()))}"
        for subject, count in sorted(incomplete.items())
    ]
    return [
        f"main block incomplete: {len(described)} subject(s) without exactly one trial of "
        f"each of {', '.join(cells)}: {_examples(described)}"
    ]


def incomplete_main_subjects(
    records: Iterable[TrialRecord],
) -> tuple[list[str], dict[str, Counter[str]]]:
    """The ``main`` block's within-subjects cells (``policy/robot``, sorted), and each subject
    that lacks exactly one trial of every one of them, with its trials per cell."""
    trials: dict[str, Counter[str]] = defaultdict(Counter)
    for record in records:
        if record.block == MAIN:
            trials[record.subject][_cell(record)] += 1
    cells = sorted({cell for count in trials.values() for cell in count})
    incomplete = {
        subject: count
        for subject, count in trials.items()
        if [count[cell] for cell in cells] != [1] * len(cells)
    }
    return cells, incomplete


def _cell(record: TrialRecord) -> str:
    """The within-subjects cell of a ``main`` trial: ``policy/robot``."""
    return f"{record.policy}/{record.robot}"


def _shared_draws(records: Iterable[TrialRecord]) -> list[str]:
    blocks: dict[str, set[str]] = defaultdict(set)
    for record in records:
        blocks[record.subject].add(record.block)
    shared = sorted(s for s, b in blocks.items() if ETA_CV in b and len(b) > 1)
    if not shared:
        return []
    return [f"{len(shared)} eta_cv subject(s) also used in the test blocks: {_examples(shared)}"]


def _examples(items: Sequence[str]) -> str:
    shown = ", ".join(items[:EXAMPLES])
    return shown if len(items) <= EXAMPLES else f"{shown}, ... ({len(items) - EXAMPLES} more)"
