"""Fabricated trial records (docs/design.md §7), for the log-layer tests.

The records are consistent by construction (paths are walks on the grid, ``reward_l2`` is
computed cell by cell with :func:`math.exp`, independently of the package's RBF features),
so any fault a test finds in them was put there by the test.
"""

from __future__ import annotations

import math
import random
from pathlib import Path
from typing import Any

from cirl_study.core.order_agreement import agreement
from cirl_study.logs.provenance import RunIdentity
from cirl_study.logs.reader import read_run, read_trials
from cirl_study.logs.record_checks import record_faults
from cirl_study.record import TrialRecord, from_builtins
from cirl_study.study.pipeline_file import logged_pipeline, parse_pipeline


def run_records(run: Path) -> list[TrialRecord]:
    """Every record of the run in ``run``, whole (``read_run`` keeps only their rows)."""
    contents = read_run(run, logged_pipeline)
    wanted = {row.trial_id for row in contents.rows}
    return read_trials(run, contents.identity, logged_pipeline, wanted)


SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"


def provenance_for(name: str = "test", variant: str = "") -> dict[str, str]:
    """A ``provenance`` record of a run of a valid pipeline named ``name`` (the smoke pipeline,
    renamed), whose run id is that of its name and text; ``variant`` is appended to the text
    (a comment makes it another run)."""
    text = SMOKE.read_text().replace('name = "smoke"', f'name = "{name}"', 1) + variant
    pipeline = parse_pipeline(text, Path(f"{name}.toml"))
    return RunIdentity(pipeline.run_id, name, f"{name}.toml", text).provenance()


RUN_ID = provenance_for()["run_id"]
"""The run id of :func:`provenance_for`'s default run, which fabricated records carry."""


STEPS = {"stay": (0, 0), "N": (0, 1), "S": (0, -1), "E": (1, 0), "W": (-1, 0)}


def _walk(rng: random.Random, start: list[int], steps: int, width: int, height: int):
    states, actions = [list(start)], []
    for _ in range(steps):
        x, y = states[-1]
        moves = [
            (a, [x + dx, y + dy])
            for a, (dx, dy) in STEPS.items()
            if 0 <= x + dx < width and 0 <= y + dy < height
        ]
        action, cell = rng.choice(moves)
        actions.append(action)
        states.append(cell)
    return states, actions


def brute_force_reward(features: dict[str, Any], theta: list[float], x: int, y: int) -> float:
    """``theta . phi([x, y])`` from the definition, one center at a time."""
    sigma = features["sigma"]
    return math.fsum(
        w * math.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * sigma**2))
        for w, (cx, cy) in zip(theta, features["centers"], strict=True)
    )


def make_record(
    subject: int = 0,
    human: str = "expert",
    *,
    block: str = "main",
    num_features: int = 3,
    width: int = 5,
    height: int = 4,
    learning_steps: int = 4,
    deployment_steps: int = 3,
    rollouts: int = 2,
    run_id: str = RUN_ID,
) -> TrialRecord:
    """A consistent trial record; the reward draw depends only on ``(subject, num_features)``."""
    draw = random.Random(f"{subject}/{num_features}")
    centers = [
        [round(draw.uniform(0, width - 1), 3), round(draw.uniform(0, height - 1), 3)]
        for _ in range(num_features)
    ]
    theta = [draw.uniform(-1, 1) for _ in range(num_features)]
    rng = random.Random(f"{subject}/{num_features}/{human}/{block}")
    start = [width // 2, height // 2]
    states, actions = _walk(rng, start, learning_steps, width, height)
    starts = [[rng.randrange(width), rng.randrange(height)] for _ in range(rollouts)]
    paths = [_walk(rng, s, deployment_steps, width, height)[0] for s in starts]
    record: dict[str, Any] = {
        "trial_id": f"{block}/k{num_features}/s{subject:04d}/{human}",
        "run_id": run_id,
        "block": block,
        "subject": f"k{num_features}-s{subject:04d}",
        "human": human,
        "num_features": num_features,
        "rationality": 1.0,
        "eta": None if human == "expert" else 0.5,
        "seed": rng.randrange(2**32),
        "grid": {"width": width, "height": height},
        "start": start,
        "learning_steps": learning_steps,
        "deployment_steps": deployment_steps,
        "features": {"kind": "rbf", "centers": centers, "sigma": 1.5},
        "theta": theta,
        "theta_hat": [max(-1.0, min(1.0, w + rng.gauss(0, 0.3))) for w in theta],
        "demonstration": {"states": states, "actions": actions},
        "irl": {"log_likelihood": -rng.uniform(1, 5), "iterations": 7, "converged": True},
        "deployment": {"starts": starts, "paths": paths},
    }
    difference = [a - b for a, b in zip(record["theta"], record["theta_hat"], strict=True)]
    l2 = math.sqrt(
        math.fsum(
            brute_force_reward(record["features"], difference, x, y) ** 2
            for x in range(width)
            for y in range(height)
        )
    )
    record["measures"] = {
        "regret": rng.uniform(0, 2),
        "kl": rng.uniform(0, 3),
        "reward_l2": l2,
        "regret_under_estimate": rng.uniform(0, 2),
        "order_agreement": agreement([record["theta"]], [record["theta_hat"]])[0],
    }
    return from_builtins(record)


def make_study(subjects: int = 3, num_features: tuple[int, ...] = (3, 10)) -> list[TrialRecord]:
    """A complete small main block: every subject under both humans."""
    return [
        make_record(subject, human, num_features=k)
        for k in num_features
        for subject in range(subjects)
        for human in ("expert", "best_response")
    ]


def test_fabricated_records_are_consistent() -> None:
    for record in make_study():
        assert record_faults(record) == []
