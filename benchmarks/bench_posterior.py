"""Time the ``posterior_mean`` robot per lambda, with the standard error and ESS it reaches.

Usage (from the repository root, so that this checkout's package is the one timed)::

    PYTHONPATH=. python benchmarks/bench_posterior.py [--trials 16] [--repeats 3]
        [--features 3 10] [--rationalities 1e-4 ... 1e3] [--budget 2048] [--before main]

Draws ``--trials`` trials of the paper's game (``pipelines/paper.toml``: 10x10 grid, 9 steps
from [5, 5], RBF sigma 1.5, centers uniform over the grid, theta ~ U[-1, 1]^K), the expert's
demonstrations, and runs :func:`cirl_study.core.posterior.posterior_mean_estimate` on each
trial alone, on one core (BLAS and OpenMP limited to one thread), ``--repeats`` times. Per
``K`` and lambda it prints, over the trials: the median and the largest time per trial (each
trial's median over the repeats), the median and largest number of likelihood evaluations,
the median of the largest per-coordinate standard error, the median ESS and ESS fraction, the
share of trials that met the target standard error, and the time of one likelihood
evaluation; then the same trials played by the implementation at the git revision
``--before`` (its ``cirl_study/core/posterior.py`` and ``maxent.py``, loaded into temporary
modules), and the ratio of the median times, measured in the same run. With ``--budget``, a
second table gives what a cap of that many evaluations reaches. The first (compiling) call of
each is not timed.
"""

from __future__ import annotations

import os

for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")  # one core: set before numpy loads BLAS

import argparse  # noqa: E402
import importlib.util  # noqa: E402
import statistics  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import tomllib  # noqa: E402
from pathlib import Path  # noqa: E402
from types import ModuleType  # noqa: E402

import numpy as np  # noqa: E402

from cirl_study.core.gridworld import Gridworld, rbf_features  # noqa: E402
from cirl_study.core.humans import expert_paths  # noqa: E402
from cirl_study.core.maxent import MaxEnt, Phase  # noqa: E402
from cirl_study.core.posterior import posterior_mean_estimate  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "pipelines" / "paper.toml"
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


def load_before(revision: str, folder: Path) -> ModuleType:
    """The ``posterior`` module at git ``revision``, reading its own ``maxent`` module.

    Both files are written to ``folder`` and imported as ``before_maxent`` and
    ``before_posterior``; the posterior module's import of the package's ``maxent`` is
    pointed at the old one, so the old estimator scores with the old kernels.
    """
    modules = {}
    for name in ("maxent", "posterior"):
        source = subprocess.run(
            ["git", "-C", str(ROOT), "show", f"{revision}:cirl_study/core/{name}.py"],
            check=True,
            capture_output=True,
            text=True,
        ).stdout
        source = source.replace("from cirl_study.core.maxent import", "from before_maxent import")
        path = folder / f"before_{name}.py"
        path.write_text(source)
        spec = importlib.util.spec_from_file_location(f"before_{name}", path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[f"before_{name}"] = module
        spec.loader.exec_module(module)
        modules[name] = module
    return modules["posterior"], modules["maxent"]


def evaluation_cost(model: MaxEnt, paths, points: int = 4096) -> float:
    """CPU milliseconds per likelihood evaluation (:meth:`MaxEnt.log_likelihood_at`)."""
    one = model.take([0])
    counts = one.path_counts(paths[:1])
    thetas = np.random.default_rng(0).uniform(-1, 1, size=(1, points, counts.shape[1]))
    one.log_likelihood_at(thetas, counts)
    begin = time.process_time()
    one.log_likelihood_at(thetas, counts)
    return 1e3 * (time.process_time() - begin) / points


def run(estimator, model: MaxEnt, paths, repeats: int, **options):
    """Each trial alone, ``repeats`` times: per-trial median CPU ms and the last estimates."""
    seeds = np.arange(model.batch) + 1
    times = np.empty((model.batch, repeats))
    rows = []
    for b in range(model.batch):
        for r in range(repeats):
            begin = time.process_time()
            estimate = estimator(model.take([b]), paths[[b]], seeds[[b]], **options)
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
    parser.add_argument("--budget", type=int, help="evaluations, second table (none: skip)")
    parser.add_argument("--before", default="main", help="git revision to compare with")
    parser.add_argument("--seed", type=int, default=2016)
    args = parser.parse_args()
    game = tomllib.loads(PAPER.read_text())["game"]
    with tempfile.TemporaryDirectory() as folder:
        before, before_maxent = load_before(args.before, Path(folder))
        warm, warm_paths = paper_trials(3, 1, 1.0, game, 0)
        posterior_mean_estimate(warm, warm_paths, np.array([0]))  # compile
        old_warm = before_maxent.MaxEnt(warm.phase, warm.features, warm.rationality)
        before.posterior_mean_estimate(old_warm, warm_paths, np.array([0]))
        header = (
            f"{'K':>3} {'lambda':>7} {'ms med':>8} {'ms max':>8} {'N med':>7} {'N max':>7} "
            f"{'se med':>7} {'se max':>7} {'ESS med':>8} {'ESS/N':>6} {'met':>5} {'us/eval':>8}"
            f" | {'before':>8} {'N':>7} {'ratio':>6}"
        )
        tables = [(f"to the target standard error {args.target}", {"target_se": args.target})]
        if args.budget:
            tables.append(
                (
                    f"capped at {args.budget} evaluations",
                    {"target_se": args.target, "max_samples": args.budget},
                )
            )
        for title, options in tables:
            print(
                f"\nposterior_mean {title}: {args.trials} trials x {args.repeats} repeats, one "
                f"core, CPU time per trial (median over repeats); se = largest over "
                f"coordinates; before = {args.before}, its median ms and evaluations"
            )
            print(header)
            for k in args.features:
                for rationality in args.rationalities:
                    model, paths = paper_trials(k, args.trials, rationality, game, args.seed)
                    ms, samples, se, ess, converged = run(
                        posterior_mean_estimate, model, paths, args.repeats, **options
                    )
                    old_model = before_maxent.MaxEnt(model.phase, model.features, model.rationality)
                    old_ms, old_samples, *_ = run(
                        before.posterior_mean_estimate, old_model, paths, args.repeats, **options
                    )
                    cost = 1e3 * evaluation_cost(model, paths)
                    new_median, old_median = statistics.median(ms), statistics.median(old_ms)
                    print(
                        f"{k:>3} {rationality:>7.0e} {new_median:>8.1f} {ms.max():>8.1f} "
                        f"{int(np.median(samples)):>7d} {samples.max():>7d} "
                        f"{np.median(se):>7.4f} {se.max():>7.4f} {np.median(ess):>8.0f} "
                        f"{np.median(ess / samples):>6.2f} {converged.mean():>5.0%} "
                        f"{cost:>8.1f} | {old_median:>8.1f} {int(np.median(old_samples)):>7d} "
                        f"{old_median / new_median:>5.1f}x",
                        flush=True,
                    )


if __name__ == "__main__":
    main()
