"""A multiverse: the study played in every universe of its pipeline's open settings.

The paper leaves much of its game unstated; a pipeline fixes each open setting by argument.
A multiverse pipeline (``[multiverse]``, :func:`cirl_study.study.pipeline_file.parse_pipeline`)
names alternative levels of the settings :data:`~cirl_study.study.spec.AXES`, and the study (the
eta cross-validation and the ``main`` block's human x num_features design) is played in
every *universe*, one choice of every setting (Steegen, Tuerlinckx, Gelman & Vanpaemel 2016,
"Increasing transparency through a multiverse analysis"; Simonsohn, Simmons & Nelson 2020,
"Specification curve analysis").

A universe's pipeline (:func:`universe_pipeline`) is the multiverse's with the universe's
settings: the same root seed, the same run, the same subjects. A subject's stream draws its
centers and then ``theta`` whatever the placement (:func:`cirl_study.study.plan.draw_reward`),
so every universe sees the same ``theta`` for a subject, and the universes are compared on
common random numbers; a trial's seed is that of its id without the universe, so the base
universe's trials are those of the pipeline played as a single study.

The eta cross-validation of a universe is played by the base pipeline's robot, as in the
paper and the robots study: the human's teaching is tuned once, against the paper's learner,
and each robot then watches the same demonstrations. Universes that differ only in their
robot, in the measure their eta is chosen on, or in the feature levels whose eta they fix,
therefore share one cross-validation, that of their *cross-validation universe*
(:func:`cv_universe`): its trials are the same whatever is chosen from them. A universe that
fixes eta at every feature level has none.
"""

from __future__ import annotations

from dataclasses import replace

from cirl_study.study.spec import AXES, MultiverseSpec, Pipeline, Universe


def universes(pipeline: Pipeline) -> tuple[Universe, ...]:
    """The universes of a multiverse pipeline, its own settings (the base) first."""
    return _multiverse(pipeline).universes


def played_universes(pipeline: Pipeline) -> tuple[Universe, ...]:
    """The universes whose trials a multiverse plays, in the order of :func:`universes`: each
    universe's :attr:`~cirl_study.study.spec.Universe.played`, once."""
    return tuple(dict.fromkeys(u.played for u in universes(pipeline)))


def base_universe(pipeline: Pipeline) -> Universe:
    """The universe of a multiverse pipeline's own settings."""
    return _multiverse(pipeline).base


def _multiverse(pipeline: Pipeline) -> MultiverseSpec:
    if pipeline.multiverse is None:
        raise ValueError(f"pipeline {pipeline.name} is not a multiverse")
    return pipeline.multiverse


def universe_pipeline(pipeline: Pipeline, universe: Universe) -> Pipeline:
    """The single study of ``universe``: ``pipeline`` with its settings, each set by its axis
    (:attr:`~cirl_study.study.spec.Axis.apply`: ``sigma``, ``centers``,
    ``demonstrator_stays`` and ``deployment_start`` in ``game``, ``steps`` both horizons,
    ``rationality`` in ``main`` and ``eta_cv``, ``robot`` as ``main.robots``), and no
    multiverse; the run id stays the multiverse's, and ``universe`` is set.
    """
    study = pipeline
    for name, axis in AXES.items():
        study = axis.apply(study, getattr(universe, name))
    return replace(study, multiverse=None, universe=universe)


def cv_universe(pipeline: Pipeline, universe: Universe) -> Universe | None:
    """The universe whose cross-validation ``universe`` uses (:func:`tables_universe`);
    ``None`` where ``universe`` fixes eta at every feature level."""
    if not universe.cross_validates(pipeline.game.feature_levels):
        return None
    return tables_universe(pipeline, universe)


def tables_universe(pipeline: Pipeline, universe: Universe) -> Universe:
    """The universe ``universe`` plays with the base robot and that robot's settings, and its
    eta cross-validated at every feature level on the default measure (over its own grid):
    the cross-validation universe of a universe that cross-validates, and the settings a
    pipeline file of ``universe`` alone is written with (a calibration probe's,
    :mod:`cirl_study.study.probes`; a file's own universe fixes no eta)."""
    base = base_universe(pipeline)
    return replace(
        universe,
        robot=base.robot,
        ascent_steps=base.ascent_steps,
        learning_rate=base.learning_rate,
        eta=None,
        eta_measure=None,
    ).played
