"""The ``gradient_ascent`` robot: Ziebart et al.'s MaxEnt IRL as it is usually coded, no box
(docs/design.md §2).

From :math:`\\theta_0 = 0`, a fixed number ``N`` of gradient steps of size :math:`\\alpha` on
the demonstration's log-likelihood :math:`L(\\theta) = \\lambda \\theta^\\top
\\phi(\\tau_{demo}) - \\log Z(\\theta)` under the MaxEnt trajectory model of the learning phase
(:class:`cirl_study.core.maxent.MaxEnt`):

.. math::

    \\theta_{i+1} = \\theta_i + \\alpha \\lambda\\, \\big(\\phi(\\tau_{demo}) -
    E_{\\theta_i}[\\phi(\\tau)]\\big), \\qquad i = 0, \\dots, N - 1, \\qquad
    \\hat\\theta = \\theta_N.

No prior bounds :math:`\\hat\\theta`: for an expert, whose demonstration is the path of
largest reward, the likelihood grows without bound along a direction and
:math:`\\|\\hat\\theta\\|` grows with the step budget. Since every feature lies in ``(0, 1]``,
each step moves a weight by at most :math:`\\alpha \\lambda T`, so :math:`\\|\\theta_N\\|_\\infty
\\le N \\alpha \\lambda T` and every scaled path reward is at most :math:`N \\alpha \\lambda^2 K
T^2` in magnitude: finite for every setting a pipeline admits, and the soft value iteration,
in log space with its largest term factored out, stays finite there.

The gradient is computed without cancellation, as the MAP robot's
(:func:`cirl_study.core.robot.map_estimate`): the ``m`` paths of the demonstration's count
class (:meth:`~cirl_study.core.maxent.MaxEnt.demonstration_classes`) have
:math:`\\Delta_\\tau = \\phi(\\tau) - \\phi(\\tau_{demo}) = 0`, so with :math:`R`, the mass of
all other paths, and :math:`q` the model restricted to them
(:class:`~cirl_study.core.maxent.OffDemonstration`),

.. math::

    \\phi(\\tau_{demo}) - E_\\theta[\\phi(\\tau)] = -\\frac{R}{m + R}\\, E_q[\\Delta],
    \\qquad L(\\theta) = -\\log(m + R).

The difference on the left, formed from :math:`E_\\theta[\\phi]`, is lost to rounding once the
demonstration's class holds all but a sliver of the mass; the product on the right is exact
to its last bits there too. The estimate is a deterministic function of the trial.

How far rounding carries: :math:`-L` is smooth with constant :math:`\\lambda^2 \\max
\\operatorname{eig} \\mathrm{Cov}_\\theta[\\phi(\\tau)] \\le \\lambda^2 K T^2 / 4` (each count
lies in ``[0, T]``), so for :math:`\\alpha < 8 / (\\lambda^2 K T^2)` every step is an ascent
and the step map :math:`\\theta \\mapsto \\theta + \\alpha \\nabla L` is non-expansive: the
rounding of each step is not amplified by the later ones, and :math:`\\hat\\theta` is exact
gradient ascent's to about ``N`` roundings. That bound is sufficient, not necessary. Where
the steps overshoot, the iterate may oscillate and amplify each step's rounding by the product
of the step maps' Jacobians :math:`I - \\alpha \\lambda^2 \\mathrm{Cov}_{\\theta_i}`; it stays
finite and within the bound above, and the moments are sums in a fixed order, so it depends on
the CPU only through the last bits of ``exp`` and ``log``, but it is then only as near exact
gradient ascent as that product allows.
"""

from __future__ import annotations

import numpy as np

from cirl_study.core.apprenticeship import Apprenticeship
from cirl_study.core.estimate import Estimate
from cirl_study.core.maxent import MaxEnt
from cirl_study.core.planning import FloatArray, IntArray


def gradient_ascent_estimate(
    model: MaxEnt, demos: IntArray, steps: int, learning_rate: float
) -> Estimate:
    """:math:`\\theta_N` of ``steps`` gradient steps of size ``learning_rate`` from
    :math:`\\theta_0 = 0`, for a batch of demonstrations (see the module docstring).

    Args:
        model: the MaxEnt model of the learning phase for the batch.
        demos: ``(B, T + 1)`` the demonstrations' cells :math:`s_0 .. s_T`.
        steps: the number of steps ``N >= 1``.
        learning_rate: the step size :math:`\\alpha > 0`.

    Returns:
        An :class:`Estimate`: ``log_likelihood`` is :math:`L(\\hat\\theta)`, ``iterations``
        is ``N`` and ``converged`` true (the stopping rule is the step budget).

    Examples:
        >>> import numpy as np
        >>> from cirl_study.core.gridworld import Gridworld, rbf_features
        >>> from cirl_study.core.maxent import MaxEnt, Phase
        >>> grid = Gridworld(3, 3)
        >>> phi = rbf_features(grid, [[0.0, 0.0], [2.0, 2.0]], 1.0)[None]
        >>> demo = [grid.index(1, 1), grid.index(2, 1), grid.index(2, 2), grid.index(2, 2)]
        >>> model = MaxEnt(Phase(grid.successors, grid.index(1, 1), 3), phi, 1.0)
        >>> fit = gradient_ascent_estimate(model, np.array([demo]), 200, 0.5)
        >>> bool(fit.theta_hat[0, 1] > 1.0 > 0.0 > fit.theta_hat[0, 0])
        True
    """
    demos = np.asarray(demos, dtype=np.int64)
    classes = model.demonstration_classes(demos)
    log_members = np.log(classes.members)
    theta = np.zeros((model.batch, model.features.shape[2]))
    size = learning_rate * model.rationality
    for _ in range(steps):
        off = model.off_demonstration(theta, classes, moments=1)
        theta = theta + size * _ascent(off.log_mass, log_members, off.mean)
    log_mass = model.off_demonstration(theta, classes, moments=0).log_mass
    log_likelihood = -np.logaddexp(log_members, log_mass)
    return Estimate(
        theta,
        log_likelihood,
        np.full(model.batch, steps, dtype=np.int64),
        np.ones(model.batch, dtype=bool),
    )


def _ascent(log_mass: FloatArray, log_members: FloatArray, mean: FloatArray) -> FloatArray:
    """``(B, K)`` :math:`\\phi(\\tau_{demo}) - E_\\theta[\\phi] = -\\frac{R}{m + R} E_q[\\Delta]`
    from :math:`\\log R`, :math:`\\log m` and :math:`E_q[\\Delta]` (zero where no path leaves
    the class: :math:`R = 0`)."""
    share = np.exp(log_mass - np.logaddexp(log_members, log_mass))
    return -share[:, None] * mean


def estimate(game: Apprenticeship, demos: IntArray, _seeds: IntArray) -> Estimate:
    """The robot's :data:`~cirl_study.core.estimate.Estimator`: the game's learning phase and
    its ``gradient_ascent`` settings."""
    settings = game.ascent()
    return gradient_ascent_estimate(game.learning, demos, settings.steps, settings.learning_rate)
