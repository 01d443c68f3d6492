"""Faults of a run as a whole (DESIGN.md section 5), across its log files.

* No trial id is logged in two files; all files share one ``run_id`` and one pipeline.
* A subject is one reward draw: all its records agree on ``num_features``, ``theta``, the
  features, the grid and the start cell.
* The ``main`` block is complete and within subjects: every subject in it has exactly one
  ``expert`` and one ``best_response`` trial (trial ids counted once, duplicates being a fault
  of their own).
* Cross-validation draws are disjoint from the test draws: no ``eta_cv`` subject appears in
  another block.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from cirl_study.logs.format import PIPELINE_NAME_KEY

POLICIES = ("expert", "best_response")
#: Record fields on which all trials of one subject must agree.
SUBJECT_FIELDS = ("num_features", "theta", "features", "grid", "start")
#: How many examples a fault message names before it only counts.
EXAMPLES = 3


def run_faults(
    files: Sequence[tuple[Path, list[dict[str, Any]], dict[str, str] | None]],
) -> list[str]:
    """Run-level faults of ``files``: ``(path, trial records, provenance)`` per log file."""
    faults = _duplicate_faults(files)
    records = [record for _, file_records, _ in files for record in file_records]
    run_ids = sorted({record["run_id"] for record in records})
    if len(run_ids) > 1:
        faults.append(f"records of {len(run_ids)} runs: {_examples(run_ids)}")
    pipelines = sorted({p.get(PIPELINE_NAME_KEY, "") for _, _, p in files if p is not None})
    if len(pipelines) > 1:
        faults.append(f"files of {len(pipelines)} pipelines: {_examples(pipelines)}")
    faults.extend(_subject_faults(records))
    faults.extend(_design_faults(records))
    return faults


def _duplicate_faults(
    files: Sequence[tuple[Path, list[dict[str, Any]], dict[str, str] | None]],
) -> list[str]:
    first_file: dict[str, Path] = {}
    duplicates = []
    for path, records, _ in files:
        for record in records:
            trial_id = record["trial_id"]
            if trial_id in first_file and first_file[trial_id] != path:
                duplicates.append(f"{trial_id} in {first_file[trial_id].name} and {path.name}")
            first_file.setdefault(trial_id, path)
    if not duplicates:
        return []
    return [f"{len(duplicates)} trial id(s) logged in two files: {_examples(duplicates)}"]


def _subject_faults(records: Iterable[dict[str, Any]]) -> list[str]:
    first: dict[str, dict[str, Any]] = {}
    disagreeing: list[str] = []
    for record in records:
        reference = first.setdefault(record["subject"], record)
        fields = [f for f in SUBJECT_FIELDS if record[f] != reference[f]]
        if fields:
            disagreeing.append(
                f"{record['subject']} ({', '.join(fields)} of {record['trial_id']} "
                f"differ from {reference['trial_id']})"
            )
    if not disagreeing:
        return []
    return [
        f"{len(disagreeing)} record(s) disagree with their subject's draw: {_examples(disagreeing)}"
    ]


def _design_faults(records: Sequence[dict[str, Any]]) -> list[str]:
    faults = []
    trials: dict[str, dict[str, set[str]]] = defaultdict(lambda: defaultdict(set))
    blocks: dict[str, set[str]] = defaultdict(set)
    for record in records:
        blocks[record["subject"]].add(record["block"])
        if record["block"] == "main":
            trials[record["subject"]][record["policy"]].add(record["trial_id"])
    counts = {
        subject: {policy: len(ids) for policy, ids in sorted(by_policy.items())}
        for subject, by_policy in sorted(trials.items())
    }
    incomplete = [
        f"{subject} has {count}"
        for subject, count in counts.items()
        if count != dict.fromkeys(sorted(POLICIES), 1)
    ]
    if incomplete:
        faults.append(
            f"main block incomplete: {len(incomplete)} subject(s) without exactly one trial "
            f"per policy: {_examples(incomplete)}"
        )
    shared = sorted(s for s, b in blocks.items() if "eta_cv" in b and len(b) > 1)
    if shared:
        faults.append(
            f"{len(shared)} eta_cv subject(s) also used in the test blocks: {_examples(shared)}"
        )
    return faults


def _examples(items: Sequence[str]) -> str:
    shown = ", ".join(items[:EXAMPLES])
    return shown if len(items) <= EXAMPLES else f"{shown}, ... ({len(items) - EXAMPLES} more)"
