"""One trial of the study: the whole two-phase apprenticeship game (DESIGN §1-4, §7).

A trial fixes a gridworld, RBF features, the true reward weights :math:`\\theta`, the
robot's rationality :math:`\\lambda`, the human's policy (``expert`` or
``best_response`` with trade-off :math:`\\eta`) and the two horizons. It plays:

1. **Learning phase.** The human demonstrates a ``learning_steps`` path from the
   fixed start cell (:mod:`cirl_study.humans`).
2. **Inference.** The robot computes the MAP estimate :math:`\\hat\\theta` by MaxEnt IRL
   (:mod:`cirl_study.irl`).
3. **Deployment phase.** The robot acts optimally for :math:`r_{\\hat\\theta}` for
   ``deployment_steps`` steps from a uniformly drawn start; the measures take the
   exact expectation over that start (:mod:`cirl_study.measures`).

:func:`play_trials` plays many trials at once, vectorised over trials that share a
game setting, rationality and policy, and returns one record per trial in the log
format of DESIGN §7. A record depends only on its own :class:`TrialSpec`, never on
the other trials in the batch.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from cirl_study.gridworld import Gridworld, path_actions, rbf_features
from cirl_study.humans import best_response_paths, expert_paths, follow_policy
from cirl_study.irl import fit_maxent_irl
from cirl_study.measures import regret, reward_l2, trajectory_kl
from cirl_study.planning import optimal_plan

POLICIES = ("expert", "best_response")
"""The human policies: demonstration by expert, and the instructive best response."""

DEPLOYMENT_ROLLOUTS = 4
"""Deployment start cells per trial whose robot paths are logged for replay."""


@dataclass(frozen=True)
class GameSetting:
    """Everything about the game that is common knowledge, except the reward weights."""

    width: int
    height: int
    start: tuple[int, int]
    learning_steps: int
    deployment_steps: int
    centers: tuple[tuple[float, float], ...]
    sigma: float

    @property
    def grid(self) -> Gridworld:
        return Gridworld(self.width, self.height)


@dataclass(frozen=True)
class TrialSpec:
    """Identity and inputs of one trial (see DESIGN §7 for the meaning of each field)."""

    trial_id: str
    run_id: str
    block: str
    subject: str
    policy: str
    num_features: int
    rationality: float
    eta: float | None
    seed: int
    theta: tuple[float, ...]
    setting: GameSetting

    def __post_init__(self) -> None:
        if self.policy not in POLICIES:
            raise ValueError(f"unknown policy {self.policy!r}; expected one of {POLICIES}")
        if (self.eta is None) != (self.policy == "expert"):
            raise ValueError("eta must be given for best_response and only for it")
        if len(self.theta) != self.num_features or len(self.setting.centers) != self.num_features:
            raise ValueError("theta and centers must have num_features entries")


def _group_key(spec: TrialSpec) -> tuple[Any, ...]:
    s = spec.setting
    return (
        s.width, s.height, s.start, s.learning_steps, s.deployment_steps, s.sigma,
        spec.num_features, spec.rationality, spec.policy,
    )  # fmt: skip


def play_trials(specs: Sequence[TrialSpec]) -> list[dict[str, Any]]:
    """Play every trial and return their records (DESIGN §7), in the order given."""
    groups: dict[tuple[Any, ...], list[int]] = defaultdict(list)
    for position, spec in enumerate(specs):
        groups[_group_key(spec)].append(position)
    records: list[dict[str, Any] | None] = [None] * len(specs)
    for positions in groups.values():
        for position, record in zip(
            positions, _play_group([specs[p] for p in positions]), strict=True
        ):
            records[position] = record
    return records  # type: ignore[return-value]


def _play_group(specs: Sequence[TrialSpec]) -> list[dict[str, Any]]:
    """Play trials that share a setting shape, rationality and policy, vectorised."""
    first = specs[0]
    setting, rationality = first.setting, first.rationality
    grid = setting.grid
    successors = grid.successors
    start = grid.index(*setting.start)
    theta = np.array([spec.theta for spec in specs], dtype=np.float64)
    centers = np.array([spec.setting.centers for spec in specs], dtype=np.float64)
    features = rbf_features(grid, centers, setting.sigma)

    if first.policy == "expert":
        demos = expert_paths(theta, features, successors, start, setting.learning_steps)
    else:
        eta = np.array([spec.eta for spec in specs], dtype=np.float64)
        demos = best_response_paths(
            theta, eta, features, successors, start, setting.learning_steps, rationality
        )
    rows = np.arange(len(specs))[:, None]
    demo_counts = features[rows, demos[:, 1:]].sum(axis=1)
    fit = fit_maxent_irl(
        demo_counts, features, successors, start, setting.learning_steps, rationality
    )
    horizon = setting.deployment_steps
    measures = {
        "regret": regret(theta, fit.theta_hat, features, successors, horizon),
        "kl": trajectory_kl(theta, fit.theta_hat, features, successors, horizon, rationality),
        "reward_l2": reward_l2(theta, fit.theta_hat, features),
    }
    robot = optimal_plan(np.einsum("bsk,bk->bs", features, fit.theta_hat), successors, horizon)
    deployment_starts = np.array(
        [
            np.random.default_rng(spec.seed).choice(
                grid.num_cells, size=min(DEPLOYMENT_ROLLOUTS, grid.num_cells), replace=False
            )
            for spec in specs
        ]
    )
    rollouts = [
        follow_policy(successors, deployment_starts[:, i], robot.actions)
        for i in range(deployment_starts.shape[1])
    ]
    records = []
    for b, spec in enumerate(specs):
        cells = [list(grid.coords(s)) for s in demos[b]]
        actions = path_actions(grid, demos[b])
        records.append(
            {
                "trial_id": spec.trial_id,
                "run_id": spec.run_id,
                "block": spec.block,
                "subject": spec.subject,
                "policy": spec.policy,
                "num_features": spec.num_features,
                "rationality": float(spec.rationality),
                "eta": None if spec.eta is None else float(spec.eta),
                "seed": int(spec.seed),
                "grid": {"width": setting.width, "height": setting.height},
                "start": list(setting.start),
                "learning_steps": setting.learning_steps,
                "deployment_steps": setting.deployment_steps,
                "features": {
                    "kind": "rbf",
                    "centers": [list(map(float, c)) for c in spec.setting.centers],
                    "sigma": float(setting.sigma),
                },
                "theta": [float(v) for v in theta[b]],
                "theta_hat": [float(v) for v in fit.theta_hat[b]],
                "demonstration": {"states": cells, "actions": actions},
                "measures": {name: float(values[b]) for name, values in measures.items()},
                "irl": {
                    "log_likelihood": float(fit.log_likelihood[b]),
                    "iterations": int(fit.iterations[b]),
                    "converged": bool(fit.converged[b]),
                },
                "deployment": {
                    "starts": [list(grid.coords(r[b, 0])) for r in rollouts],
                    "paths": [[list(grid.coords(s)) for s in r[b]] for r in rollouts],
                },
            }
        )
    return records
