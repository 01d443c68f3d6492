"""What the commands share about their parameters: the usage line, and a plain one-line
message for a value a parameter does not take.

typer writes a required argument ``{RUN}`` in the usage line; :class:`Command` writes it as
click does, ``RUN`` (an optional one stays ``[PIPELINE]``). typer checks an enum's or a
number's value with pydantic, whose messages read ``Value error, 'foo' is not one of
'local', 'dask'.`` or ``Input should be a valid integer, unable to parse string as an
integer``; the parsers :func:`choice` and :func:`number` (typer's ``parser=``) say instead
``'foo' is not one of: local, dask.``, which click prints after ``Invalid value for
'--engine':``.
"""

from __future__ import annotations

from collections.abc import Callable
from enum import Enum
from pathlib import Path
from typing import Annotated, Any, TypeVar

import typer
from typer.core import TyperCommand

from cirl_study.escape import terminal
from cirl_study.files import RUNS_DIRECTORY

Choice = TypeVar("Choice", bound=Enum)
Number = TypeVar("Number", int, float)


class Command(TyperCommand):
    """A typer command whose usage line names its arguments as click does: ``RUN`` when
    required, ``[PIPELINE]`` when not, ``...`` after one taking several values."""

    def collect_usage_pieces(self, ctx: Any) -> list[str]:
        pieces = [self.options_metavar] if self.options_metavar else []
        for param in self.get_params(ctx):
            if param.param_type_name != "argument":
                pieces += param.get_usage_pieces(ctx)
                continue
            name = param.metavar or (param.name or "").upper()
            if param.nargs != 1:
                name += "..."
            pieces.append(name if param.required else f"[{name}]")
        return pieces


def choice(kind: type[Choice]) -> Callable[[Any], Choice]:
    """The parser of an option taking one of the values of the enum ``kind``, exactly as
    written (case included)."""
    values = ", ".join(str(member.value) for member in kind)

    def parse(value: Any) -> Choice:
        try:
            return kind(value)
        except ValueError:
            raise typer.BadParameter(f"'{terminal(value)}' is not one of: {values}.") from None

    return parse


def number(kind: type[Number], what: str, minimum: Number | None = None) -> Callable[[Any], Number]:
    """The parser of an option taking a number of type ``kind`` (``int`` or ``float``), no
    smaller than ``minimum`` if given; ``what`` names such a number in the message (``a
    number >= 0``). NaN is refused where there is a minimum: it is no larger than anything."""

    def parse(value: Any) -> Number:
        try:
            parsed = kind(value)
        except (TypeError, ValueError):
            parsed = None
        if parsed is None or (minimum is not None and not parsed >= minimum):
            raise typer.BadParameter(f"'{terminal(value)}' is not {what}.")
        return parsed

    return parse


def run_directory(value: Any) -> Path:
    """``RUN``: a run directory; or, where no such path exists, the name of a pipeline whose
    run is where ``cirl-study run NAME`` puts it, ``data/runs/NAME``.

    >>> run_directory("data/runs/paper")
    PosixPath('data/runs/paper')
    """
    path = Path(value)
    if not path.exists() and len(path.parts) == 1 and (RUNS_DIRECTORY / path).is_dir():
        return RUNS_DIRECTORY / path
    return path


RunArgument = Annotated[
    Path,
    typer.Argument(
        metavar="RUN",
        help="Run directory holding the *.mcap log files, e.g. data/runs/paper; or the name "
        "of a pipeline whose run is in data/runs, e.g. paper.",
        parser=run_directory,
        show_default=False,
    ),
]
