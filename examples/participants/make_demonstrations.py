"""Write the file of demonstrations of ``pipelines/people.toml``, by simulated participants.

A stand-in for a lab's data, in the shape ``[participants]`` reads (docs/participants.md):
24 participants on Ho et al.'s coloured tiles (the game and tasks of ``pipelines/tiles.toml``),
12 told to *do* the task and 12 told to *show* it, each demonstrating the 8 tasks once in an
order of her own. A doer is the Boltzmann-rational ``literal`` human at rationality 8 (close
to the optimal path, with a person's slips); a shower is Ho et al.'s ``pedagogic`` human, who
draws her path from her teaching distribution. Each participant draws from her own seed, so
the file is the same on every machine; each move takes a lognormal time (median 0.6 s for a
doer, 0.9 s for a shower, who plans for an observer), after a first look of about 2 s.

Run from the repository root::

    python examples/participants/make_demonstrations.py
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np
from msgspec.structs import replace

from cirl_study.core.gridworld import gridworld
from cirl_study.core.trial import demonstrations
from cirl_study.record import LITERAL, MAIN, PEDAGOGIC
from cirl_study.study.pipeline_file import load_pipeline
from cirl_study.study.plan import random_stream, study_trials

PARTICIPANTS_PER_CONDITION = 12
DOER_RATIONALITY = 8.0
SEED = 2016
OUT = Path("pipelines/people/demonstrations.csv")


def main() -> None:
    tiles = load_pipeline(Path("pipelines/tiles.toml"))
    template = {
        spec.task: spec
        for spec in study_trials(tiles, {(None, "best_response", 4): 1.0})
        if spec.block == MAIN and spec.human == PEDAGOGIC and spec.robot == "map"
    }
    rows = []
    for number in range(1, 2 * PARTICIPANTS_PER_CONDITION + 1):
        condition = "do" if number % 2 else "show"
        participant = f"P{number:02d}"
        rng = np.random.default_rng(random_stream(SEED, f"participant:{participant}"))
        order = rng.permutation(sorted(template))
        specs = []
        for task in order:
            spec = template[task]
            if condition == "do":
                spec = replace(spec, human=LITERAL, teaching=None, rationality=DOER_RATIONALITY)
            specs.append(replace(spec, seed=int(rng.integers(2**53))))
        paths = demonstrations(specs)
        for position, (spec, path) in enumerate(zip(specs, paths, strict=True), start=1):
            grid = gridworld(spec)
            cells = [grid.coords(int(c)) for c in path if c < grid.num_cells]
            median = 0.6 if condition == "do" else 0.9
            gaps = rng.lognormal(np.log(median), 0.4, size=len(cells) - 1)
            seconds = np.concatenate([[0.0], 2.0 * rng.lognormal(0, 0.3) + np.cumsum(gaps)])
            for step, ((x, y), time) in enumerate(zip(cells, seconds, strict=True)):
                rows.append(
                    [participant, condition, spec.task, step, x, y, f"{time:.3f}", position]
                )
    OUT.parent.mkdir(parents=True, exist_ok=True)
    with OUT.open("w", newline="") as stream:
        writer = csv.writer(stream, lineterminator="\n")
        writer.writerow(["participant", "condition", "task", "step", "x", "y", "seconds", "order"])
        writer.writerows(rows)
    print(
        f"{OUT}: {len(rows)} moves of {2 * PARTICIPANTS_PER_CONDITION} participants",
        file=sys.stderr,
    )


if __name__ == "__main__":
    main()
