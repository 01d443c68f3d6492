"""The statistics, each a function of a tidy frame returning typed rows, checked against R and
high-precision references (docs/design.md §5).

- :mod:`~cirl_study.analysis.statistics.anova`: the mixed repeated-measures ANOVA of any
  factorial design, with Mauchly's test and the Greenhouse-Geisser and Huynh-Feldt corrections.
- :mod:`~cirl_study.analysis.statistics.procedures`: one function per further procedure
  (paired and pairwise differences with Holm, Tukey HSD, Wilcoxon, Cronbach's alpha, the
  bootstrap of ``d_z``, the joint sign-flip test).
- :mod:`~cirl_study.analysis.statistics.tails` and
  :mod:`~cirl_study.analysis.statistics.studentized_range`: p-values in log space, exact far
  into the tails.
"""
