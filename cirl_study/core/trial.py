"""One trial of the study: the whole two-phase apprenticeship game (docs/design.md §1-4, §7).

A trial (:class:`~cirl_study.record.TrialSpec`) fixes a gridworld, RBF features, the true
reward weights :math:`\\theta`, the robot's rationality :math:`\\lambda`, the human's policy
(with its trade-off :math:`\\eta` where it has one), the robot and the two horizons. It plays:

1. **Learning phase.** The human demonstrates a ``learning_steps`` path from the fixed start
   cell (:data:`cirl_study.core.humans.HUMANS`), without the ``stay`` action unless
   ``demonstrator_stays``; the robot's model of the phase has the same moves.
2. **Inference.** The robot estimates :math:`\\hat\\theta` from the demonstration
   (:data:`cirl_study.core.robot.ROBOTS`).
3. **Deployment phase.** The robot acts optimally for :math:`r_{\\hat\\theta}` for
   ``deployment_steps`` steps from a uniformly drawn start (``deployment_start =
   "uniform"``; the measures take the exact expectation over that start,
   :mod:`cirl_study.core.measures`) or from the learning phase's start.

:func:`play_trials` plays many trials at once, vectorised over trials that share the game's
shape, rationality, policy and robot, and returns one :class:`~cirl_study.record.TrialRecord`
per trial. A record depends only on its own spec, never on the other trials in the batch.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Hashable, Sequence

import numpy as np

from cirl_study.core.gridworld import (
    ACTIONS,
    UNAVAILABLE,
    Gridworld,
    feature_matrix,
    gridworld,
    path_actions,
)
from cirl_study.core.humans import HUMANS
from cirl_study.core.maxent import MaxEnt, Phase
from cirl_study.core.measures import regret, reward_l2, trajectory_kl
from cirl_study.core.planning import follow_policy, optimal_plan
from cirl_study.core.robot import ROBOTS
from cirl_study.record import (
    Demonstration,
    Deployment,
    FitDiagnostics,
    Measures,
    TrialRecord,
    TrialSpec,
    validated,
)

DEPLOYMENT_ROLLOUTS = 4
"""Deployment start cells per trial whose robot paths are logged for replay."""


def check_playable(spec: TrialSpec) -> None:
    """Raise ``ValueError`` unless ``spec`` is well-typed, names a known policy and robot and
    fits its game."""
    validated(spec)
    human = HUMANS.get(spec.policy)
    if human is None:
        raise ValueError(f"unknown policy {spec.policy!r}; known: {', '.join(HUMANS)}")
    if spec.robot not in ROBOTS:
        raise ValueError(f"unknown robot {spec.robot!r}; known: {', '.join(ROBOTS)}")
    if (spec.eta is None) == human.takes_eta:
        raise ValueError(
            f"eta must be given exactly for a policy with a trade-off ({spec.policy}: "
            f"{'has' if human.takes_eta else 'has none'})"
        )
    if len(spec.theta) != spec.num_features or len(spec.features.centers) != spec.num_features:
        raise ValueError("theta and the feature centres must have num_features entries")
    gridworld(spec).index(*spec.start)


def _group_key(spec: TrialSpec) -> Hashable:
    return (
        spec.grid, spec.start, spec.learning_steps, spec.deployment_steps, spec.features.sigma,
        spec.num_features, spec.rationality, spec.policy, spec.robot, spec.demonstrator_stays,
        spec.deployment_start,
    )  # fmt: skip


def play_trials(specs: Sequence[TrialSpec]) -> list[TrialRecord]:
    """Play every trial and return their records, in the order given."""
    for spec in specs:
        check_playable(spec)
    groups: dict[Hashable, list[int]] = defaultdict(list)
    for position, spec in enumerate(specs):
        groups[_group_key(spec)].append(position)
    records: list[TrialRecord | None] = [None] * len(specs)
    for positions in groups.values():
        for position, record in zip(
            positions, _play_group([specs[p] for p in positions]), strict=True
        ):
            records[position] = record
    return records  # type: ignore[return-value]


def _play_group(specs: Sequence[TrialSpec]) -> list[TrialRecord]:
    """Play trials that share the game's shape, rationality, policy and robot, vectorised."""
    first = specs[0]
    grid = gridworld(first)
    theta = np.array([spec.theta for spec in specs], dtype=np.float64)
    features = np.stack([feature_matrix(spec) for spec in specs])
    start = grid.index(*first.start)
    learning = MaxEnt(
        Phase(demonstrator_moves(grid, first), start, first.learning_steps),
        features,
        first.rationality,
    )
    deployment_start = start if first.deployment_start == "demonstration" else None
    deployment = MaxEnt(
        Phase(grid.successors, deployment_start, first.deployment_steps),
        features,
        first.rationality,
    )

    human = HUMANS[first.policy]
    eta = np.array([spec.eta for spec in specs], dtype=np.float64) if human.takes_eta else None
    seeds = np.array([spec.seed for spec in specs], dtype=np.int64)
    demos = human.demonstrate(learning, theta, eta, seeds)
    estimate = ROBOTS[first.robot](learning, demos, seeds)
    theta_hat = estimate.theta_hat
    measures = {
        "regret": regret(deployment, theta, theta_hat),
        "kl": trajectory_kl(deployment, theta, theta_hat),
        "reward_l2": reward_l2(features, theta, theta_hat),
    }
    robot_plan = optimal_plan(
        deployment.cell_rewards(theta_hat), grid.successors, first.deployment_steps
    )
    rollouts = _deployment_rollouts(grid, specs, deployment_start, robot_plan.actions)
    return [
        TrialRecord(
            **{name: getattr(spec, name) for name in TrialSpec.__struct_fields__},
            theta_hat=tuple(float(v) for v in theta_hat[b]),
            demonstration=Demonstration(
                states=_cells(grid, demos[b]), actions=tuple(path_actions(grid, demos[b]))
            ),
            measures=Measures(**{name: float(values[b]) for name, values in measures.items()}),
            theta_hat_se=None
            if estimate.theta_hat_se is None
            else tuple(float(v) for v in estimate.theta_hat_se[b]),
            effective_sample_size=None
            if estimate.effective_sample_size is None
            else float(estimate.effective_sample_size[b]),
            irl=FitDiagnostics(
                log_likelihood=float(estimate.log_likelihood[b]),
                iterations=int(estimate.iterations[b]),
                converged=bool(estimate.converged[b]),
            ),
            deployment=Deployment(
                starts=tuple(grid.coords(path[b, 0]) for path in rollouts),
                paths=tuple(_cells(grid, path[b]) for path in rollouts),
            ),
        )
        for b, spec in enumerate(specs)
    ]


