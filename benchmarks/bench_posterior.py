"""Time the ``posterior_mean`` robot per lambda, with the standard error and ESS it reaches.

Usage::

    python benchmarks/bench_posterior.py [--trials 16] [--repeats 3] [--features 3 10]
        [--rationalities 1e-4 ... 1e3] [--budget 2048]

Draws ``--trials`` trials of the paper's game (``pipelines/paper.toml``: 10x10 grid, 9 steps
from [5, 5], RBF sigma 1.5, centers uniform over the grid, theta ~ U[-1, 1]^K), the expert's
demonstrations, and runs :func:`cirl_study.core.posterior.posterior_mean_estimate` on each
trial alone, on one core (BLAS and OpenMP limited to one thread), ``--repeats`` times. Per
``K`` and lambda it prints, over the trials: the median and the largest time per trial (each
trial's median over the repeats), the median and largest number of likelihood evaluations,
the median of the largest per-coordinate standard error, the median ESS and ESS fraction, the
share of trials that met the target standard error, and the time of one likelihood
evaluation. A second table gives what a cap of ``--budget`` evaluations (about 50 ms at
K = 10) reaches. The first (compiling) call is not timed.
"""

from __future__ import annotations

import os

for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")  # one core: set before numpy loads BLAS

import argparse  # noqa: E402
import statistics  # noqa: E402
import time  # noqa: E402
import tomllib  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from cirl_study.core.gridworld import Gridworld, rbf_features  # noqa: E402
from cirl_study.core.humans import expert_paths  # noqa: E402
from cirl_study.core.maxent import MaxEnt, Phase  # noqa: E402
from cirl_study.core.posterior import posterior_mean_estimate  # noqa: E402

PAPER = Path(__file__).resolve().parents[1] / "pipelines" / "paper.toml"
SWEEP = (1e-4, 1e-3, 1e-2, 1e-1, 1.0, 1e1, 1e2, 1e3)


def paper_trials(k: int, n: int, rationality: float, game: dict, seed: int):
    """``n`` trials of the paper's game with ``k`` features: the model and expert paths."""
    grid = Gridworld(game["width"], game["height"])
    rng = np.random.default_rng([seed, k])
    centers = rng.uniform(0, [game["width"] - 1, game["height"] - 1], size=(n, k, 2))
    theta = rng.uniform(-1, 1, size=(n, k))
    features = rbf_features(grid, centers, game["sigma"])
    phase = Phase(grid.successors, grid.index(*game["start"]), game["learning_steps"])
    model = MaxEnt(phase, features, rationality)
    return model, expert_paths(model, theta)


def evaluation_cost(model: MaxEnt, paths, points: int = 4096) -> float:
    """CPU milliseconds per likelihood evaluation (:meth:`MaxEnt.log_likelihood_at`)."""
    one = model.take([0])
    counts = one.path_counts(paths[:1])
    thetas = np.random.default_rng(0).uniform(-1, 1, size=(1, points, counts.shape[1]))
    one.log_likelihood_at(thetas, counts)
    begin = time.process_time()
    one.log_likelihood_at(thetas, counts)
    return 1e3 * (time.process_time() - begin) / points


def run(model: MaxEnt, paths, repeats: int, **options):
    """Each trial alone, ``repeats`` times: per-trial median CPU ms and the last estimates."""
    seeds = np.arange(model.batch) + 1
    times = np.empty((model.batch, repeats))
    rows = []
    for b in range(model.batch):
        for r in range(repeats):
            begin = time.process_time()
            estimate = posterior_mean_estimate(model.take([b]), paths[[b]], seeds[[b]], **options)
            times[b, r] = 1e3 * (time.process_time() - begin)
        rows.append(estimate)
    ms = np.median(times, axis=1)
    samples = np.array([e.iterations[0] for e in rows])
    se = np.array([e.theta_hat_se[0].max() for e in rows])
    ess = np.array([e.effective_sample_size[0] for e in rows])
    converged = np.array([e.converged[0] for e in rows])
    return ms, samples, se, ess, converged


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--features", type=int, nargs="+", default=[10, 3])
    parser.add_argument("--rationalities", type=float, nargs="+", default=list(SWEEP))
    parser.add_argument("--target", type=float, default=0.01, help="target standard error")
    parser.add_argument("--budget", type=int, default=2048, help="evaluations, second table")
    parser.add_argument("--seed", type=int, default=2016)
    args = parser.parse_args()
    game = tomllib.loads(PAPER.read_text())["game"]
    warm, warm_paths = paper_trials(3, 1, 1.0, game, 0)
    posterior_mean_estimate(warm, warm_paths, np.array([0]))  # compile
    header = (
        f"{'K':>3} {'lambda':>7} {'ms med':>8} {'ms max':>8} {'N med':>7} {'N max':>7} "
        f"{'se med':>7} {'se max':>7} {'ESS med':>8} {'ESS/N':>6} {'met':>5} {'us/eval':>8}"
    )
    for title, options in (
        (f"to the target standard error {args.target}", {"target_se": args.target}),
        (
            f"capped at {args.budget} evaluations",
            {"target_se": args.target, "max_samples": args.budget},
        ),
    ):
        print(
            f"\nposterior_mean {title}: {args.trials} trials x {args.repeats} repeats, one "
            f"core, CPU time per trial (median over repeats); se = largest over coordinates"
        )
        print(header)
        for k in args.features:
            for rationality in args.rationalities:
                model, paths = paper_trials(k, args.trials, rationality, game, args.seed)
                ms, samples, se, ess, converged = run(model, paths, args.repeats, **options)
                cost = 1e3 * evaluation_cost(model, paths)
                print(
                    f"{k:>3} {rationality:>7.0e} {statistics.median(ms):>8.1f} {ms.max():>8.1f} "
                    f"{int(np.median(samples)):>7d} {samples.max():>7d} "
                    f"{np.median(se):>7.4f} {se.max():>7.4f} {np.median(ess):>8.0f} "
                    f"{np.median(ess / samples):>6.2f} {converged.mean():>5.0%} {cost:>8.1f}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
