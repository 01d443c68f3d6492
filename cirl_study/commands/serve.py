"""``cirl-study serve``: collect a pipeline's demonstrations from people in a browser."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from cirl_study.commands.parameters import Command, number
from cirl_study.commands.run import PipelineArgument
from cirl_study.files import RUNS_DIRECTORY
from cirl_study.study.pipeline_file import load_pipeline, resolve_pipeline

app = typer.Typer(rich_markup_mode=None)
"""The ``serve`` command, merged into :data:`cirl_study.cli.app`."""

OutOption = Annotated[
    Path | None,
    typer.Option(
        "--out",
        metavar="DIR",
        show_default="data/runs/<pipeline name>",
        help="Run directory the demonstrations are stored in; `cirl-study run PIPELINE "
        "--out DIR` then plays the robots on them. Serving again resumes: participants "
        "continue where they were.",
    ),
]

HostOption = Annotated[
    str,
    typer.Option(
        "--host",
        help="Address to listen on; the default takes no connection from another machine "
        "(put a reverse proxy in front: docs/participants.md).",
    ),
]

_PORT = "a port number (0 to 65535)"


def _port(value: Any) -> int:
    """A TCP port, 0 to 65535 (0: one the system chooses)."""
    port = number(int, _PORT, 0)(value)
    if port > 65535:
        raise typer.BadParameter(f"'{port}' is not {_PORT}.")
    return port


PortOption = Annotated[
    int,
    typer.Option(
        "--port",
        metavar="N",
        parser=_port,
        help="Port to listen on; 0 lets the system choose one (printed).",
    ),
]


@app.command(cls=Command)
def serve(
    pipeline: PipelineArgument,
    out: OutOption = None,
    host: HostOption = "127.0.0.1",
    port: PortOption = 8000,
) -> None:
    """Run a pipeline's web experiment and store every demonstration in its run directory.

    The pipeline has [participants] collect = true and an [experiment] table. Prints the
    participants' address and the experimenter's status page (with a token new at each
    start); holds the run directory's lock until stopped (Ctrl-C).
    """
    from cirl_study.serve.server import serve as serve_experiment

    spec = load_pipeline(resolve_pipeline(pipeline))
    serve_experiment(spec, out or RUNS_DIRECTORY / spec.name, host, port, typer.echo)