def demonstrator_moves(grid: Gridworld, spec: TrialSpec) -> np.ndarray:
    """The successor table of the learning phase: the grid's, less ``stay`` unless the human
    may stay (``spec.demonstrator_stays``)."""
    if spec.demonstrator_stays:
        return grid.successors
    moves = grid.successors.copy()
    moves[:, ACTIONS.index("stay")] = UNAVAILABLE
    return moves


def _cells(grid: Gridworld, path: np.ndarray) -> tuple[tuple[int, int], ...]:
    return tuple(grid.coords(s) for s in path)


def _deployment_rollouts(
    grid: Gridworld, specs: Sequence[TrialSpec], start: int | None, policy: np.ndarray
) -> list[np.ndarray]:
    """The robot's paths ``(B, T + 1)`` from each trial's own few replay start cells.

    The start cells are drawn from the trial's ``seed``, without replacement, when the
    deployment starts anywhere (``start`` is ``None``); else the one path from ``start``.
    """
    if start is not None:
        return [follow_policy(grid.successors, np.full(len(specs), start), policy)]
    starts = np.array(
        [
            np.random.default_rng(spec.seed).choice(
                grid.num_cells, size=min(DEPLOYMENT_ROLLOUTS, grid.num_cells), replace=False
            )
            for spec in specs
        ]
    )
    return [follow_policy(grid.successors, starts[:, i], policy) for i in range(starts.shape[1])]
