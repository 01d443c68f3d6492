"""MCAP logs of the study: writing, reading and validating (docs/design.md §6-7).

The log format is described in ``docs/log-format.md`` and :mod:`cirl_study.logs.format`; the
trial record it carries is :class:`cirl_study.record.TrialRecord`. Writing is
:mod:`~cirl_study.logs.writer`, reading a run :mod:`~cirl_study.logs.reader`, checking every
record :mod:`~cirl_study.logs.record_checks` and every file :mod:`~cirl_study.logs.validate`;
a run's identity and provenance are :mod:`~cirl_study.logs.provenance`. Import each from its
module: this package loads none of them, so that a command loads only what it uses (the
reader, without the writer and its dependencies).
"""
