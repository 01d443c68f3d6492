"""The ``cirl-study`` command line (a typer application).

Each command lives in its own module of :mod:`cirl_study.commands`, as a typer app with one
``@app.command()``; this file merges them into one application (typer's ``add_typer`` without
a name) and is the one place where a :class:`~cirl_study.errors.UserError` becomes a one-line
message and a non-zero exit code, and a stopping signal (Ctrl-C, SIGTERM, SIGHUP: see
:mod:`cirl_study.interrupts`) one line and 128 + the signal's number.
"""

from __future__ import annotations

from typing import Annotated, Any

import typer
from typer.core import TyperGroup

from cirl_study import interrupts
from cirl_study.commands import (
    analyze,
    calibrate,
    compare,
    office_supplies,
    reproduce,
    run,
    serve,
    show,
    validate,
)
from cirl_study.errors import UserError
from cirl_study.escape import terminal
from cirl_study.version import __version__


class _Commands(TyperGroup):
    """The commands of ``cirl-study``, with user errors reported in one line, never a traceback."""

    def invoke(self, ctx: Any) -> Any:
        try:
            return super().invoke(ctx)
        except UserError as error:
            typer.echo(f"error: {terminal(error, limit=None)}", err=True)
            raise typer.Exit(error.exit_code) from None
        except KeyboardInterrupt as interrupt:
            raise typer.Exit(interrupts.report(interrupt)) from None


app = typer.Typer(
    name="cirl-study",
    cls=_Commands,
    help="Reproduce, question and extend Cooperative Inverse Reinforcement Learning "
    "(Hadfield-Menell et al., NeurIPS 2016).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    # Plain click help: paragraphs reflowed to the terminal's width, flags without a type.
    rich_markup_mode=None,
)
for command in (
    run,
    serve,
    validate,
    show,
    analyze,
    calibrate,
    reproduce,
    compare,
    office_supplies,
):
    app.add_typer(command.app)


def _print_version(value: bool) -> None:
    if value:
        typer.echo(f"cirl-study {__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_print_version, is_eager=True, help="Print the version and exit."
        ),
    ] = False,
) -> None:
    """Reproduce, question and extend Cooperative Inverse Reinforcement Learning."""
