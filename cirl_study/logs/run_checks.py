"""Faults of a run as a whole (docs/design.md §5), across its log files.

* No trial id is logged twice; all files state one run (run id and pipeline file) and hold
  only its records.
* A subject is one reward draw: all its records agree on ``num_features``, ``theta``, the
  features, the grid and the start cell (their :attr:`~cirl_study.record.TrialRow.draw`
  digest; so a subject lies at one feature level). In a multiverse this holds within each
  universe (:func:`subject_in_universe`): universes differ in the features by design.
* The ``main`` block is non-empty, complete and within subjects: every subject in it has
  exactly one trial of every (robot, human) pair the block plays. A participant (a subject of
  the ``recorded`` human) is one draw and one set of cells per demonstration
  (:func:`main_unit`): each of her demonstrations shows one task, which every robot watches
  once; she need not have shown every task.
* Cross-validation draws are disjoint from the test draws: no ``eta_cv`` subject appears in
  another block.

:func:`design_faults` is the one design check of the project: ``validate`` reports its faults
and ``analyze`` refuses a run that has any. The checks read the records' rows
(:class:`~cirl_study.record.TrialRow`), so a run of any size is checked in memory.
"""

from __future__ import annotations

from collections import Counter, defaultdict
from collections.abc import Iterable, Sequence
from pathlib import Path

from cirl_study.escape import terminal
from cirl_study.logs.provenance import RunIdentity
from cirl_study.record import ETA_CV, MAIN, TrialRow

EXAMPLES = 3
"""How many examples a fault message names before it only counts."""


def run_faults(
    files: Sequence[tuple[Path, list[TrialRow], dict[str, str] | None]],
) -> list[str]:
    """Run-level faults of ``files``: ``(path, trial rows, provenance)`` per log file.

    Besides the design's: a trial logged in two files; files stating different runs
    (:class:`~cirl_study.logs.provenance.RunIdentity`: run id and pipeline file); records
    of another run than their file's.
    """
    faults = _duplicate_faults(files)
    rows = [row for _, file_rows, _ in files for row in file_rows]
    runs: dict[str, list[str]] = defaultdict(list)
    for path, file_rows, provenance in files:
        try:
            identity = RunIdentity.of(provenance or {})
        except ValueError:
            continue  # a file fault already
        runs[f"{identity.run_id} (pipeline sha256 {identity.pipeline_sha256})"].append(path.name)
        foreign = sorted({r.run_id for r in file_rows} - {identity.run_id})
        if foreign:
            faults.append(f"{path.name} holds records of run(s) {_examples(_shown(foreign))}")
    if len(runs) > 1:
        described = [f"{run} in {_examples(names)}" for run, names in runs.items()]
        faults.append(f"files of {len(runs)} runs: {'; '.join(described)}")
    unique = list({row.trial_id: row for row in rows}.values())
    return faults + design_faults(unique)


def design_faults(rows: Sequence[TrialRow]) -> list[str]:
    """Faults of the study design held by the trials' ``rows`` (see the module docstring)."""
    counts = Counter(row.trial_id for row in rows)
    repeated = sorted(trial for trial, count in counts.items() if count > 1)
    shown = _examples(_shown(repeated))
    faults = [f"{len(repeated)} trial id(s) repeated: {shown}"] if repeated else []
    return faults + _subject_faults(rows) + _main_block_faults(rows) + _shared_draws(rows)


def _duplicate_faults(
    files: Sequence[tuple[Path, list[TrialRow], dict[str, str] | None]],
) -> list[str]:
    first_file: dict[str, Path] = {}
    duplicates = []
    for path, rows, _ in files:
        for row in rows:
            trial_id = row.trial_id
            if trial_id in first_file and first_file[trial_id] != path:
                duplicates.append(
                    f"{terminal(trial_id)} in {first_file[trial_id].name} and {path.name}"
                )
            first_file.setdefault(trial_id, path)
    if not duplicates:
        return []
    return [f"{len(duplicates)} trial id(s) logged in two files: {_examples(duplicates)}"]


def subject_in_universe(row: TrialRow) -> str:
    """The subject of a trial within its universe: ``<subject>@<universe>`` (in a single study,
    the subject)."""
    return row.subject if row.universe is None else f"{row.subject}@{row.universe}"


