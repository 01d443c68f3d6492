"""A run's logs as an analysis takes them: read, audited, its trials chosen, and the
provenance its report states (:func:`read_for_analysis`).

Every analysis of a run reads it here: ``cirl-study analyze``, ``cirl-study calibrate`` (and
the probes of its refinement) and :func:`cirl_study.api.analyze`. The logs are read as
:func:`~cirl_study.logs.reader.read_run` reads them (every file checked, its pipeline judged
by :func:`~cirl_study.study.pipeline_file.logged_pipeline`) and the run audited against the
pipeline they carry (:func:`~cirl_study.study.audit.audit_run`).
"""

from __future__ import annotations

import datetime
import gc
import importlib
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cirl_study.errors import UserError
from cirl_study.escape import terminal
from cirl_study.logs.provenance import machine_provenance
from cirl_study.logs.reader import read_run
from cirl_study.logs.run_checks import complete_main_subjects
from cirl_study.record import TrialRecord, TrialRow
from cirl_study.study.audit import audit_run, resume_advice
from cirl_study.study.pipeline_file import logged_pipeline, pipelines_in
from cirl_study.study.spec import Pipeline


@dataclass(frozen=True)
class AnalysedRun:
    """What an analysis of a run takes: its pipeline (from the logs), the trials it analyses,
    the run's id, and, for an incomplete run analysed anyway, what it lacks (``partial``:
    ``planned``, ``logged``, ``missing``, ``damaged_files``, ``main_subjects_left_out``;
    ``None`` for a complete run); the ``provenance.json`` of its report (``None`` when no
    report is written: see :func:`read_for_analysis`); and the whole records of the trials
    asked for (``records``), fetched from the logs."""

    pipeline: Pipeline
    trials: list[TrialRow]
    run_id: str
    partial: dict[str, Any] | None
    provenance: dict[str, Any] | None
    records: Callable[[set[str]], list[TrialRecord]]


def read_for_analysis(
    run_dir: Path,
    *,
    partial: bool = False,
    outputs: Sequence[Path] | None = None,
    warn: Callable[[str], object] = lambda warning: None,
) -> AnalysedRun:
    """The run in ``run_dir`` as an analysis takes it: every trial of a complete run; with
    ``partial``, an incomplete or damaged run's trials (its damaged files salvaged) less the
    ``main`` subjects that lack a cell
    (:func:`~cirl_study.logs.run_checks.complete_main_subjects`).

    Each warning of reading the logs (a damaged file salvaged, temporary files ignored) is
    told to ``warn`` before the run is audited. Given ``outputs``, the directories that the
    command writing a report of the run writes to (the report's, and calibrate's probes), the
    run is read for that report: the libraries every report needs load while the logs are read
    (:func:`_load_report_libraries`), and :attr:`AnalysedRun.provenance` is the report's
    (:func:`_report_provenance`).

    Raises:
        UserError: the logs do not read as one run; a foreign trial; an incomplete run
            without ``partial`` (naming what is missing and how to resume); an incomplete
            multiverse (analysed only whole).
    """
    contents = read_run(
        run_dir,
        pipelines_in(run_dir),
        salvage=partial,
        meanwhile=_load_report_libraries if outputs is not None else lambda: None,
    )
    for warning in contents.warnings:
        warn(warning)
    pipeline = logged_pipeline(contents.identity, run_dir)
    audit = audit_run(pipeline, contents.rows)
    incomplete = not audit.complete or bool(contents.damaged)
    # How to complete the run, only where it is not: the advice hashes the pipeline files it
    # may name.
    resume = resume_advice(contents.identity, run_dir, contents.writer) if incomplete else ""
    faults = audit.faults(resume)
    whole = pipeline.multiverse is not None
    if audit.foreign or (faults and not partial):
        advice = "" if audit.foreign or whole else ", or analyze it with --partial"
        raise UserError(f"{terminal(run_dir)}: not a complete run: {faults[0]}{advice}")
    trials, lacks = contents.rows, None
    if incomplete:
        if whole:
            raise UserError(
                f"{terminal(run_dir)}: a multiverse is analysed only whole (its universes "
                f"share the reward draws); {resume}"
            )
        missing = audit.missing_text() or None
        trials, left_out = complete_main_subjects(contents.rows)
        lacks = {
            "planned": audit.planned,
            "logged": audit.logged,
            "missing": missing,
            "damaged_files": len(contents.damaged),
            "main_subjects_left_out": len(left_out),
        }
    return AnalysedRun(
        pipeline=pipeline,
        trials=trials,
        run_id=contents.identity.run_id,
        partial=lacks,
        provenance=None
        if outputs is None
        else _report_provenance(contents.provenance, outputs=(run_dir, *outputs)),
        records=contents.records,
    )


def _load_report_libraries() -> None:
    """Load what every report needs that reading the logs does not (pandas, scipy, matplotlib
    and pingouin: the statistics, the figures and the trial table).

    The libraries live as long as the process, so the garbage collector is paused while they
    load and they are frozen out of it after (``gc.freeze``, until workers fork: see
    :func:`~cirl_study.workers.started`): its full collections would otherwise walk their few
    hundred thousand objects while they load and while the rows arrive.
    """
    gc.disable()
    try:
        for module in (
            "cirl_study.analysis.statistics.procedures",
            "cirl_study.analysis.report.figures",
            "cirl_study.analysis.table",
        ):
            importlib.import_module(module)
    finally:
        gc.enable()
    gc.freeze()


def _report_provenance(run: list[dict[str, str]], *, outputs: Sequence[Path]) -> dict[str, Any]:
    """``provenance.json`` of a report: each distinct provenance of the run's log files
    (``run``, in a fixed order) and the report's own: the date, the machine and the packages
    (:func:`~cirl_study.logs.provenance.machine_provenance`; whether the checkout is dirty
    judged without the ``outputs``: the run's directory and those the command writes to)."""
    distinct = {json.dumps(p, sort_keys=True): p for p in run}
    return {
        "run": [distinct[key] for key in sorted(distinct)],
        "report": {
            "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            **machine_provenance(outputs=outputs),
        },
    }
