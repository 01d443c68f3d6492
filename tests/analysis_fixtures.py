"""Synthetic trial records (docs/design.md §7), for the analysis tests.

The measures are drawn, not computed from a game: they only need the structure the
analysis relies on (paired subjects, unique subject ids across feature levels, a
human effect, a lambda curve with an interior minimum, an eta curve with a known
minimum). Everything is a deterministic function of the arguments. Each record is built
as plain data and validated into a :class:`~cirl_study.record.TrialRecord`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from cirl_study.core.gridworld import Gridworld, rbf_features
from cirl_study.core.order_agreement import agreement
from cirl_study.record import BEST_RESPONSE, PAPER_HUMANS, TrialRecord, TrialRow, from_builtins
from cirl_study.study.pipeline_file import parse_pipeline
from cirl_study.study.spec import Pipeline

SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"

WIDTH, HEIGHT, START, STEPS, SIGMA = 6, 5, (3, 2), 4, 1.5
MOVES = {"N": (0, 1), "S": (0, -1), "E": (1, 0), "W": (-1, 0)}


def _walk(rng: np.random.Generator) -> dict[str, list]:
    """A random ``STEPS``-move path from ``START`` that never leaves the grid."""
    states, actions = [list(START)], []
    while len(actions) < STEPS:
        name = str(rng.choice(sorted(MOVES)))
        dx, dy = MOVES[name]
        x, y = states[-1][0] + dx, states[-1][1] + dy
        if 0 <= x < WIDTH and 0 <= y < HEIGHT:
            states.append([x, y])
            actions.append(name)
    return {"states": states, "actions": actions}


def _centers(rng: np.random.Generator, count: int) -> list[list[float]]:
    """``count`` RBF centers drawn uniformly over the grid."""
    return [
        [float(rng.uniform(0, WIDTH - 1)), float(rng.uniform(0, HEIGHT - 1))] for _ in range(count)
    ]


def _reward_l2(theta: np.ndarray, theta_hat: np.ndarray, centers: list[list[float]]) -> float:
    """``||Phi theta - Phi theta_hat||_2`` over every cell, ``Phi`` the RBF feature matrix."""
    phi = rbf_features(Gridworld(WIDTH, HEIGHT), centers, SIGMA)
    return float(np.linalg.norm(phi @ (theta - theta_hat)))


def _record(
    rng: np.random.Generator,
    *,
    block: str,
    subject: str,
    human: str,
    num_features: int,
    rationality: float,
    eta: float | None,
    theta: list[float],
    centers: list[list[float]],
    scale: float,
) -> TrialRecord:
    """One trial whose losses grow with ``scale``: regret and KL drawn around it, theta_hat
    off theta by noise of that size, reward_l2 and order_agreement computed from theta and
    theta_hat."""
    eta_part = "none" if eta is None else f"{eta:g}"
    theta_hat = np.clip(np.asarray(theta) + rng.normal(0, 0.3 * scale, len(theta)), -1, 1)
    return from_builtins(
        {
            "trial_id": f"{block}/{subject}/{human}/lambda={rationality:g}/eta={eta_part}",
            "run_id": "synthetic-run",
            "block": block,
            "subject": subject,
            "human": human,
            "num_features": num_features,
            "rationality": rationality,
            "eta": eta,
            "seed": int(rng.integers(0, 2**32)),
            "grid": {"width": WIDTH, "height": HEIGHT},
            "start": list(START),
            "learning_steps": STEPS,
            "deployment_steps": STEPS,
            "features": {"kind": "rbf", "centers": centers, "sigma": SIGMA},
            "theta": theta,
            "theta_hat": [float(v) for v in theta_hat],
            "demonstration": _walk(rng),
            "measures": {
                "regret": (regret := scale * float(np.exp(rng.normal(0, 0.3)))),
                "kl": 2.7 * scale * float(np.exp(rng.normal(0, 0.3))),
                "reward_l2": _reward_l2(np.asarray(theta), theta_hat, centers),
                "regret_under_estimate": 1.5 * regret,
                "order_agreement": agreement([theta], [theta_hat])[0],
            },
        }
    )


def synthetic_records(
    subjects_per_level: int = 12,
    levels: tuple[int, ...] = (3, 10),
    seed: int = 0,
    lambdas: tuple[float, ...] = (1e-2, 1.0, 1e2),
    etas: tuple[float, ...] = (0.1, 1.0, 10.0),
    cv_subjects: int = 4,
    human_effect: float = 0.8,
) -> list[TrialRecord]:
    """Records of a small study: ``main``, ``lambda_sweep`` and ``eta_cv`` blocks.

    The records pass the log format's consistency checks, so they can be written to MCAP.

    Args:
        subjects_per_level: reward draws per feature level in ``main`` (and the sweep).
        levels: the feature levels.
        seed: seed of every random draw.
        lambdas: the sweep's rationalities; every loss is lowest at lambda = 1.
        etas: the cross-validation grid; every loss is lowest at eta = 1.
        cv_subjects: reward draws per feature level in ``eta_cv`` (disjoint ids).
        human_effect: log-ratio by which the best response lowers every loss; the gap is
            1.5 times larger at the smallest feature level.
    """
    rng = np.random.default_rng(seed)
    records: list[TrialRecord] = []
    for level in levels:
        gap = human_effect * (1.5 if level == min(levels) else 1.0)
        for index in range(subjects_per_level):
            subject = f"k{level}-s{index:03d}"
            theta = [float(v) for v in rng.uniform(-1, 1, level)]
            centers = _centers(rng, level)
            base = rng.normal(0, 0.5)
            for human in PAPER_HUMANS:
                best = human == BEST_RESPONSE
                common = dict(
                    subject=subject,
                    human=human,
                    num_features=level,
                    eta=1.0 if best else None,
                    theta=theta,
                    centers=centers,
                )
                factor = math.exp(base - gap * best)
                records.append(_record(rng, block="main", rationality=1.0, scale=factor, **common))
                for rationality in lambdas:
                    bowl = 1.0 + 0.3 * math.log10(rationality) ** 2
                    records.append(
                        _record(
                            rng,
                            block="lambda_sweep",
                            rationality=rationality,
                            scale=factor * bowl,
                            **common,
                        )
                    )
        for index in range(cv_subjects):
            theta = [float(v) for v in rng.uniform(-1, 1, level)]
            centers = _centers(rng, level)
            for eta in etas:
                records.append(
                    _record(
                        rng,
                        block="eta_cv",
                        subject=f"cv-k{level}-s{index:03d}",
                        human=BEST_RESPONSE,
                        num_features=level,
                        rationality=1.0,
                        eta=eta,
                        theta=theta,
                        centers=centers,
                        scale=1.0 + 0.5 * math.log10(eta) ** 2,
                    )
                )
    return records


def rows(records: list[TrialRecord]) -> list[TrialRow]:
    """The rows the analysis reads (:class:`~cirl_study.record.TrialRow`) of ``records``."""
    return [TrialRow.of(record) for record in records]


def records_of(records: list[TrialRecord]) -> Callable[[set[str]], list[TrialRecord]]:
    """``write_report``'s ``records_of`` over records held in memory."""
    return lambda wanted: [record for record in records if record.trial_id in wanted]


def pipeline(
    name: str = "paper",
    humans: Sequence[str] = PAPER_HUMANS,
    robots: Sequence[str] = ("map",),
) -> Pipeline:
    """The smoke pipeline named ``name``, playing ``humans`` with ``robots``: the order of
    the humans and robots the analysis of synthetic records follows."""
    text = SMOKE.read_text(encoding="utf-8").replace('name = "smoke"', f'name = "{name}"')
    text = text.replace(
        'humans = ["expert", "best_response"]', f"humans = {json.dumps(list(humans))}"
    )
    text = text.replace('robots = ["map"]', f"robots = {json.dumps(list(robots))}")
    return parse_pipeline(text, Path(f"{name}.toml"))
