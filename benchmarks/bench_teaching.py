"""Time the teaching players of ``pipelines/teaching.toml`` and say where the time goes.

Usage::

    python benchmarks/bench_teaching.py [--draws 8] [--repeats 3] [--k 10]

Takes the first ``--draws`` reward draws at ``--k`` features of the teaching pipeline's main
block, exactly as it plans them (10x10 grid, start [5, 5], 9 + 9 steps, 64 hypotheses with the
truth, alpha = 10; the best response at eta = 1), and plays them in one process on one core,
``--repeats`` times. It prints the median wall time per trial of each human and robot pair
(:func:`cirl_study.core.trial.play_trials`), of all the pipeline's trials of a draw played
together (each demonstration once for every robot, each normaliser once for every human), and
of the stages the teaching players add: the hypotheses' log-partitions, one pass over the
visit classes (the pedagogic normaliser and the human's teaching weights) and one MAP fit (the
regret-optimal search makes many). The one-off enumeration of the visit classes is timed on
its own; every other first (compiling) call is not timed.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from cirl_study.core.gridworld import feature_matrix, gridworld
from cirl_study.core.hypotheses import HypothesisSpace, VisitClasses, draw_hypotheses
from cirl_study.core.maxent import MaxEnt, Phase
from cirl_study.core.robot import map_estimate
from cirl_study.core.trial import play_trials
from cirl_study.record import MAIN
from cirl_study.study.pipeline_file import load_pipeline
from cirl_study.study.plan import study_trials

TEACHING = Path(__file__).resolve().parents[1] / "pipelines" / "teaching.toml"


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
    parser.add_argument("--draws", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--k", type=int, default=10)
    options = parser.parse_args()
    pipeline = load_pipeline(TEACHING)
    teaching = pipeline.teaching
    assert teaching is not None
    etas = {
        (None, human, k): 1.0
        for human in pipeline.humans_with_eta
        for k in pipeline.game.feature_levels
    }
    planned = [
        t for t in study_trials(pipeline, etas) if t.block == MAIN and t.num_features == options.k
    ]
    subjects = sorted({t.subject for t in planned})[: options.draws]
    trials = [t for t in planned if t.subject in subjects]
    first = [next(t for t in trials if t.subject == s) for s in subjects]

    grid = gridworld(first[0])
    phase = Phase(
        grid.demonstrator_moves(first[0].demonstrator_stays),
        grid.index(*first[0].start),
        first[0].learning_steps,
    )
    begin = time.perf_counter()
    classes = VisitClasses.of(phase)
    enumeration = time.perf_counter() - begin
    print(
        f"enumeration (once per process): {enumeration:.2f} s, "
        f"{classes.multiplicity.sum():,} paths in {classes.size:,} classes"
    )

    n = len(first)
    theta = np.array([t.theta for t in first])
    model = MaxEnt(phase, np.stack([feature_matrix(t) for t in first]), first[0].rationality)
    seeds = np.array([t.teaching.hypothesis_seed for t in first])  # type: ignore[union-attr]
    thetas = draw_hypotheses(
        theta, seeds, teaching.hypotheses, includes_truth=teaching.includes_truth
    )
    space = HypothesisSpace(model, thetas, teaching.includes_truth, teaching.alpha)
    demos = np.array([classes.paths[0]] * n, dtype=np.int64)

    def one_pass() -> None:
        for b in range(n):
            space.pass_over_classes(b, thetas[b], 0)

    stages = {
        "log-partitions of the hypotheses": lambda: (
            HypothesisSpace(model, thetas, teaching.includes_truth, teaching.alpha).log_partition
        ),
        "one pass over the classes": one_pass,
        "one MAP fit": lambda: map_estimate(model, demos),
    }
    print(
        f"K = {options.k}, H = {teaching.hypotheses}, alpha = {teaching.alpha:g}, {n} reward "
        f"draws, median of {options.repeats}, ms per trial:"
    )
    for name, run in stages.items():
        print(f"  {name:<40} {1e3 * median_seconds(run, options.repeats) / n:9.1f}")
    for pair in dict.fromkeys((t.human, t.robot) for t in trials):
        specs = [t for t in trials if (t.human, t.robot) == pair]
        seconds = median_seconds(lambda specs=specs: play_trials(specs), options.repeats)
        label = f"whole trial, {pair[0]} + {pair[1]}"
        print(f"  {label:<40} {1e3 * seconds / len(specs):9.1f}")
    seconds = median_seconds(lambda: play_trials(trials), options.repeats)
    per_draw = len(trials) // n
    label = f"all {per_draw} trials of a draw together"
    print(f"  {label:<40} {1e3 * seconds / len(trials):9.1f} (x {per_draw} per draw)")


if __name__ == "__main__":
    main()