def main_unit(row: TrialRow) -> str:
    """What shares one reward draw and plays every cell of the ``main`` block once: a subject
    (:func:`subject_in_universe`), or one demonstration of a participant,
    ``<subject>:task=<task>`` (``:condition=<condition>`` after it)."""
    subject = subject_in_universe(row)
    if row.participant is None:
        return subject
    return f"{subject}:task={row.task}:condition={row.condition}"


def _subject_faults(rows: Iterable[TrialRow]) -> list[str]:
    first: dict[str, TrialRow] = {}
    disagreeing: list[str] = []
    for row in rows:
        reference = first.setdefault(main_unit(row), row)
        if row.draw != reference.draw:
            levels = (
                f": num_features {row.num_features} against {reference.num_features}"
                if row.num_features != reference.num_features
                else ""
            )
            disagreeing.append(
                f"{terminal(row.subject)} (the reward draw of {terminal(row.trial_id)} differs "
                f"from {terminal(reference.trial_id)}'s{levels})"
            )
    if not disagreeing:
        return []
    return [
        f"{len(disagreeing)} record(s) disagree with their subject's draw: {_examples(disagreeing)}"
    ]


def _main_block_faults(rows: Sequence[TrialRow]) -> list[str]:
    if not any(row.block == MAIN for row in rows):
        return ["no trials in the main block: the human x num_features study is missing"]
    cells, incomplete = incomplete_main_subjects(rows)
    if not incomplete:
        return []
    described = [
        f"{terminal(subject)} has {terminal(dict(sorted(count.items())))}"
        for subject, count in sorted(incomplete.items())
    ]
    return [
        f"main block incomplete: {len(described)} subject(s) without exactly one trial of "
        f"each of {', '.join(_shown(cells))}: {_examples(described)}"
    ]


def incomplete_main_subjects(
    rows: Iterable[TrialRow],
) -> tuple[list[str], dict[str, Counter[str]]]:
    """The ``main`` block's within-subjects cells (``human/robot``, sorted), and each subject
    (:func:`main_unit`: a participant's demonstration) that lacks exactly one trial of every
    cell its universe plays (the recorded human's, for a demonstration; the others', for a
    subject), with its trials per cell."""
    trials: dict[str, Counter[str]] = defaultdict(Counter)
    kind_of: dict[str, tuple[str | None, bool]] = {}
    cells_of: dict[tuple[str | None, bool], set[str]] = defaultdict(set)
    for row in rows:
        if row.block == MAIN:
            unit, kind = main_unit(row), (row.universe, row.participant is not None)
            trials[unit][_cell(row)] += 1
            kind_of[unit] = kind
            cells_of[kind].add(_cell(row))
    incomplete = {
        unit: count
        for unit, count in trials.items()
        if any(count[cell] != 1 for cell in cells_of[kind_of[unit]])
    }
    return sorted(set().union(*cells_of.values())), incomplete


def _cell(row: TrialRow) -> str:
    """The within-subjects cell of a ``main`` trial: ``human/robot``."""
    return f"{row.human}/{row.robot}"


def _shared_draws(rows: Iterable[TrialRow]) -> list[str]:
    blocks: dict[str, set[str]] = defaultdict(set)
    for row in rows:
        blocks[row.subject].add(row.block)
    shared = sorted(s for s, b in blocks.items() if ETA_CV in b and len(b) > 1)
    if not shared:
        return []
    shown = _examples(_shown(shared))
    return [f"{len(shared)} eta_cv subject(s) also used in the test blocks: {shown}"]


def _shown(items: Iterable[str]) -> list[str]:
    """Texts from the logs as a terminal shows them (:func:`cirl_study.escape.terminal`)."""
    return [terminal(item) for item in items]


def _examples(items: Sequence[str]) -> str:
    shown = ", ".join(items[:EXAMPLES])
    return shown if len(items) <= EXAMPLES else f"{shown}, ... ({len(items) - EXAMPLES} more)"


def complete_main_subjects(rows: Sequence[TrialRow]) -> tuple[list[TrialRow], list[str]]:
    """The trials without the ``main``-block trials of subjects that lack a cell.

    For a partial run: a ``main`` subject must have exactly one trial in every (human,
    robot) cell the block plays to enter the within-subjects analysis
    (:func:`incomplete_main_subjects`). Returns the rows kept
    and the ids of the subjects whose ``main`` trials were left out.
    """
    _, incomplete = incomplete_main_subjects(rows)
    kept = [r for r in rows if not (r.block == MAIN and main_unit(r) in incomplete)]
    return kept, sorted(incomplete)
