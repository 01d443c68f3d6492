"""A study: the pipeline file, its planned trials, and playing them into a run directory.

- :mod:`~cirl_study.study.spec`: the pipeline file, parsed and validated.
- :mod:`~cirl_study.study.plan`: trial identities, seeds, reward draws, the eta choice.
- :mod:`~cirl_study.study.engines`: where trials are played (this process, a pool, Dask).
- :mod:`~cirl_study.study.runner`: plays a plan on an engine into MCAP logs, resumably.
- :mod:`~cirl_study.study.audit`: a run's logged trials against its plan (missing, foreign).
"""
