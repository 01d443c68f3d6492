"""Time a pipeline's whole life, stage by stage, and print medians and ratios to the run.

Usage::

    python benchmarks/bench_run.py [--pipelines smoke paper] [--repeats 3]
                                   [--workers N] [--engine local|dask]

Each repeat, in new processes exactly as a user would type them, into a fresh temporary
directory:

1. ``cirl-study run PIPELINE --out DIR``: wall time, CPU time of the process and its workers,
   and the compute floor the run reports (the workers' own play time divided among them);
2. the same command again, which finds everything logged (a no-op resume);
3. ``cirl-study validate DIR``;
4. ``cirl-study analyze DIR --out REPORT``.

Per pipeline it prints the median of each stage and its ratio to the run's wall time
measured in the same repeat (the median of the per-repeat ratios, and their range), and the
run's wall time over its compute floor. The package's bytecode is compiled first, as Python
caches it after a user's first command: where ``PYTHONDONTWRITEBYTECODE`` is set (some
containers), every command would otherwise compile the package's modules again, about 0.4 s
of a short stage.
Targets: analyze and validate <= 0.15 x run, a no-op resume <= 0.10 x run, run <= 1.2 x its
compute floor.
"""

from __future__ import annotations

import argparse
import compileall
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cirl_study

FLOOR = re.compile(r"compute floor ([\d.]+) s")


def children_cpu_seconds() -> float:
    """User + system CPU time of every finished child process of this one."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def timed(arguments: list[str]) -> tuple[float, float, str]:
    """Wall-clock and CPU seconds, and the standard output, of one ``cirl-study`` command."""
    command = [sys.executable, "-m", "cirl_study", *arguments]
    cpu = children_cpu_seconds()
    began = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - began
    if done.returncode != 0:
        sys.exit(f"{' '.join(command)} failed:\n{done.stderr}")
    return wall, children_cpu_seconds() - cpu, done.stdout


def one_repeat(pipeline: str, options: list[str]) -> dict[str, float]:
    """Seconds of every stage of one pipeline's life, in fresh directories."""
    with tempfile.TemporaryDirectory(prefix="bench-run-") as scratch:
        out, report = str(Path(scratch) / "run"), str(Path(scratch) / "report")
        run, cpu, summary = timed(["run", pipeline, "--out", out, *options])
        floor = FLOOR.search(summary)
        resume, _, _ = timed(["run", pipeline, "--out", out, *options])
        validate, _, _ = timed(["validate", out])
        analyze, _, _ = timed(["analyze", out, "--out", report])
    return {
        "run": run,
        "run CPU": cpu,
        "compute floor": float(floor.group(1)) if floor else float("nan"),
        "no-op resume": resume,
        "validate": validate,
        "analyze": analyze,
    }


def _ratios(ratios: list[float]) -> str:
    """The median of the per-repeat ratios, and their range when there are several."""
    median = f"{statistics.median(ratios):.3f}"
    if len(ratios) < 2:
        return median
    return f"{median} ({min(ratios):.3f}-{max(ratios):.3f})"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pipelines", nargs="+", default=["smoke", "paper"], metavar="NAME")
    parser.add_argument("--repeats", type=int, default=3, help="runs per pipeline (default 3)")
    parser.add_argument("--workers", type=int, help="passed on to cirl-study run")
    parser.add_argument("--engine", choices=["local", "dask"], default="local")
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error("--repeats must be at least 1")
    compileall.compile_dir(Path(cirl_study.__file__).parent, quiet=1)
    options = ["--engine", args.engine]
    if args.workers is not None:
        options += ["--workers", str(args.workers)]
    print(f"cirl-study run {' '.join(options)}, {args.repeats} repeat(s), {Path.cwd()}")
    for pipeline in args.pipelines:
        repeats = [one_repeat(pipeline, options) for _ in range(args.repeats)]
        print(f"{pipeline}:")
        for stage in repeats[0]:
            median = statistics.median(r[stage] for r in repeats)
            line = f"  {stage:<14} median {median:7.2f} s"
            if stage in ("no-op resume", "validate", "analyze"):
                line += f"   {_ratios([r[stage] / r['run'] for r in repeats])} x run"
            if stage == "run":
                ratios = [r["run"] / r["compute floor"] for r in repeats]
                line += f"   {_ratios(ratios)} x compute floor"
            print(line)


if __name__ == "__main__":
    main()
