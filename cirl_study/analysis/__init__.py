"""Analysis of a run's trial records: statistics, claims, figures and the report.

Everything here works on the typed trial records of docs/design.md §7
(:class:`cirl_study.record.TrialRecord`, one per trial). Reading them from the MCAP logs
is the job of :mod:`cirl_study.logs`.

- :mod:`~cirl_study.analysis.table`: the tidy one-row-per-trial table and the design check.
- :mod:`~cirl_study.analysis.statistics`: one function per statistical test.
- :mod:`~cirl_study.analysis.results`: every number of the report, as JSON-ready data.
- :mod:`~cirl_study.analysis.claims`: the paper's claims beside our measurements.
- :mod:`~cirl_study.analysis.figures`: the figures, as deterministic PNG bytes.
- :mod:`~cirl_study.analysis.report`: ``report.md``, ``results.json``, ``trials.csv``.
- :mod:`~cirl_study.analysis.multiverse`, :mod:`~cirl_study.analysis.multiverse_report`: the
  paper's claims in every universe of a multiverse, and across them.
- :mod:`~cirl_study.analysis.anova`: the repeated-measures ANOVA of any factorial design, with
  its sphericity corrections; :mod:`~cirl_study.analysis.tails`: F and t tails in log space.
- :mod:`~cirl_study.analysis.study`, :mod:`~cirl_study.analysis.study_report`: a study of
  any humans x robots x feature levels other than the paper's own design, with its questions
  (among them pedagogic and literal humans, pragmatic and literal robots).

The package itself imports nothing, so that importing one module (say the table) does
not pay for the statistics libraries; the entry points are
:func:`cirl_study.analysis.report.write_report`,
:func:`cirl_study.analysis.multiverse_report.write_multiverse_report` and
:func:`cirl_study.analysis.study_report.write_study_report`.
"""
