"""Time whole pipelines end to end (``cirl-study run``) and print medians.

Usage::

    python benchmarks/bench_run.py [--pipelines smoke paper] [--repeats 3]
                                   [--workers N] [--engine local|dask]

Each repeat runs ``cirl-study run PIPELINE --out <fresh temporary directory>`` in a new
process, exactly as a user would (start-up, planning, playing, logging), and measures its
wall-clock time and the CPU time of the process and its workers. The median over the
repeats is printed per pipeline. CPU time says how much work was done even on a machine
shared with other jobs, where wall-clock time also measures the neighbours.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def children_cpu_seconds() -> float:
    """User + system CPU time of every finished child process of this one."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def time_run(pipeline: str, options: list[str]) -> tuple[float, float]:
    """Wall-clock and CPU seconds of one ``cirl-study run`` into a fresh directory."""
    with tempfile.TemporaryDirectory(prefix="bench-run-") as out:
        command = [sys.executable, "-m", "cirl_study", "run", pipeline, "--out", out]
        cpu = children_cpu_seconds()
        began = time.perf_counter()
        done = subprocess.run([*command, *options], capture_output=True, text=True, check=False)
        wall = time.perf_counter() - began
        cpu = children_cpu_seconds() - cpu
        if done.returncode != 0:
            sys.exit(f"{' '.join(command)} failed:\n{done.stderr}")
        return wall, cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pipelines", nargs="+", default=["smoke", "paper"], metavar="NAME")
    parser.add_argument("--repeats", type=int, default=3, help="runs per pipeline (default 3)")
    parser.add_argument("--workers", type=int, help="passed on to cirl-study run")
    parser.add_argument("--engine", choices=["local", "dask"], default="local")
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error("--repeats must be at least 1")
    options = ["--engine", args.engine]
    if args.workers is not None:
        options += ["--workers", str(args.workers)]
    print(f"cirl-study run {' '.join(options)}, {args.repeats} repeat(s), {Path.cwd()}")
    for pipeline in args.pipelines:
        walls, cpus = [], []
        for _ in range(args.repeats):
            wall, cpu = time_run(pipeline, options)
            walls.append(wall)
            cpus.append(cpu)
        runs = ", ".join(f"{w:.1f}" for w in walls)
        print(
            f"{pipeline}: median {statistics.median(walls):.1f} s wall "
            f"(runs: {runs}), median {statistics.median(cpus):.1f} s CPU"
        )


if __name__ == "__main__":
    main()
