"""Time the core engine per stage at the paper's setting and print medians.

Usage::

    python benchmarks/bench_core.py [--trials 200] [--repeats 5] [--eta 1.0]
                                    [--rationalities 1 100 1000]

Plays ``--trials`` trials (10x10 grid, start [5, 5], 9 + 9 steps, sigma and lambda
from ``pipelines/paper.toml`` or the given ``--rationalities``, centers and theta drawn as
the pipeline draws them) for K = 3 and K = 10 in one process on one core, ``--repeats``
times, and prints the median wall time per trial of each stage and of the whole
best-response and expert trial (:func:`cirl_study.core.trial.play_trials`). The first
(compiling) call is not timed. The MAP robot's parts are timed too: its demonstration
classes, and one evaluation of its objective at the estimate with the Hessian (what each
iteration and each accepted step needs) and without (what the line search needs); with the
mean iterations per fit, printed first, they say where the fit's time goes.
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
from cirl_study.core.humans import best_response_paths, best_response_target, expert_paths
from cirl_study.core.maxent import MaxEnt, Phase
from cirl_study.core.measures import regret, reward_l2, trajectory_kl
from cirl_study.core.path_search import nearest_paths
from cirl_study.core.robot import map_estimate
from cirl_study.core.trial import play_trials
from cirl_study.features import RBFFeatures
from cirl_study.record import BEST_RESPONSE, EXPERT, Grid, TrialSpec

PAPER = Path(__file__).resolve().parents[1] / "pipelines" / "paper.toml"


def median_ms_per_trial(run: Callable[[], object], trials: int, repeats: int) -> float:
    """Median over ``repeats`` of the wall time of ``run()``, per trial, in milliseconds."""
    run()  # compile / warm up
    times = []
    for _ in range(repeats):
        begin = time.perf_counter()
        run()
        times.append(time.perf_counter() - begin)
    return 1e3 * statistics.median(times) / trials


def stages_for(k: int, n: int, game: dict, rationality: float, eta_value: float):
    """The timed stages for ``n`` trials with ``k`` features, as name -> callable."""
    grid = Gridworld(game["width"], game["height"])
    start, steps, deploy = (
        grid.index(*game["start"]),
        game["learning_steps"],
        game["deployment_steps"],
    )
    rng = np.random.default_rng(k)
    centers = rng.uniform(0, [game["width"] - 1, game["height"] - 1], size=(n, k, 2))
    theta = rng.uniform(-1, 1, size=(n, k))
    eta = np.full(n, eta_value)
    phi = rbf_features(grid, centers, game["sigma"])
    learning = MaxEnt(Phase(grid.successors, start, steps), phi, rationality)
    deployment = MaxEnt(Phase(grid.successors, None, deploy), phi, rationality)
    br = best_response_paths(learning, theta, eta)
    fit = map_estimate(learning, br)
    classes = learning.demonstration_classes(br)
    print(f"K={k:<3} MAP robot: {fit.iterations.mean():.1f} iterations per fit on average")
    target = best_response_target(learning, theta, eta)
    specs = {
        human: [
            TrialSpec(
                trial_id=f"{human}-{i}",
                run_id="bench",
                block="main",
                subject=f"s{i}",
                human=human,
                num_features=k,
                rationality=rationality,
                eta=None if human == EXPERT else eta_value,
                seed=i,
                grid=Grid(width=game["width"], height=game["height"]),
                start=tuple(game["start"]),
                learning_steps=steps,
                deployment_steps=deploy,
                features=RBFFeatures(
                    centers=tuple((float(x), float(y)) for x, y in centers[i]),
                    sigma=game["sigma"],
                ),
                theta=tuple(float(v) for v in theta[i]),
            )
            for i in range(n)
        ]
        for human in (EXPERT, BEST_RESPONSE)
    }
    return {
        "expert demonstration": lambda: expert_paths(learning, theta),
        "best-response target (phi_theta)": lambda: best_response_target(learning, theta, eta),
        "best-response search": lambda: nearest_paths(phi, target, learning.phase, direction=theta),
        "MAP robot (best-response demos)": lambda: map_estimate(learning, br),
        "  its demonstration classes": lambda: learning.demonstration_classes(br),
        "  one evaluation with the Hessian": lambda: learning.off_demonstration(
            fit.theta_hat, classes
        ),
        "  one evaluation of the value alone": lambda: learning.off_demonstration(
            fit.theta_hat, classes, moments=0
        ),
        "measures": lambda: (
            regret(deployment, theta, fit.theta_hat),
            trajectory_kl(deployment, theta, fit.theta_hat),
            reward_l2(phi, theta, fit.theta_hat),
        ),
        "whole trial, expert": lambda: play_trials(specs[EXPERT]),
        "whole trial, best response": lambda: play_trials(specs[BEST_RESPONSE]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--eta", type=float, default=1.0, help="best-response eta")
    parser.add_argument(
        "--rationalities",
        type=float,
        nargs="+",
        default=None,
        help="lambdas to time (default: the paper's main block, lambda = 1)",
    )
    args = parser.parse_args()
    paper = tomllib.loads(PAPER.read_text())
    game = paper["game"]
    for rationality in args.rationalities or [paper["main"]["rationality"]]:
        print(f"{args.trials} trials x {args.repeats} repeats, sigma={game['sigma']}, "
              f"lambda={rationality:g}, eta={args.eta}: median ms per trial")  # fmt: skip
        for k in (3, 10):
            for name, run in stages_for(k, args.trials, game, rationality, args.eta).items():
                ms = median_ms_per_trial(run, args.trials, args.repeats)
                print(f"K={k:<3} {name:<36} {ms:8.3f}")


if __name__ == "__main__":
    main()
