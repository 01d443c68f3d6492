"""Time the teaching players at the paper's size and say where the time goes.

Usage::

    python benchmarks/bench_teaching.py [--trials 8] [--repeats 3] [--hypotheses 64] [--k 10]

Plays ``--trials`` trials per pair of human and robot (10x10 grid, start [5, 5], 9 + 9 steps,
sigma and lambda from ``pipelines/paper.toml``, ``--hypotheses`` reward hypotheses with the
truth among them) in one process on one core, ``--repeats`` times, and prints the median wall
time per trial of each whole trial (:func:`cirl_study.core.trial.play_trials`) and of the
stages the teaching players add: the one-off enumeration of the learning phase's visit
classes, the hypotheses' log-partitions, one pass over the classes (the pedagogic normaliser
and the human's teaching weights) and one MAP fit (the regret-optimal search makes many).
The first (compiling, enumerating) call is not timed; the enumeration is timed on its own.
"""

from __future__ import annotations

import argparse
import statistics
import time
import tomllib
from collections.abc import Callable
from pathlib import Path

import numpy as np

from cirl_study.core.gridworld import Gridworld, rbf_features
from cirl_study.core.hypotheses import HypothesisSpace, VisitClasses, draw_hypotheses
from cirl_study.core.maxent import MaxEnt, Phase
from cirl_study.core.robot import map_estimate
from cirl_study.core.trial import play_trials
from cirl_study.record import (
    BEST_RESPONSE,
    EXPERT,
    LITERAL,
    LITERAL_ROBOT,
    MAP,
    PEDAGOGIC,
    PRAGMATIC,
    REGRET_OPTIMAL,
    Grid,
    RBFFeatures,
    Teaching,
    TrialSpec,
)

PAPER = Path(__file__).resolve().parents[1] / "pipelines" / "paper.toml"
PAIRS = [
    (EXPERT, MAP),
    (BEST_RESPONSE, MAP),
    (LITERAL, LITERAL_ROBOT),
    (PEDAGOGIC, LITERAL_ROBOT),
    (EXPERT, PRAGMATIC),
    (PEDAGOGIC, PRAGMATIC),
    (REGRET_OPTIMAL, MAP),
]
"""Human and robot pairs timed: each teaching player once, and the pedagogic pair."""


def median_seconds(run: Callable[[], object], repeats: int) -> float:
    """Median wall time of ``run()`` over ``repeats`` calls, after one untimed call."""
    run()
    times = []
    for _ in range(repeats):
        begin = time.perf_counter()
        run()
        times.append(time.perf_counter() - begin)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--hypotheses", type=int, default=64)
    parser.add_argument("--k", type=int, default=10)
    options = parser.parse_args()
    pipeline = tomllib.loads(PAPER.read_text())
    game, rationality = pipeline["game"], pipeline["main"]["rationality"]
    etas = tuple(pipeline["eta_cv"]["etas"])
    grid = Gridworld(game["width"], game["height"])
    phase = Phase(grid.successors, grid.index(*game["start"]), game["learning_steps"])
    n, k = options.trials, options.k

    begin = time.perf_counter()
    classes = VisitClasses.of(phase)
    enumeration = time.perf_counter() - begin
    print(
        f"enumeration (once per process): {enumeration:.2f} s, "
        f"{classes.multiplicity.sum():,} paths in {classes.size:,} classes"
    )

    rng = np.random.default_rng(k)
    centers = rng.uniform(0, [game["width"] - 1, game["height"] - 1], size=(n, k, 2))
    theta = rng.uniform(-1, 1, size=(n, k))
    features = rbf_features(grid, centers, game["sigma"])
    model = MaxEnt(phase, features, rationality)
    thetas = draw_hypotheses(theta, np.arange(n), options.hypotheses, includes_truth=True)
    space = HypothesisSpace(model, thetas, True, 1.0)
    demos = np.array([classes.paths[0]] * n, dtype=np.int64)

    def one_pass() -> None:
        for b in range(n):
            space.pass_over_classes(b, thetas[b], 0)

    stages = {
        "log-partitions of the hypotheses": lambda: (
            HypothesisSpace(model, thetas, True, 1.0).log_partition
        ),
        "one pass over the classes": one_pass,
        "one MAP fit": lambda: map_estimate(model, demos),
    }
    print(f"K = {k}, H = {options.hypotheses}, {n} trials, median of {options.repeats}:")
    for name, run in stages.items():
        print(f"  {name:<36} {1e3 * median_seconds(run, options.repeats) / n:9.1f} ms/trial")

    for human, robot in PAIRS:
        specs = [
            TrialSpec(
                trial_id=f"{human}-{robot}-{i}",
                run_id="bench",
                block="main",
                subject=f"s{i}",
                policy=human,
                num_features=k,
                rationality=rationality,
                eta=1.0 if human == BEST_RESPONSE else None,
                seed=i,
                grid=Grid(width=game["width"], height=game["height"]),
                start=tuple(game["start"]),
                learning_steps=game["learning_steps"],
                deployment_steps=game["deployment_steps"],
                features=RBFFeatures(
                    centers=tuple(map(tuple, centers[i].tolist())), sigma=game["sigma"]
                ),
                theta=tuple(theta[i].tolist()),
                robot=robot,
                teaching=Teaching(
                    hypotheses=options.hypotheses,
                    includes_truth=True,
                    hypothesis_seed=i,
                    alpha=1.0,
                    demonstration="draw",
                    search_etas=etas,
                ),
            )
            for i in range(n)
        ]
        seconds = median_seconds(lambda specs=specs: play_trials(specs), options.repeats)
        label = f"whole trial, {human} + {robot}"
        print(f"  {label:<36} {1e3 * seconds / n:9.1f} ms/trial")


if __name__ == "__main__":
    main()
