"""Feature order agreement: whether the robot learned which features are better than which.

A measure that needs no scale (docs/design.md §4): it compares only the orders of
:math:`\\theta` and :math:`\\hat\\theta`, so it is the same for :math:`\\hat\\theta` and any
strictly increasing transform of it. Over the pairs :math:`P = \\{(i, j) : i < j,
\\theta_i \\ne \\theta_j\\}`, the fraction that :math:`\\hat\\theta` orders as :math:`\\theta`
does, a pair :math:`\\hat\\theta` ties counting one half:

.. math::

    A(\\theta, \\hat\\theta) = \\frac{1}{|P|} \\sum_{(i, j) \\in P}
    \\frac{1 + \\operatorname{sgn}(\\theta_i - \\theta_j)
    \\operatorname{sgn}(\\hat\\theta_i - \\hat\\theta_j)}{2},

a concordance in :math:`[0, 1]`: 1 when :math:`\\hat\\theta` orders every such pair as
:math:`\\theta`, 0 when it reverses every one, and undefined (``None``) where :math:`P` is empty
(one feature, or every weight equal). Higher is better. It is computed exactly: the sum counts
halves, so it is an integer over :math:`2 |P|`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from cirl_study.core.apprenticeship import Outcome
    from cirl_study.core.planning import FloatArray


def order_agreement(outcome: Outcome) -> list[float | None]:
    """:func:`agreement` of a played batch: the registry's ``order_agreement``."""
    return agreement(outcome.theta, outcome.theta_hat)


def agreement(theta: FloatArray, theta_hat: FloatArray) -> list[float | None]:
    """:math:`A(\\theta_b, \\hat\\theta_b)` of each row ``b`` of ``theta`` and ``theta_hat``
    (``(B, K)`` each; see the module docstring), ``None`` where ``theta_b`` has no two
    different weights.

    Examples:
        >>> agreement(np.array([[0.1, 0.5, -0.3], [0.2, 0.2, 0.7], [0.4, 0.4, 0.4]]),
        ...           np.array([[0.2, 0.1, 0.0], [0.9, 0.1, 0.1], [1.0, 0.0, -1.0]]))
        [0.6666666666666666, 0.25, None]
    """
    theta, theta_hat = np.asarray(theta, dtype=np.float64), np.asarray(theta_hat, dtype=np.float64)
    first, second = np.triu_indices(theta.shape[1], k=1)
    order = np.sign(theta[:, first] - theta[:, second])
    order_hat = np.sign(theta_hat[:, first] - theta_hat[:, second])
    pairs = np.count_nonzero(order, axis=1)
    halves = np.sum(np.abs(order) * (1.0 + order * order_hat), axis=1)
    return [
        None if count == 0 else float(half / (2 * count))
        for half, count in zip(halves, pairs, strict=True)
    ]
