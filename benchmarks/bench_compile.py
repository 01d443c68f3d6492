"""Time a first run's kernel compilation (``warm_up``), now and at another revision.

Usage::

    python benchmarks/bench_compile.py [--pipelines paper robots] [--repeats 3]
                                       [--before main]

Each repeat, for each pipeline and for this checkout and ``--before`` (a git revision, checked
out into a temporary worktree), in a new process with an empty numba cache
(``NUMBA_CACHE_DIR``): :func:`cirl_study.study.runner.warm_up` from nothing (the first run on
a machine: every kernel compiled), then again in another new process with the cache it left
(every later run: every kernel loaded). The two revisions alternate within a repeat, so a
busy machine slows both alike. Prints per pipeline the median seconds of each and their ratio
(before / now) measured in the same repeats.
Target: a cold warm-up of the paper pipeline <= 5 s of wall time on 2 cores.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

TIMED = """
import sys, time
from pathlib import Path
from cirl_study.study.pipeline_file import load_pipeline
from cirl_study.study.runner import warm_up
pipeline = load_pipeline(Path(sys.argv[1]))
began = time.perf_counter()
warm_up(pipeline)
print(time.perf_counter() - began)
"""


def timed_warm_up(source: Path, pipeline: Path, cache: Path) -> float:
    """Seconds of ``warm_up(pipeline)`` in a new process importing the package at ``source``
    with the numba cache ``cache``."""
    environment = {**os.environ, "PYTHONPATH": str(source), "NUMBA_CACHE_DIR": str(cache)}
    done = subprocess.run(
        [sys.executable, "-c", TIMED, str(pipeline)],
        env=environment,
        cwd=source,
        capture_output=True,
        text=True,
        check=True,
    )
    return float(done.stdout.split()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pipelines", nargs="+", default=["paper", "robots"])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--before", default="main", help="git revision to compare with")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        before = Path(folder) / "before"
        subprocess.run(
            ["git", "-C", str(ROOT), "worktree", "add", "--detach", "-q", str(before), args.before],
            check=True,
        )
        try:
            sources = {"now": ROOT, "before": before}
            times: dict[tuple[str, str, str], list[float]] = {}
            for repeat in range(args.repeats):
                for name in args.pipelines:
                    for label, source in sources.items():
                        cache = Path(folder) / f"cache-{label}-{name}-{repeat}"
                        cache.mkdir()
                        pipeline = source / "pipelines" / f"{name}.toml"
                        for state in ("cold", "warm"):
                            seconds = timed_warm_up(source, pipeline, cache)
                            times.setdefault((name, label, state), []).append(seconds)
        finally:
            subprocess.run(
                ["git", "-C", str(ROOT), "worktree", "remove", "--force", str(before)], check=True
            )
    print(f"warm_up, median seconds of {args.repeats} (before = {args.before})")
    print(f"{'pipeline':<10} {'cache':<5} {'now':>7} {'before':>7} {'ratio':>6}")
    for name in args.pipelines:
        for state in ("cold", "warm"):
            now = statistics.median(times[name, "now", state])
            then = statistics.median(times[name, "before", state])
            print(f"{name:<10} {state:<5} {now:7.2f} {then:7.2f} {then / now:6.2f}")


if __name__ == "__main__":
    main()
