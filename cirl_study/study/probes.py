"""A calibration's probes: each universe its refinement measures, played as a run of its own.

A *probe* of a multiverse run is a universe the run may lack: the universe nearest a target
with other values of its numeric settings (:mod:`cirl_study.analysis.calibration.refine`). Its
pipeline (:func:`probe_pipeline`) is a multiverse of that universe, written as a pipeline file of
its own: the run's seed and subjects, the tables of the probe's cross-validation universe
(:func:`~cirl_study.study.multiverse.tables_universe`: the probe with the run's base robot and
its eta cross-validated), and, where the probe differs from that (another robot, a fixed eta
or another measure to choose it on, or a reading of regret), the probe as the one entry of
``[[multiverse.universes]]``. Universe ids and trial seeds depend on the choices alone
(:mod:`cirl_study.study.plan`), so a probe's trials are those the run would have played for
the universe had it listed it, its cross-validation included; a probe of another robot than
the base's, or with a fixed eta, also plays that universe's ``main`` block (and its
cross-validation), its pipeline's base.

A probe lives in ``<probes>/<universe id>/``: its logs, played by
:func:`~cirl_study.study.runner.run_pipeline` (locked, resumable, and refused where the
directory holds another pipeline's logs, as ``cirl-study run`` refuses it), and its pipeline
file :data:`PIPELINE_FILE_NAME`, written once the run is complete (so ``cirl-study run
<probe>/pipeline.toml --out <probe>`` resumes or checks it); its directory is then read as
any run is analysed. A probe played before is found complete, not replayed. A symbolic link
in place of a probe's directory or of its pipeline file is refused, as is a pipeline file
there that holds another text.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from cirl_study.errors import UserError
from cirl_study.escape import terminal
from cirl_study.files import non_regular, read_regular_file, write_file
from cirl_study.logs.format import MAX_PIPELINE_BYTES
from cirl_study.record import GRADIENT_ASCENT
from cirl_study.study.engines import Engine
from cirl_study.study.multiverse import tables_universe, universe_pipeline
from cirl_study.study.pipeline_file import parse_pipeline
from cirl_study.study.runner import ProgressHooks, run_pipeline
from cirl_study.study.settings import written
from cirl_study.study.spec import AXES, PROBE_SUFFIX, GradientAscentSpec, Pipeline, Universe

PIPELINE_FILE_NAME = "pipeline.toml"
"""The pipeline file in a probe's directory."""


@dataclass(frozen=True)
class Probe:
    """A probe played (or found complete): its universe and directory, and the trials played
    by this call (0: reused)."""

    universe: Universe
    directory: Path
    played: int


def probe_directory(probes: Path, universe: Universe) -> Path:
    """Where the probe of ``universe`` lives below the directory of probes ``probes``."""
    return probes / universe.id


def _toml_value(value: Any) -> str:
    """``value`` (a bool, number, string, or a list or table of them) as TOML."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(value, Mapping):
        pairs = (f"{_toml_value(key)} = {_toml_value(item)}" for key, item in value.items())
        return "{" + ", ".join(pairs) + "}"
    return "[" + ", ".join(_toml_value(item) for item in value) + "]"


def _table(name: str, entries: Mapping[str, Any], header: str = "[{}]") -> list[str]:
    """The lines of the TOML table ``name`` of ``entries``, and a blank line."""
    return [header.format(name), *(f"{k} = {_toml_value(v)}" for k, v in entries.items()), ""]


def _settings(spec: Any) -> dict[str, Any]:
    """The keys of a spec's table as a pipeline file writes them (:func:`written`: its derived
    fields, the keys without a place and the optional ones at their default left out)."""
    return written(spec)


def probe_text(pipeline: Pipeline, universe: Universe) -> str:
    """The text of the pipeline file of the probe of ``universe`` in the multiverse run of
    ``pipeline`` (see the module docstring)."""
    # The file keeps the run's eta grid: another grid is a level of the universe (its base
    # reads none), so the entry names it.
    cv = replace(tables_universe(pipeline, universe), eta_grid=None)
    study = universe_pipeline(pipeline, cv)
    ascent = None
    if cv.robot == GRADIENT_ASCENT:
        ascent = study.gradient_ascent
    elif universe.robot == GRADIENT_ASCENT:
        ascent = GradientAscentSpec(
            steps=universe.ascent_steps, learning_rate=universe.learning_rate
        )
    entry = {
        name: axis.written(getattr(universe, name))
        for name, axis in AXES.items()
        if getattr(universe, name) is not None and getattr(universe, name) != getattr(cv, name)
    }
    top = {
        "name": f"{pipeline.name}{PROBE_SUFFIX}",
        "description": f"A probe of the calibration of the run {pipeline.run_id}: {universe.id}",
        "seed": pipeline.seed,
    }
    lines = [
        "# Written by cirl-study calibrate --refine: one universe of a multiverse run, played",
        "# as a run of its own (docs/multiverse.md, Refinement).",
        *(f"{k} = {_toml_value(v)}" for k, v in top.items()),
        "",
        *_table("game", _settings(study.game)),
        *_table("eta_cv", _settings(study.eta_cv)),
        *_table("main", _settings(study.main)),
        *([] if ascent is None else _table("gradient_ascent", _settings(ascent))),
        *(_table("multiverse.universes", entry, "[[{}]]") if entry else ["[multiverse]"]),
    ]
    return "\n".join(lines).rstrip("\n") + "\n"


def probe_pipeline(pipeline: Pipeline, universe: Universe, path: Path) -> Pipeline:
    """The pipeline of the probe of ``universe`` (:func:`probe_text`), as its file at ``path``
    is read: validated as any pipeline file is, limits included.

    Raises:
        UserError: the probe's pipeline passes a limit of one run.
    """
    study = parse_pipeline(probe_text(pipeline, universe), path)
    if study.multiverse is None or universe not in study.multiverse.universes:
        raise RuntimeError(f"the pipeline of the probe {universe.id} does not hold it")
    return study


def play_probe(
    pipeline: Pipeline,
    universe: Universe,
    probes: Path,
    engine: Engine,
    progress: ProgressHooks | None = None,
) -> Probe:
    """Play the probe of ``universe`` of the multiverse run of ``pipeline`` below ``probes``
    on ``engine`` (not yet entered), or resume it (see the module docstring).

    Raises:
        UserError: the probe's directory or pipeline file is a symbolic link, the pipeline
            file holds another text, the directory holds another pipeline's logs, a limit
            of one run is passed, or the run stops.
    """
    directory = probe_directory(probes, universe)
    path = directory / PIPELINE_FILE_NAME
    for entry in (directory, path):
        if entry.is_symlink():
            raise UserError(f"{terminal(entry)}: is a symbolic link; refusing to write through it")
    study = probe_pipeline(pipeline, universe, path)
    written = read_regular_file(path, MAX_PIPELINE_BYTES) if path.exists() else None
    if written is not None and written != study.text.encode():
        raise UserError(
            f"{terminal(path)}: holds another pipeline than this probe's; move the directory "
            "out of the way, or give another --probes"
        )
    result = run_pipeline(study, directory, engine, progress)
    if written is None:
        reason = non_regular(path)
        if reason is not None:
            raise UserError(f"{terminal(path)}: {reason}; refusing to write to it")
        write_file(path, study.text.encode())
    return Probe(universe=universe, directory=directory, played=result.played)
