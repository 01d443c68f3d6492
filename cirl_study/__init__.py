"""cirl-study: reproduce and extend Cooperative Inverse Reinforcement Learning.

Hadfield-Menell, Dragan, Abbeel and Russell, "Cooperative Inverse Reinforcement
Learning", NeurIPS 2016.

The Python API (:mod:`cirl_study.api`): :func:`run` plays a pipeline, :func:`load_trials`
returns a run's trials as a table, :func:`analyze` its results, typed. They load on first
use, so ``import cirl_study`` stays cheap for the command line.
"""

from __future__ import annotations

from typing import Any

from cirl_study.version import __version__

API = ("run", "load_trials", "analyze")
"""The functions of :mod:`cirl_study.api` this package exports."""

__all__ = ["__version__", *API]


def __getattr__(name: str) -> Any:
    if name in API:
        from cirl_study import api

        return getattr(api, name)
    raise AttributeError(f"module 'cirl_study' has no attribute {name!r}")
