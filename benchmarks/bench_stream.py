"""Peak memory of analysing a run of a million trials: the report is built streaming.

Usage::

    python benchmarks/bench_stream.py [--trials 1000000] [--keep DIR]

Writes a pipeline of the paper's shape on a 3 x 3 grid with 2-step phases (so its trials are
cheap to play, while every record is a real, fully checked one) whose ``main`` block holds
about ``--trials`` trials, plays it with ``cirl-study run`` and analyses it with
``cirl-study analyze``, each in its own process exactly as a user would type them. Prints
the wall time and the peak memory of each (the command and its workers together, sampled
from Linux's ``/proc``: see :func:`measured`), and the analysis's memory per trial above that
of an analysis of a run of ~1,000 trials of the same pipeline shape (the fixed cost of the
libraries). Target: the analysis of 1,000,000 trials within 2 GB.

``analyze`` reads the files in worker processes and keeps each record only as its
:class:`~cirl_study.record.TrialRow`; the statistics are linear in ``n`` in time and memory
(the bootstrap and the Wilcoxon effect sizes included), and Figure 1's two records are read
back by id.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PIPELINE = """\
name = "stream-{trials}"
description = "A million-trial run for the streaming analysis benchmark"
seed = 1

[game]
width = 3
height = 3
start = [1, 1]
learning_steps = 2
deployment_steps = 2
sigma = 1.0
feature_levels = [2, 3]
centers = "per_draw"
demonstrator_stays = true
deployment_start = "uniform"

[eta_cv]
subjects = 2
etas = [0.1, 1.0]
rationality = 1.0

[main]
subjects = {subjects}
rationality = 1.0
humans = ["expert", "best_response"]
robots = ["map"]

[lambda_sweep]
subjects = 2
rationalities = [1.0]
"""

LIMIT_BYTES = 2 * 1024**3
"""The target: peak memory of the analysis of 1,000,000 trials."""


SAMPLE_SECONDS = 0.1
"""How often the memory of a command's processes is sampled."""


def _descendants(pid: int) -> list[int]:
    """``pid`` and every process it started, still running (Linux ``/proc``)."""
    found, queue = [], [pid]
    while queue:
        current = queue.pop()
        found.append(current)
        for task in Path(f"/proc/{current}/task").glob("*/children"):
            try:
                queue += [int(child) for child in task.read_text().split()]
            except OSError:  # the task ended meanwhile
                continue
    return found


def _proportional_bytes(pid: int) -> int:
    """``pid``'s proportional set size: its private pages, and its share of shared ones."""
    try:
        text = Path(f"/proc/{pid}/smaps_rollup").read_text()
    except OSError:  # it ended meanwhile
        return 0
    match = re.search(r"^Pss:\s+(\d+) kB", text, re.MULTILINE)
    return int(match.group(1)) * 1024 if match else 0


def measured(arguments: list[str]) -> tuple[float, int, str]:
    """Wall seconds, peak memory in bytes and output of one ``cirl-study`` command.

    The memory is that of the command and every worker it starts together: their
    proportional set sizes summed (a page the workers share with it counts once), sampled
    every :data:`SAMPLE_SECONDS`; the largest resident set of any one of them would miss
    what forked workers copy.
    """
    began = time.perf_counter()
    with tempfile.TemporaryFile("w+") as output, tempfile.TemporaryFile("w+") as errors:
        command = [sys.executable, "-m", "cirl_study", *arguments]
        process = subprocess.Popen(command, stdout=output, stderr=errors, text=True)
        peak = 0
        while process.poll() is None:
            peak = max(peak, sum(map(_proportional_bytes, _descendants(process.pid))))
            time.sleep(SAMPLE_SECONDS)
        seconds = time.perf_counter() - began
        output.seek(0)
        errors.seek(0)
        if process.returncode != 0:
            sys.exit(f"cirl-study {' '.join(arguments)} failed:\n{errors.read()}")
        return seconds, peak, output.read()


def run_and_analyse(directory: Path, trials: int) -> tuple[int, float, float, int]:
    """Play and analyse a pipeline of about ``trials`` main-block trials in ``directory``.

    Returns the trials logged, the run's and the analysis's wall seconds and the analysis's
    peak memory in bytes (see :func:`measured`).
    """
    subjects = max(2, trials // 4)  # 2 feature levels x 2 humans
    pipeline = directory / f"stream-{trials}.toml"
    pipeline.write_text(PIPELINE.format(trials=trials, subjects=subjects), encoding="utf-8")
    run_dir = directory / f"run-{trials}"
    run_seconds, _, _ = measured(["run", str(pipeline), "--out", str(run_dir)])
    report = str(directory / f"report-{trials}")
    analyse_seconds, peak, said = measured(["analyze", str(run_dir), "--out", report])
    match = re.search(r"report of (\d+) trials", said)
    if match is None:
        sys.exit(f"analyze said no trial count: {said}")
    return int(match.group(1)), run_seconds, analyse_seconds, peak


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=1_000_000)
    parser.add_argument("--keep", type=Path, help="play into this directory and keep it")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-stream-") as scratch:
        directory = args.keep or Path(scratch)
        directory.mkdir(parents=True, exist_ok=True)
        _, _, _, fixed = run_and_analyse(directory, 1_000)
        logged, run_seconds, analyse_seconds, peak = run_and_analyse(directory, args.trials)
    per_trial = (peak - fixed) / logged
    print(f"trials: {logged:,}")
    print(f"run: {run_seconds:.1f} s")
    print(f"analyze: {analyse_seconds:.1f} s, peak memory {peak / 1024**3:.2f} GiB")
    print(f"analyze of ~1,000 trials (the libraries' fixed cost): {fixed / 1024**2:.0f} MiB")
    print(f"memory per trial above it: {per_trial:.0f} bytes")
    if args.trials >= 1_000_000:
        verdict = "within" if peak <= LIMIT_BYTES else "ABOVE"
        print(f"{verdict} the 2 GiB target ({peak / LIMIT_BYTES:.2f} x)")


if __name__ == "__main__":
    main()
