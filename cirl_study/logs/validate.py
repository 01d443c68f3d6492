"""Verdicts on a run's log files, one per file and one for the run (``cirl-study validate``).

A file is OK when :func:`~cirl_study.logs.scan.scan_file` finds no storage fault (magic,
framing, chunk / data-section / summary CRCs, summary counts and indexes) and
:func:`~cirl_study.logs.contents.read_file_contents` no content fault (provenance, schemas and
encodings, every record complete and consistent, time layout, replay counts), and its run
identity states a pipeline the study accepts (:data:`~cirl_study.logs.provenance.PipelineOf`);
an entry named like a log that is no regular file, or a file past a bound of
:mod:`cirl_study.logs.bounds`, fails with what it is. The run is OK when every file is, no
temporary file is left, :func:`~cirl_study.logs.run_checks.run_faults` finds nothing. Whether
the logs hold exactly the trials the run's pipeline plans is the study's question (its audit
of the plan); ``cirl-study validate`` asks both.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from cirl_study.escape import terminal
from cirl_study.files import non_regular
from cirl_study.logs.contents import read_file_contents
from cirl_study.logs.format import log_files, temp_files
from cirl_study.logs.lock import writer_pid
from cirl_study.logs.provenance import PipelineOf, pipeline_faults
from cirl_study.logs.reader import check_run_directory
from cirl_study.logs.run_checks import run_faults
from cirl_study.record import TrialRow
from cirl_study.workers import map_in_workers

#: Faults shown on a verdict line before the rest are only counted.
SHOWN_FAULTS = 3


@dataclass(frozen=True)
class FileVerdict:
    """The verdict on one log file: its readable trial count and every fault found."""

    path: Path
    trials: int
    faults: tuple[str, ...]

    @property
    def ok(self) -> bool:
        return not self.faults

    def line(self) -> str:
        """``OK path: N trials`` or ``FAIL path: reason; ...``."""
        if self.ok:
            return f"OK {self.path}: {self.trials} trials"
        return f"FAIL {self.path}: {_summary(self.faults)}"


@dataclass(frozen=True)
class RunVerdict:
    """The verdict on a run: one per file plus the run-level faults, and the rows of the
    records read (:class:`~cirl_study.record.TrialRow`), per file."""

    run_dir: Path
    files: tuple[FileVerdict, ...]
    faults: tuple[str, ...]
    rows: tuple[tuple[Path, list[TrialRow], dict[str, str] | None], ...] = ()

    @property
    def ok(self) -> bool:
        return not self.faults and all(verdict.ok for verdict in self.files)

    @property
    def trials(self) -> int:
        return sum(verdict.trials for verdict in self.files)

    def line(self) -> str:
        """The run-level verdict line."""
        totals = f"{len(self.files)} file(s), {self.trials} trials"
        if self.ok:
            return f"OK run {self.run_dir}: {totals}, design complete"
        bad = sum(not verdict.ok for verdict in self.files)
        reasons = [f"{bad} faulty file(s)"] if bad else []
        return f"FAIL run {self.run_dir}: {totals}; {_summary((*reasons, *self.faults))}"


def validate_file(path: str | Path, pipeline_of: PipelineOf) -> FileVerdict:
    """Check one log file (see the module docstring), its identity's pipeline judged by
    ``pipeline_of``."""
    return _checked(Path(path)).verdict(pipeline_of)


def validate_run(run_dir: str | Path, pipeline_of: PipelineOf) -> RunVerdict:
    """Check every complete file of ``run_dir`` (each identity's pipeline judged by
    ``pipeline_of``, in this process) and the run as a whole."""
    run_dir = Path(run_dir)
    check_run_directory(run_dir)
    verdicts, files = [], []
    for checked in map_in_workers(_checked, log_files(run_dir)):
        verdicts.append(checked.verdict(pipeline_of))
        files.append((checked.path, checked.rows, checked.provenance))
    faults = run_faults(files) if verdicts else ["no complete log files (*.mcap)"]
    unfinished = []
    for path in temp_files(run_dir):
        reason = non_regular(path)
        if reason is None:
            unfinished.append(path)
        else:
            faults.append(f"{terminal(path)}: {reason}, not a temporary log file")
    pid = writer_pid(run_dir) if unfinished else None
    if pid is not None:
        faults.append(
            f"{len(unfinished)} temporary file(s): a cirl-study run (pid {pid}) is still "
            "writing it, wait for it to end"
        )
    elif unfinished:
        faults.append(
            f"{len(unfinished)} unfinished temporary file(s) of an interrupted run "
            f"(e.g. {unfinished[0].name}); run the pipeline again to complete the run"
        )
    return RunVerdict(run_dir, tuple(verdicts), tuple(faults), tuple(files))


@dataclass(frozen=True)
class _Checked:
    """What :func:`validate_run` keeps of one file, checked in a worker: its faults, the rows
    of its readable records and its provenance."""

    path: Path
    damage: list[str]
    content_faults: list[str]
    rows: list[TrialRow]
    provenance: dict[str, str] | None

    def verdict(self, pipeline_of: PipelineOf) -> FileVerdict:
        """The file's verdict, its identity's pipeline judged by ``pipeline_of``: storage
        damage first, then content."""
        pipeline = pipeline_faults(self.provenance, pipeline_of)
        faults = (*self.damage, *pipeline, *self.content_faults)
        return FileVerdict(self.path, len(self.rows), faults)


def _checked(path: Path) -> _Checked:
    """One file of :func:`validate_run`."""
    contents = read_file_contents(path)
    rows = [TrialRow.of(record) for record in contents.records]
    return _Checked(path, contents.damage, contents.content_faults, rows, contents.provenance)


def _summary(faults: tuple[str, ...]) -> str:
    shown = "; ".join(faults[:SHOWN_FAULTS])
    rest = len(faults) - SHOWN_FAULTS
    return shown if rest <= 0 else f"{shown}; and {rest} more"
