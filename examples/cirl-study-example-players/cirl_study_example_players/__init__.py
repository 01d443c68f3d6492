"""Two players of one's own for cirl-study, found through the ``cirl_study.players`` entry
points of this package's ``pyproject.toml``: no edit to cirl-study.

* ``first_step_only``, a human who takes the expert's first step and then stays put: she shows
  where the reward is, and nothing more.
* ``theta_zero``, a robot that ignores the demonstration and acts on the prior mean of the
  reward, ``theta_hat = 0``: the floor any robot that learns should beat.
"""

from __future__ import annotations

import numpy as np

from cirl_study.core.apprenticeship import Apprenticeship
from cirl_study.core.estimate import Estimate
from cirl_study.core.players import HUMANS, Human, Robot


def first_step(
    game: Apprenticeship, theta: np.ndarray, eta: np.ndarray | None, seeds: np.ndarray
) -> np.ndarray:
    """The ``(B, T + 1)`` paths: the expert's first move from the start, then ``stay``."""
    expert = HUMANS["expert"].demonstrate(game, theta, eta, seeds)
    return np.concatenate([expert[:, :1], np.repeat(expert[:, 1:2], expert.shape[1] - 1, 1)], 1)


def prior_mean(game: Apprenticeship, demos: np.ndarray, seeds: np.ndarray) -> Estimate:
    """``theta_hat = 0`` for every trial, with its log-likelihood under the robot's model."""
    model = game.learning
    theta_hat = np.zeros((len(demos), model.features.shape[2]))
    return Estimate(
        theta_hat=theta_hat,
        log_likelihood=model.log_likelihood(theta_hat, model.path_counts(demos)),
        iterations=np.zeros(len(demos), dtype=np.int64),
        converged=np.ones(len(demos), dtype=bool),
    )


FIRST_STEP_ONLY = Human(first_step, takes_eta=False)
THETA_ZERO = Robot(prior_mean)
