"""Analysis of a run's trial records: statistics, claims, figures and the report.

Everything here works on the typed trial records of docs/design.md §7
(:class:`cirl_study.record.TrialRecord`, one per trial). Reading them from the MCAP logs
is the job of :mod:`cirl_study.logs`. One analysis serves every study, whatever its humans,
robots and feature levels; a multiverse is analysed universe by universe with it.

- :mod:`~cirl_study.analysis.table`: the tidy one-row-per-trial table and the design check.
- :mod:`~cirl_study.analysis.cells`: a design's factors, and the cells a section or a claim
  needs.
- :mod:`~cirl_study.analysis.statistics`: one function per statistical test;
  :mod:`~cirl_study.analysis.anova`: the repeated-measures ANOVA of any factorial design,
  with its sphericity corrections; :mod:`~cirl_study.analysis.tails` and
  :mod:`~cirl_study.analysis.studentized_range`: p-values in log space.
- :mod:`~cirl_study.analysis.result_types`: the typed records of the results (and of
  ``results.json``), every table a ``Table`` with ``to_frame()``;
  :mod:`~cirl_study.analysis.study_tests`: the per-measure tests, each registered by the field
  that holds its rows; :mod:`~cirl_study.analysis.measure_rows`: their computations, for every
  measure.
- :mod:`~cirl_study.analysis.results`: every number of a study's report, built as its typed
  record; :mod:`~cirl_study.analysis.teaching`: its teaching sections.
- :mod:`~cirl_study.analysis.claims`: the published claims as data, judged on the results.
- :mod:`~cirl_study.analysis.figures`: the figures, as deterministic PNG bytes.
- :mod:`~cirl_study.analysis.report`: ``report.md``, ``results.json``, ``trials.csv``, with
  its sections in :mod:`~cirl_study.analysis.study_report`,
  :mod:`~cirl_study.analysis.paper_report` and :mod:`~cirl_study.analysis.teaching_report`
  (their headings: :mod:`~cirl_study.analysis.sections`).
- :mod:`~cirl_study.analysis.multiverse`, :mod:`~cirl_study.analysis.multiverse_report`: the
  paper's claims in every universe of a multiverse, and across them.

The package itself imports nothing, so that importing one module (say the table) does
not pay for the statistics libraries; the entry points are
:func:`cirl_study.analysis.report.write_report` and
:func:`cirl_study.analysis.multiverse_report.write_multiverse_report`.
"""
