"""Which universe made the published numbers: a run's universes ranked by their distance to a
target table (:mod:`~cirl_study.analysis.calibration.results`), the refinement of the nearest
(:mod:`~cirl_study.analysis.calibration.refine`), and the calibration's report
(:mod:`~cirl_study.analysis.calibration.report`)."""
