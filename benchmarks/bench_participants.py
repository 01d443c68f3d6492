"""Time a study of people shaped like Ho et al.'s (2016): play every trial of it.

Usage::

    python benchmarks/bench_participants.py [--participants 58] [--repeats 3] [--workers 2]

Writes, in a temporary directory, a file of demonstrations of ``--participants`` people
(half told to do, half to show: between participants) on the 8 tasks of
``pipelines/tiles.toml``, each path a walk of up to 40 moves to the goal (each move towards
the goal with probability 0.6, else to a random neighbour; drawn from a fixed seed), and a
pipeline of that game with ``learning_steps = 40`` whose only human is ``recorded``, watched
by ``map`` and ``posterior_mean``. It then plays the run (``cirl_study.run``) ``--repeats``
times into fresh directories and prints the median wall time, kernels compiled beforehand
(the first run's compilation is timed by ``bench_compile.py``).
"""

from __future__ import annotations

import argparse
import csv
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

import cirl_study
from cirl_study.study.pipeline_file import load_pipeline

TILES = Path(__file__).resolve().parents[1] / "pipelines" / "tiles.toml"
MAX_MOVES = 40


def _pipeline_text() -> str:
    text = TILES.read_text()
    game = text[text.index("[game]") : text.index("[eta_cv]")]
    game = game.replace("learning_steps = 13", f"learning_steps = {MAX_MOVES}")
    return f"""name = "ho-shaped"
description = "People shaped like Ho et al.'s: 2 conditions between, 8 tasks within"
seed = 2016

{game}
[participants]
file = "moves.csv"
conditions = ["do", "show"]
design = "between"

[eta_cv]
subjects = 2
etas = [1.0]
rationality = 1.0

[main]
rationality = 1.0
humans = ["recorded"]
robots = ["map", "posterior_mean"]
"""


def _walks(directory: Path, participants: int) -> None:
    """Write the file of demonstrations: every participant's walk on every task."""
    spec = load_pipeline(TILES).game
    goal = spec.goals[0]
    width, height = spec.width, spec.height
    rng = np.random.default_rng(58)
    rows = []
    for number in range(1, participants + 1):
        condition = "do" if number % 2 else "show"
        for task in load_pipeline(TILES).tasks or ():
            while True:
                path = [tuple(spec.start)]
                while path[-1] != goal and len(path) <= MAX_MOVES:
                    x, y = path[-1]
                    steps = [(x + dx, y + dy) for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1))]
                    steps = [(a, b) for a, b in steps if 0 <= a < width and 0 <= b < height]
                    closer = [c for c in steps if abs(c[0] - goal[0]) + abs(c[1] - goal[1])
                              < abs(x - goal[0]) + abs(y - goal[1])]  # fmt: skip
                    pool = closer if closer and rng.random() < 0.6 else steps
                    path.append(pool[rng.integers(len(pool))])
                if path[-1] == goal:
                    break
            for step, (x, y) in enumerate(path):
                rows.append([f"P{number:02d}", condition, task.name, step, x, y])
    with (directory / "moves.csv").open("w", newline="") as stream:
        writer = csv.writer(stream, lineterminator="\n")
        writer.writerow(["participant", "condition", "task", "step", "x", "y"])
        writer.writerows(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--participants", type=int, default=58)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as temporary:
        directory = Path(temporary)
        _walks(directory, args.participants)
        (directory / "ho-shaped.toml").write_text(_pipeline_text())
        pipeline = load_pipeline(directory / "ho-shaped.toml")
        shown = pipeline.participants.shown().shown  # type: ignore[union-attr]
        moves = [len(s.recorded.path) - 1 for s in shown]
        print(
            f"{len(shown)} demonstrations of {args.participants} participants, "
            f"{min(moves)} to {max(moves)} moves (median {statistics.median(moves):g})"
        )
        cirl_study.run(directory / "ho-shaped.toml", directory / "warm", workers=1)
        times = []
        for repeat in range(args.repeats):
            out = directory / f"run-{repeat}"
            began = time.perf_counter()
            cirl_study.run(directory / "ho-shaped.toml", out, workers=args.workers)
            times.append(time.perf_counter() - began)
            shutil.rmtree(out)
        print(
            f"run of {2 * len(shown)} trials with {args.workers} workers: median "
            f"{statistics.median(times):.2f} s over {args.repeats} (each: "
            f"{', '.join(f'{t:.2f}' for t in times)})"
        )


if __name__ == "__main__":
    main()
