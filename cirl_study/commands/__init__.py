"""Command modules of the ``cirl-study`` CLI.

Each module in :data:`COMMAND_MODULES` defines ``register(app, wrap)``, which adds
its command(s) to the typer ``app``; ``wrap`` turns user errors into one-line
messages (see :func:`cirl_study.cli.user_errors_as_one_line`).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

import typer

COMMAND_MODULES: tuple[str, ...] = ("run", "validate", "analyze", "reproduce", "office_supplies")


def register_all(
    app: typer.Typer, wrap: Callable[[Callable[..., Any]], Callable[..., Any]]
) -> None:
    """Import every command module and let it register its commands on ``app``."""
    for name in COMMAND_MODULES:
        module = importlib.import_module(f"cirl_study.commands.{name}")
        module.register(app, wrap)
