"""The study's results: every number of a report, as typed records built from the trial table.

- :mod:`~cirl_study.analysis.results.types`: the records of ``results.json`` (a study's, a
  multiverse's, a calibration's), each table with ``to_frame()``, and their JSON Schemas.
- :mod:`~cirl_study.analysis.results.registry`: the per-measure tests of a study, each declared
  once (its computation, row type, heading and renderer).
- :mod:`~cirl_study.analysis.results.study`: every number of a study's report;
  :mod:`~cirl_study.analysis.results.per_measure`: each registered test for every measure;
  :mod:`~cirl_study.analysis.results.cells`: a design's factors and the cells a section or a
  claim needs; :mod:`~cirl_study.analysis.results.teaching`: the teaching sections.
- :mod:`~cirl_study.analysis.results.claims` and
  :mod:`~cirl_study.analysis.results.theory_claims`: the published claims as data, judged on
  the results.
"""
