"""Analysis of a run's trial records: statistics, results, claims, figures and the report.

Data flows one way: :mod:`~cirl_study.analysis.reading` reads, audits and selects a run's
trials (the one seam between the logs and the analysis); :mod:`~cirl_study.analysis.table`
makes them the tidy one-row-per-trial table; then, each a sub-package:

- :mod:`~cirl_study.analysis.statistics`: the statistical procedures;
- :mod:`~cirl_study.analysis.results`: every number of a study's report, typed, and the
  claims judged on them;
- :mod:`~cirl_study.analysis.report`: the report rendered and written, and reports compared;
- :mod:`~cirl_study.analysis.multiverse`: the paper's claims in every universe, and across them;
- :mod:`~cirl_study.analysis.calibration`: which universe made the published numbers.

One analysis serves every study, whatever its humans, robots and feature levels; a multiverse
is analysed universe by universe with it. The packages import nothing themselves, so that
importing one module (say the table) does not pay for the statistics libraries; the entry
points are :func:`cirl_study.analysis.report.study.write_report` and
:func:`cirl_study.analysis.multiverse.report.write_multiverse_report`.
"""
