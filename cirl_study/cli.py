"""The ``cirl-study`` command line (a typer application).

Each command lives in the module that owns its job; this file only wires
them together and turns :class:`~cirl_study.errors.UserError` into a
one-line message and a non-zero exit code.
"""

from __future__ import annotations

import functools
import sys
from collections.abc import Callable
from typing import Annotated, Any

import typer

from cirl_study import __version__
from cirl_study.errors import UserError

app = typer.Typer(
    name="cirl-study",
    help="Reproduce, question and extend Cooperative Inverse Reinforcement Learning "
    "(Hadfield-Menell et al., NeurIPS 2016).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


def user_errors_as_one_line(command: Callable[..., Any]) -> Callable[..., Any]:
    """Wrap a command so that a :class:`UserError` prints one line and exits non-zero."""

    @functools.wraps(command)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return command(*args, **kwargs)
        except UserError as error:
            typer.echo(f"error: {error}", err=True)
            raise typer.Exit(code=error.exit_code) from None
        except KeyboardInterrupt:
            typer.echo("interrupted", err=True)
            raise typer.Exit(code=130) from None

    return wrapper


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


# --- commands -------------------------------------------------------------
# Each command module registers itself on `app` when imported below.
from cirl_study.commands import register_all  # noqa: E402

register_all(app, user_errors_as_one_line)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(app())
