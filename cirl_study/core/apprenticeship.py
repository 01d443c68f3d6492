"""The two-phase apprenticeship game of a batch of trials, as its players know it.

The game of the paper's Definition 2 (:mod:`cirl_study.theory.apprenticeship` poses it
exactly, for small games), here as the numerical models the gridworld study plays.

One object carries what a human or a robot may read (docs/design.md §1-3): the MaxEnt model
of the learning phase (its dynamics, the trials' features and the robot's :math:`\\lambda`),
the model of the deployment phase (the regret-optimal human plans for it), and, in a
pipeline with teaching players, the trials' hypothesis spaces and teaching settings; the
``gradient_ascent`` robot reads its own settings from it too, and the ``recorded`` human the
demonstrations her participants gave.
"""

from __future__ import annotations

from dataclasses import dataclass

from cirl_study.core.hypotheses import HypothesisSpace
from cirl_study.core.maxent import MaxEnt
from cirl_study.core.planning import FloatArray, IntArray
from cirl_study.record import GradientAscent, Teaching


@dataclass(frozen=True, eq=False)
class Apprenticeship:
    """A batch of ``B`` trials' game.

    Attributes:
        learning: the MaxEnt model of the learning phase, in which the human demonstrates.
        deployment: the MaxEnt model of the deployment phase, in which the robot acts alone.
        hypotheses: the trials' hypothesis spaces (``None`` without teaching players).
        teaching: the teaching settings the trials share (``None`` likewise).
        gradient_ascent: the settings of the ``gradient_ascent`` robot, for a batch it
            estimates (``None`` otherwise).
        recorded: ``(B, T + 1)`` the participants' demonstrations as paths of the learning
            phase (cell indices, padded with the sink after a goal), for a batch with trials
            of the ``recorded`` human (``None`` otherwise); a row of another human's trial is
            ``-1``.
    """

    learning: MaxEnt
    deployment: MaxEnt
    hypotheses: HypothesisSpace | None = None
    teaching: Teaching | None = None
    gradient_ascent: GradientAscent | None = None
    recorded: IntArray | None = None

    def take(self, rows: IntArray) -> Apprenticeship:
        """The game of the trials ``rows`` only (an index array)."""
        return Apprenticeship(
            self.learning.take(rows),
            self.deployment.take(rows),
            None if self.hypotheses is None else self.hypotheses.take(rows),
            self.teaching,
            self.gradient_ascent,
            None if self.recorded is None else self.recorded[rows],
        )

    def replayed(self) -> IntArray:
        """The participants' demonstrations; an error for a game without them."""
        if self.recorded is None:
            raise ValueError("this game has no recorded demonstrations: its trials have none")
        return self.recorded

    def space(self) -> HypothesisSpace:
        """The hypothesis spaces; an error for a game without them."""
        if self.hypotheses is None:
            raise ValueError("this game has no hypothesis space: its pipeline has no [teaching]")
        return self.hypotheses

    def settings(self) -> Teaching:
        """The teaching settings; an error for a game without them."""
        if self.teaching is None:
            raise ValueError("this game has no teaching settings: its pipeline has no [teaching]")
        return self.teaching

    def ascent(self) -> GradientAscent:
        """The ``gradient_ascent`` robot's settings; an error for a game without them."""
        if self.gradient_ascent is None:
            raise ValueError("this game has no gradient_ascent settings")
        return self.gradient_ascent


@dataclass(frozen=True)
class Outcome:
    """What a batch of ``B`` played trials is measured on (every measure of
    :data:`cirl_study.measure_registry.MEASURES`).

    Attributes:
        game: the batch's two-phase game: the deployment phase's MaxEnt model, the trials'
            features ``(B, S, K)`` and the robot's rationality.
        theta: the true reward weights, ``(B, K)``.
        theta_hat: the robot's estimates, ``(B, K)``.
    """

    game: Apprenticeship
    theta: FloatArray
    theta_hat: FloatArray
