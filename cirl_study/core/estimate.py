"""What a robot returns, and where its random numbers come from (docs/design.md §2).

Every robot of :data:`cirl_study.core.players.ROBOTS` is an :data:`Estimator`: given the
batch's game (:class:`~cirl_study.core.apprenticeship.Apprenticeship`, whose ``learning`` is
the MaxEnt model of the learning phase), the demonstrations and the trials' seeds, it returns
an :class:`Estimate` per trial.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cirl_study.core.apprenticeship import Apprenticeship
from cirl_study.core.planning import FloatArray, IntArray


@dataclass(frozen=True)
class Estimate:
    """A robot's estimates for a batch of demonstrations.

    Attributes:
        theta_hat: ``(B, K)`` estimated reward weights, in the box :math:`[-1, 1]^K` for every
            robot but ``gradient_ascent``.
        log_likelihood: ``(B,)`` :math:`\\log P(\\tau_{demo} \\mid \\hat\\theta, \\lambda)`.
        iterations: ``(B,)`` iterations of the estimator.
        converged: ``(B,)`` whether the estimator met its stopping rule.
        theta_hat_se: ``(B, K)`` Monte-Carlo standard error of each coordinate, for a robot
            whose estimate is random (else ``None``).
        effective_sample_size: ``(B,)`` the Monte-Carlo effective sample size (else ``None``).
    """

    theta_hat: FloatArray
    log_likelihood: FloatArray
    iterations: NDArray[np.int64]
    converged: NDArray[np.bool_]
    theta_hat_se: FloatArray | None = None
    effective_sample_size: FloatArray | None = None


Estimator = Callable[[Apprenticeship, IntArray, NDArray[np.int64]], Estimate]
"""A robot: ``estimate(game, demos, seeds)`` for the batch of ``game``'s trials.

``demos`` ``(B, T + 1)`` are the demonstrations' cells (``game.learning.path_counts(demos)``
their feature counts).

``seeds`` ``(B,)`` are the trials' own seeds (:attr:`cirl_study.record.TrialSpec.seed`); a
robot that draws random numbers derives its generator from them with
:func:`robot_generator`, so its estimate depends on its trial alone.
"""

ROBOT_STREAM = 1
"""Spawn key that separates a robot's random stream from the trial's other uses of its seed."""


def robot_generator(seed: int) -> np.random.Generator:
    """The random generator of the robot of the trial with ``seed``."""
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(ROBOT_STREAM,)))
