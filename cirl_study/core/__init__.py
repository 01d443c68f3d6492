"""The numerical core: one trial of the two-phase apprenticeship game, exactly.

- :mod:`~cirl_study.core.gridworld`: the grid, its moves and the RBF features.
- :mod:`~cirl_study.core.planning`: batched soft and hard finite-horizon planning (compiled).
- :mod:`~cirl_study.core.maxent`: the MaxEnt trajectory model of a phase (the problem object).
- :mod:`~cirl_study.core.apprenticeship`: a batch's two-phase game, as its players know it.
- :mod:`~cirl_study.core.estimate`: what a robot returns, and its random stream.
- :mod:`~cirl_study.core.robot`: the MAP robot.
- :mod:`~cirl_study.core.posterior`: the posterior-mean robot (Monte Carlo).
- :mod:`~cirl_study.core.path_search`: the exact nearest-feature-count path search.
- :mod:`~cirl_study.core.humans`: the paper's humans, and the literal demonstrator.
- :mod:`~cirl_study.core.hypotheses`: a finite hypothesis space; literal and pedagogic models.
- :mod:`~cirl_study.core.teaching`: the teaching humans and the robots that read them.
- :mod:`~cirl_study.core.players`: every human and robot by name.
- :mod:`~cirl_study.measure_registry`: every measure by name.
- :mod:`~cirl_study.core.measures`: regret, trajectory KL and reward L2.
- :mod:`~cirl_study.core.order_agreement`: the feature order agreement.
- :mod:`~cirl_study.core.trial`: a batch of trial specs played into trial records.
"""
