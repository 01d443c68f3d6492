"""MCAP logs of the study: writing, reading and validating (DESIGN.md sections 6-7).

The log format is described in ``docs/log-format.md`` and :mod:`cirl_study.logs.format`.
"""

from cirl_study.logs.format import canonical_json
from cirl_study.logs.provenance import collect_provenance
from cirl_study.logs.reader import (
    LoggedTrials,
    RunContents,
    completed_trial_ids,
    logged_trials,
    read_run,
)
from cirl_study.logs.record_checks import record_faults
from cirl_study.logs.validate import FileVerdict, RunVerdict, validate_file, validate_run
from cirl_study.logs.writer import TrialLogWriter

__all__ = [
    "FileVerdict",
    "LoggedTrials",
    "RunContents",
    "RunVerdict",
    "TrialLogWriter",
    "canonical_json",
    "collect_provenance",
    "completed_trial_ids",
    "logged_trials",
    "read_run",
    "record_faults",
    "validate_file",
    "validate_run",
]
