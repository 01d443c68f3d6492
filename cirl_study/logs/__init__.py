"""MCAP logs of the study: writing, reading and validating (docs/design.md §6-7).

The log format is described in ``docs/log-format.md`` and :mod:`cirl_study.logs.format`; the
trial record it carries is :class:`cirl_study.record.TrialRecord`.
"""

from cirl_study.logs.provenance import RunIdentity, collect_provenance
from cirl_study.logs.reader import RunContents, logged_trials, read_run, read_trials
from cirl_study.logs.record_checks import decode_trial, record_faults
from cirl_study.logs.validate import FileVerdict, RunVerdict, validate_file, validate_run
from cirl_study.logs.writer import TrialLogWriter

__all__ = [
    "FileVerdict",
    "RunContents",
    "RunIdentity",
    "RunVerdict",
    "TrialLogWriter",
    "collect_provenance",
    "decode_trial",
    "logged_trials",
    "read_run",
    "read_trials",
    "record_faults",
    "validate_file",
    "validate_run",
]
