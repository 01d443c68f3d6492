"""Is a run complete? Its logged trials against the trials its pipeline plans.

Every log file carries the run's pipeline file (:class:`~cirl_study.logs.provenance.RunIdentity`),
so the logs alone say what the run must hold. :func:`audit_run` takes that pipeline (validated
when the identity was read: :func:`~cirl_study.study.pipeline_file.logged_pipeline`), plans
block ``eta_cv`` (:func:`~cirl_study.study.plan.eta_cv_trial_ids`), chooses eta from the logged
cross-validation records exactly as the run did (:func:`~cirl_study.study.eta_cv.study_etas`),
plans blocks ``main`` and ``lambda_sweep`` with it, and compares trial ids: a planned trial
that is not logged is *missing*, a logged trial that is not planned is *foreign*. Until every
cross-validation trial is logged the study blocks cannot be planned trial by trial; they are
then counted (:func:`~cirl_study.study.plan.trial_counts`) and their records checked only
for belonging to a study block. :func:`resume_advice` says how to complete a run that lacks
trials.
"""

from __future__ import annotations

import hashlib
import os
import stat
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from cirl_study.escape import shell, terminal
from cirl_study.logs.format import MAX_PIPELINE_BYTES
from cirl_study.logs.lock import writer_pid
from cirl_study.logs.provenance import RunIdentity
from cirl_study.logs.reader import read_run
from cirl_study.record import ETA_CV, TrialRow
from cirl_study.study.eta_cv import study_etas
from cirl_study.study.pipeline_file import (
    logged_pipeline,
    path_argument,
    pipeline_search_path,
    pipelines_in,
)
from cirl_study.study.plan import eta_cv_trial_ids, study_trial_ids, trial_counts
from cirl_study.study.spec import Pipeline

EXAMPLES = 3
"""How many foreign trial ids a fault names."""


@dataclass(frozen=True)
class BlockAudit:
    """One block: trials planned, and how many of them are logged."""

    block: str
    planned: int
    logged: int

    @property
    def missing(self) -> int:
        return self.planned - self.logged


@dataclass(frozen=True)
class RunAudit:
    """The logged trials of a run against its plan (see the module docstring)."""

    blocks: tuple[BlockAudit, ...]
    foreign: tuple[str, ...]
    study_checked: bool
    """Whether the study blocks were planned trial by trial (every ``eta_cv`` trial logged)."""

    @property
    def planned(self) -> int:
        return sum(block.planned for block in self.blocks)

    @property
    def logged(self) -> int:
        return sum(block.logged for block in self.blocks)

    @property
    def complete(self) -> bool:
        return not self.foreign and all(block.missing == 0 for block in self.blocks)

    def missing_text(self) -> str:
        """``lambda_sweep: 500 of 16000 trials missing; ...`` (empty when nothing is)."""
        text = "; ".join(
            f"{block.block}: {block.missing} of {block.planned} trials missing"
            for block in self.blocks
            if block.missing
        )
        if text and not self.study_checked:
            text += " (the study blocks are checked trial by trial once eta_cv is complete)"
        return text

    def faults(self, advice: str) -> list[str]:
        """One line per fault: foreign trials; missing trials, with the ``advice`` on
        completing the run (:func:`resume_advice`)."""
        faults = []
        if self.foreign:
            shown = ", ".join(terminal(trial_id) for trial_id in self.foreign[:EXAMPLES])
            more = (
                f" and {len(self.foreign) - EXAMPLES} more" if len(self.foreign) > EXAMPLES else ""
            )
            faults.append(
                f"{len(self.foreign)} logged trial(s) the run's pipeline does not plan: "
                f"{shown}{more}"
            )
        if self.missing_text():
            faults.append(f"{self.missing_text()}; {advice}")
        return faults


def audit_run(pipeline: Pipeline, rows: Sequence[TrialRow]) -> RunAudit:
    """Compare the logged trials (their ``rows``) with the trials ``pipeline`` plans."""
    logged = {row.trial_id: row for row in rows}
    cv_ids = set(eta_cv_trial_ids(pipeline))
    cv_logged = [logged[trial_id] for trial_id in cv_ids if trial_id in logged]
    blocks = [BlockAudit(ETA_CV, len(cv_ids), len(cv_logged))]
    counts = trial_counts(pipeline)
    study_blocks = [block for block in counts if block != ETA_CV]
    if len(cv_logged) == len(cv_ids):
        etas = {key: choice.eta for key, choice in study_etas(pipeline, cv_logged).items()}
        plan = study_trial_ids(pipeline, etas)
        planned = {trial_id for _, trial_id in plan} | cv_ids
        found = Counter(block for block, trial_id in plan if trial_id in logged)
        blocks += [BlockAudit(block, counts[block], found[block]) for block in study_blocks]
        foreign = sorted(set(logged) - planned)
    else:
        found = Counter(row.block for row in rows)
        blocks += [
            BlockAudit(block, counts[block], min(found[block], counts[block]))
            for block in study_blocks
        ]
        foreign = sorted(
            trial_id
            for trial_id, row in logged.items()
            if (row.block == ETA_CV and trial_id not in cv_ids) or row.block not in counts
        )
    return RunAudit(tuple(blocks), tuple(foreign), len(cv_logged) == len(cv_ids))


