"""A multiverse's analysis: the paper's claims in every universe
(:mod:`~cirl_study.analysis.multiverse.results`), and its report
(:mod:`~cirl_study.analysis.multiverse.report`)."""
