"""Reports: the results rendered as ``report.md``, the figures and the tables, written into a
report directory that replaces the old one whole, and two reports compared by value.

- :mod:`~cirl_study.analysis.report.study`: a study's report; its sections in
  :mod:`~cirl_study.analysis.report.study_sections`,
  :mod:`~cirl_study.analysis.report.paper_sections` and
  :mod:`~cirl_study.analysis.report.teaching_sections`, their headings in
  :mod:`~cirl_study.analysis.report.sections`, Markdown helpers in
  :mod:`~cirl_study.analysis.report.markdown`.
- :mod:`~cirl_study.analysis.report.figures`: the figures, as deterministic PNG and SVG.
- :mod:`~cirl_study.analysis.report.output` writes a report directory;
  :mod:`~cirl_study.analysis.report.replacement` replaces one atomically, by one writer, never
  over a run; :mod:`~cirl_study.analysis.report.compare` compares two by value.
"""
