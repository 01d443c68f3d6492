"""``cirl-study run``: run (or resume) a pipeline and log every trial."""

from __future__ import annotations

import math
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from cirl_study.commands.parameters import Command, choice, number
from cirl_study.errors import UserError
from cirl_study.escape import terminal
from cirl_study.study.pipeline_file import load_pipeline, resolve_pipeline

app = typer.Typer(rich_markup_mode=None)
"""The ``run`` command, merged into :data:`cirl_study.cli.app`."""

if TYPE_CHECKING:
    from cirl_study.study.runner import RunResult


class EngineName(StrEnum):
    """The engines ``--engine`` accepts."""

    local = "local"
    dask = "dask"


def _summary(result: RunResult, engine: str) -> str:
    """Three lines: what is logged where, how fast, and the etas cross-validation chose.

    The rate is over the time spent playing (as the progress bar's), beside the whole wall
    time and the compute floor: the workers' own play time divided among them.
    """
    playing = result.playing_seconds
    rate = result.played / playing if playing > 0 else 0.0
    floor = result.play_seconds / result.workers
    universes = {universe for universe, _, _ in result.etas} - {None}
    if not result.etas:
        etas = "none (no human has a trade-off)"
    elif universes:
        fixed = sum(choice.fixed for choice in result.etas.values())
        etas = (
            f"{len(result.etas) - fixed} choices and {fixed} fixed etas in {len(universes)} "
            "universes (see the report)"
        )
    else:
        etas = "; ".join(
            f"{human} at K={k} -> {choice.eta:g} "
            f"(mean {choice.measure} {choice.means[choice.eta]:.4g})"
            for (_, human, k), choice in sorted(result.etas.items())
        )
    return "\n".join(
        [
            f"run {result.run_id}: {result.total} trials logged in {terminal(result.out_dir)} "
            f"({result.files} files); {result.played} played now, "
            f"{result.resumed} were already logged",
            f"{result.seconds:.1f} s in all; playing {playing:.1f} s, {rate:.0f} trials/s, "
            f"{engine} (compute floor {floor:.1f} s)",
            f"eta by cross-validation: {etas}",
        ]
    )


PipelineArgument = Annotated[
    str,
    typer.Argument(
        metavar="PIPELINE",
        help="Pipeline file, or the name of one in pipelines/ (looked up in "
        "./pipelines, then in the pipelines/ directory of the cirl-study source tree).",
    ),
]

RunDirectoryOption = Annotated[
    Path | None,
    typer.Option(
        "--out",
        metavar="DIR",
        show_default="data/runs/<pipeline name>",
        help="Run directory for the MCAP logs. Running again into the same directory "
        "resumes: trials already logged are skipped. A directory holding another "
        "pipeline's logs is refused.",
    ),
]

WorkersOption = Annotated[
    int | None,
    typer.Option(
        "--workers",
        metavar="N",
        parser=number(int, "an integer"),
        help="Trials played at once: worker processes of the local pool, or workers of "
        "the local Dask cluster; 1 plays in this process. Results do not depend on it.",
        show_default="all cores",
    ),
]

EngineOption = Annotated[
    EngineName,
    typer.Option(
        "--engine",
        parser=choice(EngineName),
        help="Where trials are played: 'local' (a process pool on this machine) or "
        "'dask' (Dask distributed; needs the dask extra: pip install -e '.[dask]' in a "
        "checkout, pip install 'cirl-study[dask]' otherwise). "
        "Results do not depend on it.",
    ),
]

SchedulerOption = Annotated[
    str | None,
    typer.Option(
        "--scheduler",
        metavar="ADDRESS",
        help="With --engine dask: address of a running Dask scheduler "
        "(e.g. tcp://10.0.0.1:8786), whose workers must have cirl-study installed. "
        "Without it a local Dask cluster is started.",
    ),
]

NoWorkersTimeoutOption = Annotated[
    float | None,
    typer.Option(
        "--no-workers-timeout",
        metavar="SECONDS",
        parser=number(float, "a number of seconds"),
        show_default="60",
        help="With --engine dask: how long the cluster may be without workers (its workers "
        "died, or it never had any) before the run stops, keeping every trial logged.",
    ),
]


@app.command(cls=Command)
def run(
    pipeline: PipelineArgument = "paper",
    out: RunDirectoryOption = None,
    workers: WorkersOption = None,
    engine: EngineOption = EngineName.local,
    scheduler: SchedulerOption = None,
    no_workers_timeout: NoWorkersTimeoutOption = None,
) -> None:
    """Run a study pipeline and log every trial to MCAP (resumable).

    Plays the eta cross-validation first, picks per number of features the eta with the
    lowest mean regret, then plays the main study and the lambda sweep. Progress goes to
    stderr, a summary to stdout.
    """
    # The engine and the runner import the numerical core, and the bar rich: only when a
    # run is asked for.
    from cirl_study.commands.progress import progress_bar
    from cirl_study.study.engines import make_engine
    from cirl_study.study.runner import default_out_dir, run_pipeline

    spec = load_pipeline(resolve_pipeline(pipeline))
    if workers is not None and workers < 1:
        raise UserError(f"--workers must be a positive integer, got {workers}")
    if scheduler is not None and engine is not EngineName.dask:
        raise UserError("--scheduler needs --engine dask")
    if no_workers_timeout is not None:
        if engine is not EngineName.dask:
            raise UserError("--no-workers-timeout needs --engine dask")
        if not 0 < no_workers_timeout < math.inf:
            raise UserError(
                f"--no-workers-timeout must be a positive number of seconds, "
                f"got {no_workers_timeout:g}"
            )
    chosen = make_engine(engine.value, workers, scheduler, no_workers_timeout)
    with progress_bar() as hooks:
        result = run_pipeline(spec, out or default_out_dir(spec), chosen, hooks)
    typer.echo(_summary(result, chosen.description))