def plan_faults(
    run_dir: Path, files: Sequence[tuple[Path, list[TrialRow], dict[str, str] | None]]
) -> list[str]:
    """The faults of a run's logged trials against its plan.

    Only for files that all state one run identity; other files are faults of their own
    (:func:`~cirl_study.logs.run_checks.run_faults`).
    """
    identities = set()
    for _, _, provenance in files:
        try:
            identities.add(RunIdentity.of(provenance or {}))
        except ValueError:
            return []
    if len(identities) != 1:
        return []
    (identity,) = identities
    try:
        pipeline = logged_pipeline(identity, run_dir)
    except ValueError:
        return []  # a fault of every file already
    rows = [row for _, file_rows, _ in files for row in file_rows]
    writer = writer_pid(run_dir)
    return audit_run(pipeline, rows).faults(resume_advice(identity, run_dir, writer))


def resume_advice(identity: RunIdentity, run_dir: Path, writer: str | None) -> str:
    """How to complete the run in ``run_dir``: that a run is writing to it, while one is
    (``writer``, its process id: :func:`~cirl_study.logs.lock.writer_pid`); else
    :func:`resume_command`."""
    if writer is not None:
        return f"a cirl-study run (pid {writer}) is still writing it: wait for it to end"
    return resume_command(identity, run_dir)


def resume_command(identity: RunIdentity, run_dir: Path) -> str:
    """``resume with `<command>```, the command that completes the run in ``run_dir``, each
    of its arguments a shell word (:func:`~cirl_study.escape.shell`) naming its path as
    :func:`~cirl_study.study.pipeline_file.path_argument` does.

    The command's pipeline is a file that holds the run's pipeline text now
    (:func:`_pipeline_file`); when none does, the command says ``PIPELINE`` and what it must be.
    """
    out = path_argument(run_dir)
    pipeline = _pipeline_file(identity)
    if pipeline is None:
        return (
            f"resume with `cirl-study run PIPELINE --out {shell(out)}`, PIPELINE a file "
            f"holding the run's pipeline text (its logs' pipeline_toml, sha256 "
            f"{identity.pipeline_sha256[:12]}...), which is no longer at "
            f"{terminal(identity.pipeline_file)}"
        )
    return f"resume with `cirl-study run {shell(pipeline)} --out {shell(out)}`"


def _pipeline_file(identity: RunIdentity) -> str | None:
    """A file that holds the run's pipeline text, as
    :func:`~cirl_study.study.pipeline_file.path_argument` names it: the file the run was made
    from, where the run recorded it, else the pipeline of the run's name in
    :func:`~cirl_study.study.pipeline_file.pipeline_search_path`; ``None`` if neither does."""
    candidates = [identity.pipeline_file] + [
        str(directory / f"{identity.pipeline_name}.toml") for directory in pipeline_search_path()
    ]
    for candidate in candidates:
        if _holds(candidate, identity.pipeline_sha256):
            return path_argument(Path(candidate))
    return None


def _holds(path: str, sha256: str) -> bool:
    """Whether ``path`` is a regular file of at most :data:`MAX_PIPELINE_BYTES` whose bytes
    hash to ``sha256``. The path may come from a log: a FIFO or a device there is not read,
    nor waited on."""
    try:
        descriptor = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except (OSError, ValueError):
        return False
    with os.fdopen(descriptor, "rb") as stream:
        status = os.fstat(descriptor)
        if not stat.S_ISREG(status.st_mode) or status.st_size > MAX_PIPELINE_BYTES:
            return False
        data = stream.read(MAX_PIPELINE_BYTES + 1)
    return hashlib.sha256(data).hexdigest() == sha256


@dataclass(frozen=True)
class RunStatus:
    """What ``cirl-study show`` says of a run: its identity and the pipeline it plays, the
    trials logged against the plan (:class:`RunAudit`), its files (and the damaged ones,
    read as far as they are intact), and how to complete it."""

    identity: RunIdentity
    pipeline: Pipeline
    audit: RunAudit
    files: int
    damaged: tuple[Path, ...]
    advice: str

    def lines(self) -> list[str]:
        """The status as lines of text, each escaped for a terminal."""
        identity, audit = self.identity, self.audit
        state = "complete" if audit.complete else "incomplete"
        if not audit.complete:
            missing = audit.missing_text() or f"{len(audit.foreign)} foreign trial(s)"
            state += f" ({missing}); {self.advice}"
        blocks = ", ".join(
            f"{block.block} {block.logged} of {block.planned}" for block in audit.blocks
        )
        lines = [
            f"run {identity.run_id}: pipeline {identity.pipeline_name} "
            f"({self.pipeline.description}), from {identity.pipeline_file}, "
            f"log format {identity.log_format}",
            f"status: {state}",
            f"trials: {audit.logged} of {audit.planned} planned, in {self.files} file(s): {blocks}",
        ]
        if self.damaged:
            names = ", ".join(path.name for path in self.damaged)
            lines.append(f"damaged: {len(self.damaged)} file(s), read as far as intact: {names}")
        return [terminal(line, limit=None) for line in lines]


def run_status(run_dir: Path) -> RunStatus:
    """The :class:`RunStatus` of the run in ``run_dir``, its damaged files salvaged.

    Raises:
        UserError: ``run_dir`` is no run directory, or holds no readable log file.
    """
    contents = read_run(run_dir, pipelines_in(run_dir), salvage=True)
    pipeline = logged_pipeline(contents.identity, run_dir)
    return RunStatus(
        identity=contents.identity,
        pipeline=pipeline,
        audit=audit_run(pipeline, contents.rows),
        files=len(contents.files),
        damaged=tuple(contents.damaged),
        advice=resume_advice(contents.identity, run_dir, contents.writer),
    )
