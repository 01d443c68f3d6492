"""Time the core engine per stage at the paper's setting and print medians.

Usage::

    python benchmarks/bench_core.py [--trials 200] [--repeats 5] [--eta 1.0]

Plays ``--trials`` trials (10x10 grid, start [5, 5], 9 + 9 steps, sigma and lambda
from ``pipelines/paper.toml``, centres and theta drawn as the pipeline draws them)
for K = 3 and K = 10 in one process on one core, ``--repeats`` times, and prints the
median wall time per trial of each stage and of the whole best-response and expert
trial (:func:`cirl_study.trial.play_trials`). The first (compiling) call is not timed.
"""

from __future__ import annotations

import argparse
import statistics
import time
import tomllib
from collections.abc import Callable
from pathlib import Path

import numpy as np

from cirl_study.gridworld import Gridworld, rbf_features
from cirl_study.humans import best_response_paths, best_response_target, expert_paths
from cirl_study.irl import fit_maxent_irl
from cirl_study.measures import regret, reward_l2, trajectory_kl
from cirl_study.path_search import nearest_paths
from cirl_study.trial import GameSetting, TrialSpec, play_trials

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
    succ = grid.successors
    rng = np.random.default_rng(k)
    centers = rng.uniform(0, [game["width"] - 1, game["height"] - 1], size=(n, k, 2))
    theta = rng.uniform(-1, 1, size=(n, k))
    eta = np.full(n, eta_value)
    phi = rbf_features(grid, centers, game["sigma"])
    br = best_response_paths(theta, eta, phi, succ, start, steps, rationality)
    counts = phi[np.arange(n)[:, None], br[:, 1:]].sum(axis=1)
    fit = fit_maxent_irl(counts, phi, succ, start, steps, rationality)
    target = best_response_target(theta, eta, phi, succ, start, steps, rationality)
    setting = [
        GameSetting(game["width"], game["height"], tuple(game["start"]), steps, deploy,
                    tuple(map(tuple, centers[i])), game["sigma"])
        for i in range(n)
    ]  # fmt: skip
    specs = {
        policy: [
            TrialSpec(
                f"{policy}-{i}",
                "bench",
                "main",
                f"s{i}",
                policy,
                k,
                rationality,
                None if policy == "expert" else eta_value,
                i,
                tuple(theta[i]),
                setting[i],
            )
            for i in range(n)
        ]  # fmt: skip
        for policy in ("expert", "best_response")
    }
    return {
        "expert demonstration": lambda: expert_paths(theta, phi, succ, start, steps),
        "best-response target (phi_theta)": lambda: best_response_target(
            theta, eta, phi, succ, start, steps, rationality
        ),
        "best-response search": lambda: nearest_paths(
            phi, target, succ, start, steps, direction=theta
        ),
        "MaxEnt IRL (best-response demos)": lambda: fit_maxent_irl(
            counts, phi, succ, start, steps, rationality
        ),
        "measures": lambda: (
            regret(theta, fit.theta_hat, phi, succ, deploy),
            trajectory_kl(theta, fit.theta_hat, phi, succ, deploy, rationality),
            reward_l2(theta, fit.theta_hat, phi),
        ),
        "whole trial, expert": lambda: play_trials(specs["expert"]),
        "whole trial, best response": lambda: play_trials(specs["best_response"]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--eta", type=float, default=1.0, help="best-response eta")
    args = parser.parse_args()
    paper = tomllib.loads(PAPER.read_text())
    game, rationality = paper["game"], paper["main"]["rationality"]
    print(f"{args.trials} trials x {args.repeats} repeats, sigma={game['sigma']}, "
          f"lambda={rationality}, eta={args.eta}: median ms per trial")  # fmt: skip
    for k in (3, 10):
        for name, run in stages_for(k, args.trials, game, rationality, args.eta).items():
            ms = median_ms_per_trial(run, args.trials, args.repeats)
            print(f"K={k:<3} {name:<36} {ms:8.3f}")


if __name__ == "__main__":
    main()
