"""Reading a pipeline file: its text into the typed specs of :mod:`cirl_study.study.spec`.

:func:`load_pipeline` reads a file, :func:`parse_pipeline` a text (a file's, or the one a run's
logs carry: :func:`logged_pipeline`); both check the text's size, its TOML and nesting, every
setting against the constraint its spec declares beside the field
(:mod:`cirl_study.study.settings`), the rules that join tables (which tables a study has; a
multiverse's axes), and what the pipeline plans against the limits of one run
(:func:`cirl_study.study.limits.check_resources`). Every problem is one
:class:`~cirl_study.errors.UserError` line naming the file and the key.
:func:`resolve_pipeline` says which file a ``cirl-study run PIPELINE`` argument means.
"""

from __future__ import annotations

import codecs
import functools
import hashlib
import itertools
import math
import tomllib
from collections import ChainMap
from collections.abc import Callable
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

from cirl_study.errors import UserError
from cirl_study.escape import terminal
from cirl_study.logs.collection import COLLECTED_DIRECTORY, collected, collected_text
from cirl_study.logs.format import (
    MAX_PIPELINE_BYTES,
    PIPELINE_NAME_KEY,
    PIPELINE_SHA_KEY,
    PIPELINE_TEXT_KEY,
    RUN_ID_KEY,
)
from cirl_study.logs.provenance import RunIdentity
from cirl_study.logs.versions import pipeline_table
from cirl_study.record import RECORDED
from cirl_study.study.limits import check_resources, check_universe_count, single_study_problem
from cirl_study.study.participants import MAX_DEMONSTRATIONS_BYTES, file_text, read_demonstrations
from cirl_study.study.plan import trial_counts
from cirl_study.study.settings import Table, applies, shown
from cirl_study.study.spec import (
    AXES,
    MAX_NAME_LENGTH,
    PROBE_SUFFIX,
    EtaCVSpec,
    ExperimentSpec,
    GameSpec,
    GradientAscentSpec,
    LambdaSweepSpec,
    MainSpec,
    MultiverseSpec,
    ParticipantsSpec,
    Pipeline,
    Task,
    TeachingSpec,
    Universe,
)

PIPELINES_DIRECTORY = "pipelines"
"""Name of the directory that holds the pipeline files, at the repository root."""


MAX_PIPELINE_NESTING = 8
"""Most levels of tables and arrays a pipeline nests, its top table counting one. A valid
pipeline nests at most four (a multiverse axis: the file, ``[multiverse]``, ``cross`` and the
axis's list of levels); the bound leaves room for new keys and keeps every check of a value
far from the interpreter's recursion limit (the parser itself recurses at about 500 levels)."""

TOP_KEYS = (
    "name", "description", "seed", "game", "tasks", "eta_cv", "main", "lambda_sweep",
    "multiverse", "teaching", "gradient_ascent", "participants", "experiment",
)  # fmt: skip
"""The keys of a pipeline's top table, in the order they are checked."""


def parse_pipeline(
    text: str,
    path: Path,
    *,
    label: str | None = None,
    rename: Callable[[dict[str, Any]], dict[str, Any]] | None = None,
    demonstrations: str | None = None,
) -> Pipeline:
    """Validate the TOML ``text`` of the pipeline file ``path``, and what it plans against the
    limits of one run (:func:`cirl_study.study.limits.check_resources`).

    Every error is one line beginning with ``label``, by default ``path`` as the user sees it.
    ``rename`` maps the parsed table to the current names before it is read: how the text a
    log of an earlier format carries is read (:func:`cirl_study.logs.versions.pipeline_table`).
    A pipeline with ``[participants]`` reads its file of demonstrations, checked whole
    (:func:`cirl_study.study.participants.read_demonstrations`): ``demonstrations``, its text
    as a run's logs carry it, or else the file it names, beside ``path``.
    """
    label = _display_path(path) if label is None else label
    # A character is at least one byte: a text of too many is not encoded to be measured.
    _check_size(label, len(text) if len(text) > MAX_PIPELINE_BYTES else len(text.encode()))
    nested = f"nests deeper than {MAX_PIPELINE_NESTING} levels of tables and arrays"
    try:
        data = tomllib.loads(text, parse_float=_float)
    except tomllib.TOMLDecodeError as error:
        raise UserError(f"{label}: not valid TOML: {error}") from None
    except ValueError:  # Python's bound on the digits of an integer it converts from text
        raise UserError(
            f"{label}: holds an integer of more than {_MAX_INTEGER_DIGITS} digits, beyond "
            "the 64-bit integers a pipeline's numbers are held in"
        ) from None
    except RecursionError:
        raise UserError(f"{label}: {nested}") from None
    deep = _too_deep(data)
    if deep is not None:
        raise UserError(f"{label}: {deep} {nested}")
    _refuse_unheld_numbers(label, data)
    if rename is not None:
        data = rename(data)
    top = Table(label, "", data, TOP_KEYS)
    # The file is checked top to bottom, but for [gradient_ascent], which the universes read.
    name = top.setting(Pipeline, "name")
    description = top.setting(Pipeline, "description")
    seed = top.setting(Pipeline, "seed")
    game = top.spec("game", GameSpec)
    tasks = _tasks(top, game)
    eta_cv = top.spec("eta_cv", EtaCVSpec)
    main = top.spec("main", MainSpec, ChainMap({"game": game, "tasks": tasks}))
    lambda_sweep = _lambda_sweep(top, main)
    ascent = _ascent_table(top)
    study = Pipeline(
        name=name,
        description=description,
        seed=seed,
        game=game,
        tasks=tasks,
        eta_cv=eta_cv,
        main=main,
        lambda_sweep=lambda_sweep,
        path=path,
        text=text,
        sha256=hashlib.sha256(text.encode()).hexdigest(),
    )
    multiverse = None
    if "multiverse" in top.data:
        multiverse = _multiverse(top, replace(study, gradient_ascent=ascent), ascent)
    pipeline = replace(
        study,
        multiverse=multiverse,
        teaching=_teaching(top, game, main, tasks),
        gradient_ascent=_gradient_ascent(top, main, multiverse, ascent),
        participants=_participants(top, study, path, demonstrations),
    )
    pipeline = replace(pipeline, experiment=_experiment(top, pipeline))
    check_resources(pipeline, label)
    return pipeline


def _tasks(top: Table, game: GameSpec) -> tuple[Task, ...] | None:
    """``[tasks]``, where it has a place (a tile game's; :class:`~cirl_study.study.spec.Pipeline`)
    and is given."""
    (declared,) = (f for f in fields(Pipeline) if f.name == "tasks")
    known = ChainMap({"game": game})
    if not applies(declared, known):
        if "tasks" in top.data:
            top.fail("tasks", f"must not be given {declared.metadata['only'](known)}")
        return None
    return top.setting(Pipeline, "tasks", known) if "tasks" in top.data else None


def _lambda_sweep(top: Table, main: MainSpec) -> LambdaSweepSpec | None:
    """``[lambda_sweep]``: required in a single study without a hypothesis space, refused in
    the others (:class:`~cirl_study.study.spec.Pipeline`)."""
    if "multiverse" in top.data:
        if "lambda_sweep" in top.data:
            top.fail(
                "lambda_sweep",
                "must not be given with [multiverse] (lambda is one of its axes: rationality)",
            )
        return None
    from cirl_study.core.players import HUMANS

    people = any(HUMANS[human].recorded for human in main.humans)
    for table in ("teaching", "participants"):
        if table in top.data or (table == "participants" and people):
            if "lambda_sweep" in top.data:
                top.fail(
                    "lambda_sweep", f"must not be given with [{table}] (its study has no sweep)"
                )
            return None
    return top.spec("lambda_sweep", LambdaSweepSpec, ChainMap({"main": main}))


def _participants(
    top: Table, study: Pipeline, path: Path, logged: str | None
) -> ParticipantsSpec | None:
    """``[participants]``: required exactly when the ``recorded`` human plays, in a single
    study of ``[tasks]``; its file of demonstrations read and checked whole (``logged``, its
    text as a run's logs carry it, else the file beside ``path``). A collecting pipeline's
    demonstrations are read with its run directory (:func:`with_collected`)."""
    from cirl_study.core.players import HUMANS

    recorded = [human for human in study.main.humans if HUMANS[human].recorded]
    if "participants" not in top.data:
        if recorded:
            top.fail(
                "participants", f"is missing ({recorded[0]} shows participants' demonstrations)"
            )
        return None
    if not recorded:
        top.fail("participants", f"must not be given without the {RECORDED} human in main.humans")
    if "multiverse" in top.data:
        top.fail("participants", "must not be given with [multiverse]")
    if study.tasks is None:
        top.fail("participants", "must not be given without [tasks] (the tasks people show)")
    spec = top.spec("participants", ParticipantsSpec)
    if (spec.file is None) == (not spec.collect):
        top.fail("participants", "must give exactly one of file and collect = true")
    if spec.collect:
        return spec  # collected in the run directory: with_collected
    label = f"{top.label}: participants.file {spec.file}"
    if logged is None:
        file = path.parent / str(spec.file)
        try:
            with file.open("rb") as stream:
                raw = stream.read(MAX_DEMONSTRATIONS_BYTES + 1)
        except OSError as error:
            raise UserError(f"{label}: cannot read: {error.strerror}") from None
        logged = file_text(raw, label)
    shown = read_demonstrations(
        logged, label, study.game, study.tasks, spec.conditions, spec.within
    )
    return replace(spec, demonstrations=shown)


def _experiment(top: Table, pipeline: Pipeline) -> ExperimentSpec | None:
    """``[experiment]``: given only where ``cirl-study serve`` collects the demonstrations
    (``participants.collect = true``), which refuses a pipeline without it."""
    if "experiment" not in top.data:
        return None
    participants = pipeline.participants
    if participants is None or not participants.collect:
        top.fail(
            "experiment",
            "must not be given unless participants.collect = true (it describes the web "
            "experiment that collects the demonstrations)",
        )
    known = ChainMap({"game": pipeline.game, "tasks": pipeline.tasks, "participants": participants})
    return top.spec("experiment", ExperimentSpec, known)


def with_collected(pipeline: Pipeline, run_dir: Path) -> Pipeline:
    """``pipeline`` with the demonstrations collected in ``run_dir`` (a ``collect = true``
    pipeline's, :mod:`cirl_study.logs.collection`), checked as a file of them is; any other
    pipeline as it is.

    Raises:
        UserError: a collected demonstration is damaged, of another run, or not a legal one.
    """
    spec = pipeline.participants
    if spec is None or not spec.collect:
        return pipeline
    text = collected_text(collected(run_dir, pipeline.run_id))
    label = f"{run_dir / COLLECTED_DIRECTORY}"
    if len(text.splitlines()) < 2:
        raise UserError(f"{label}: no demonstration collected yet (cirl-study serve collects them)")
    shown = read_demonstrations(
        text, label, pipeline.game, pipeline.tasks or (), spec.conditions, spec.within
    )
    return replace(pipeline, participants=replace(spec, demonstrations=shown))


def _teaching(
    top: Table, game: GameSpec, main: MainSpec, tasks: tuple[Task, ...] | None
) -> TeachingSpec | None:
    """The ``[teaching]`` table: required exactly when a human or robot of ``main`` needs one."""
    from cirl_study.core.players import HUMANS, ROBOTS

    teaching = [p for p in main.humans if HUMANS[p].needs_hypotheses]
    teaching += [r for r in main.robots if ROBOTS[r].needs_hypotheses]
    if "teaching" not in top.data:
        if teaching:
            top.fail("teaching", f"is missing ({', '.join(teaching)} need a hypothesis space)")
        return None
    if "multiverse" in top.data:
        top.fail("teaching", "must not be given with [multiverse]")
    from cirl_study.core.hypotheses import MAX_PATHS

    spec = top.spec("teaching", TeachingSpec, ChainMap({"game": game, "tasks": tasks}))
    if spec.hypotheses == "tasks" and not spec.includes_truth:
        top.fail(
            "teaching.includes_truth",
            'must be true with hypotheses = "tasks" (each subject\'s task is one of them)',
        )
    if spec.learning_paths > MAX_PATHS:
        top.fail(
            "game.learning_steps",
            f"gives {spec.learning_paths:,} learning paths, more than the {MAX_PATHS:,} a "
            "hypothesis space enumerates",
        )
    return spec


def _multiverse(top: Table, study: Pipeline, ascent: GradientAscentSpec | None) -> MultiverseSpec:
    """The universes of ``[multiverse]``: the file's own (the base) first, then those of
    ``cross`` (a full factorial), ``alone`` (one level varied at a time) and ``universes``
    (listed), each once, in that order, each with the settings of its robot alone
    (:meth:`~cirl_study.study.spec.Universe.fitted`: ``ascent`` the ``[gradient_ascent]``
    table).

    ``study`` is the file's single study (its own settings, ``[gradient_ascent]`` as written,
    no multiverse). Before any universe is built, every level is held to the limits of a
    single study (:class:`_AxisLevels`), and the plan is counted from the axes
    (:func:`~cirl_study.study.limits.check_universe_count`).
    """
    game, eta_cv, main = study.game, study.eta_cv, study.main
    if len(study.name) > MAX_NAME_LENGTH - len(PROBE_SUFFIX):
        top.fail(
            "name",
            f"must be at most {MAX_NAME_LENGTH - len(PROBE_SUFFIX)} characters in a multiverse "
            f"(a calibration probe's pipeline is named <name>{PROBE_SUFFIX}), got "
            f"{len(study.name)} characters",
        )
    if game.tiles is not None:
        top.fail(
            "multiverse",
            f'must not be given with game.features = "{game.features}" (its universes vary '
            "the RBF features)",
        )
    if len(main.robots) != 1:
        top.fail("main.robots", "must name one robot in a multiverse (robot is one of its axes)")
    if game.learning_steps != game.deployment_steps:
        top.fail(
            "game.deployment_steps",
            "must equal game.learning_steps in a multiverse (one axis, steps, sets both)",
        )
    if eta_cv.rationality != main.rationality:
        top.fail(
            "eta_cv.rationality",
            "must equal main.rationality in a multiverse (one axis, rationality, sets both)",
        )
    base = Universe(**{name: axis.read(game, main) for name, axis in AXES.items()}).fitted(
        ascent, game.feature_levels
    )
    block = top.table("multiverse", ("cross", "alone", "universes"))
    levels = _AxisLevels(study)
    crossed: dict[str, list[Any]] = {}
    if "cross" in block.data:
        cross = block.table("cross", tuple(AXES))
        crossed = {axis: levels.of(cross, axis) for axis in AXES if axis in cross.data}
    varied: dict[str, list[Any]] = {}
    if "alone" in block.data:
        alone = block.table("alone", tuple(AXES))
        varied = {axis: levels.of(alone, axis) for axis in AXES if axis in alone.data}
    chosen: list[dict[str, Any]] = []
    if "universes" in block.data:
        listed = block.value("universes")
        if not isinstance(listed, list) or not all(isinstance(u, dict) for u in listed):
            block.fail("universes", f"must be an array of tables, got {shown(listed)}")
        for position, entry in enumerate(listed):
            table = Table(top.label, f"multiverse.universes[{position}].", entry, tuple(AXES))
            chosen.append({axis: levels.one(table, axis) for axis in AXES if axis in entry})
    # The universes that play trials: an axis of the analysis alone (regret) shares them.
    playing = {axis for axis in AXES if not AXES[axis].analysis_only}
    count = 1 + math.prod(len(each) for axis, each in crossed.items() if axis in playing)
    count += sum(len(each) for axis, each in varied.items() if axis in playing) + len(chosen)
    check_universe_count(top.label, count, sum(trial_counts(study).values()))
    universes = [base]
    universes += [
        replace(base, **dict(zip(crossed, choice, strict=True)))
        for choice in itertools.product(*crossed.values())
    ]
    universes += [replace(base, **{axis: one}) for axis, each in varied.items() for one in each]
    universes += [replace(base, **choice) for choice in chosen]
    fitted = (u.fitted(ascent, game.feature_levels) for u in universes)
    return MultiverseSpec(base, tuple(dict.fromkeys(fitted)))


class _AxisLevels:
    """Validation of an axis's levels: the range the same setting has in ``[game]``/``[main]``
    (:attr:`Axis.levels`), and the limits of a single study: ``study`` (the file's own, no
    multiverse) with the level set (:attr:`Axis.apply`) must pass
    :func:`~cirl_study.study.limits.single_study_problem`, as the same value given in
    ``[game]`` or ``[main]`` would (``steps`` sets both horizons, whose batch must fit)."""

    def __init__(self, study: Pipeline):
        self.study = study
        self.checks = {name: axis.levels(study.game) for name, axis in AXES.items()}
        self.passed: set[tuple[str, Any]] = set()

    def of(self, table: Table, axis: str) -> list[Any]:
        """The distinct levels ``table[axis]`` lists."""
        ok, what = self.checks[axis]
        value = table.value(axis)
        if not isinstance(value, list) or not value or not all(ok(v) for v in value):
            table.fail(axis, f"must be a non-empty list of {what}, got {shown(value)}")
        converted = [AXES[axis].convert(v) for v in value]
        if len(set(converted)) != len(converted):
            table.fail(axis, f"must not repeat a level, got {shown(value)}")
        return [self._within_limits(table, axis, level) for level in converted]

    def one(self, table: Table, axis: str) -> Any:
        """The one level ``table[axis]`` names."""
        ok, what = self.checks[axis]
        value = table.value(axis)
        if not ok(value):
            table.fail(axis, f"must be one of {what}, got {shown(value)}")
        return self._within_limits(table, axis, AXES[axis].convert(value))

    def _within_limits(self, table: Table, axis: str, level: Any) -> Any:
        """``level`` of ``axis``, once the single study of that level is within the limits."""
        if (axis, level) not in self.passed:
            problem = single_study_problem(AXES[axis].apply(self.study, level))
            if problem is not None:
                table.fail(axis, f"level {shown(level)}: {problem}")
            self.passed.add((axis, level))
        return level


def _ascent_table(top: Table) -> GradientAscentSpec | None:
    """``[gradient_ascent]`` as written, if it is (:func:`_gradient_ascent` says whether it
    must be)."""
    return (
        top.spec("gradient_ascent", GradientAscentSpec) if "gradient_ascent" in top.data else None
    )


def _gradient_ascent(
    top: Table,
    main: MainSpec,
    multiverse: MultiverseSpec | None,
    ascent: GradientAscentSpec | None,
) -> GradientAscentSpec | None:
    """The ``[gradient_ascent]`` table ``ascent``: required exactly when the
    ``gradient_ascent`` robot plays, in ``main.robots`` or as a multiverse's ``robot`` level."""
    from cirl_study.record import GRADIENT_ASCENT

    universes = () if multiverse is None else multiverse.universes
    plays = GRADIENT_ASCENT in main.robots or any(u.robot == GRADIENT_ASCENT for u in universes)
    if ascent is None:
        if plays:
            top.fail("gradient_ascent", f"is missing (robot {GRADIENT_ASCENT} needs its settings)")
        return None
    if not plays:
        top.fail("gradient_ascent", f"is given, but robot {GRADIENT_ASCENT} does not play")
    return ascent


def _too_deep(data: dict[str, Any]) -> str | None:
    """The key of ``data`` (a parsed TOML document) whose value nests past
    :data:`MAX_PIPELINE_NESTING` levels, if any (found without recursion)."""
    pending: list[tuple[object, int, str]] = [(data, 1, "")]
    while pending:
        value, depth, key = pending.pop()
        if isinstance(value, dict):
            children = [(f"{key}.{k}" if key else k, v) for k, v in value.items()]
        elif isinstance(value, list):
            children = [(key, v) for v in value]
        else:
            continue
        if depth > MAX_PIPELINE_NESTING:
            return key
        pending += [(child, depth + 1, name) for name, child in children]
    return None


INTEGER_RANGE = (-(2**63), 2**63 - 1)
"""The integers a pipeline may write: the signed 64-bit ones, in which its counts, sizes and
seeds are computed (a larger one would overflow where it meets a float or an array)."""

_MAX_INTEGER_DIGITS = 4300
"""The most digits of an integer Python converts from text (:func:`sys.get_int_max_str_digits`
by default); TOML's parser raises past it."""


class _UnheldFloat:
    """A TOML float no 64-bit float holds: its literal overflows to an infinity or underflows
    to zero. Put in the parsed document in its place, and refused by
    :func:`_refuse_unheld_numbers` before any setting is read."""

    def __init__(self, text: str) -> None:
        self.text = text


def _float(text: str) -> float | _UnheldFloat:
    """A TOML float literal as a float, or as an :class:`_UnheldFloat` where rounding to a
    64-bit float would change it past recognition: ``1e400`` (to ``inf``; TOML's ``inf`` is
    written so) or ``1e-400`` (to ``0.0``)."""
    value = float(text)
    if math.isinf(value) and "inf" not in text:
        return _UnheldFloat(text)
    mantissa = text.lower().split("e")[0]
    if value == 0.0 and any(digit in mantissa for digit in "123456789"):
        return _UnheldFloat(text)
    return value


def _refuse_unheld_numbers(label: str, data: dict[str, Any]) -> None:
    """Refuse, in one line naming its key, a number of ``data`` (a parsed TOML document)
    outside what the study computes with: an integer outside :data:`INTEGER_RANGE`, a float
    past the 64-bit floats (:class:`_UnheldFloat`)."""
    low, high = INTEGER_RANGE
    pending: list[tuple[object, str]] = [(data, "")]
    while pending:
        value, key = pending.pop()
        if isinstance(value, dict):
            pending += [(v, f"{key}.{k}" if key else k) for k, v in reversed(value.items())]
        elif isinstance(value, list):
            pending += [(v, key) for v in reversed(value)]
        elif isinstance(value, _UnheldFloat):
            kind = "overflows" if math.isinf(float(value.text)) else "underflows"
            raise UserError(
                f"{label}: {key} holds {shown(value.text)[1:-1]}, which {kind} a 64-bit float "
                "(magnitudes from about 5e-324 to 1.8e308)"
            )
        elif isinstance(value, int) and not isinstance(value, bool) and not low <= value <= high:
            raise UserError(
                f"{label}: {key} holds an integer of {len(str(abs(value)))} digits, beyond "
                f"the 64-bit integers a pipeline's numbers are held in ({low} to {high})"
            )


def _display_path(path: Path) -> str:
    """``path`` relative to the current directory when it lies below it, else as given."""
    try:
        return str(path.resolve().relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(path)


def path_argument(path: Path) -> str:
    """``path`` as a command the user is told to run names it, and as a run records where it
    found its pipeline file: relative to the current directory when it lies below it, else
    absolute. It never reads as a pipeline's name, which ``cirl-study run`` would look up among
    the shipped pipelines (:func:`resolve_pipeline`), nor as an option: a file of the current
    directory itself is ``./name``, as is a relative path that starts with ``-``.
    """
    resolved = path.resolve()
    try:
        shown = str(resolved.relative_to(Path.cwd().resolve()))
    except ValueError:
        return str(resolved)
    return shown if "/" in shown and not shown.startswith("-") else f"./{shown}"


def _check_size(label: str, size: int) -> None:
    """Refuse a pipeline of more than :data:`MAX_PIPELINE_BYTES` (its text, or as much of its
    file as was read)."""
    if size > MAX_PIPELINE_BYTES:
        raise UserError(
            f"{label}: more than {MAX_PIPELINE_BYTES} bytes, too large for a pipeline file"
        )


def load_pipeline(path: Path) -> Pipeline:
    """Read and validate the pipeline file at ``path``."""
    try:
        with path.open("rb") as stream:
            raw = stream.read(MAX_PIPELINE_BYTES + 1)
    except OSError as error:
        raise UserError(f"{_display_path(path)}: cannot read: {error.strerror}") from None
    _check_size(_display_path(path), len(raw))
    if raw.startswith(codecs.BOM_UTF8):
        raise UserError(
            f"{_display_path(path)}: starts with a UTF-8 byte-order mark; save it as plain "
            "UTF-8 without one (TOML)"
        )
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise UserError(f"{_display_path(path)}: not valid TOML: not UTF-8 text") from None
    return parse_pipeline(text, path)


def logged_pipeline(identity: RunIdentity, run_dir: Path | None = None) -> Pipeline:
    """The pipeline a run's logs carry in their ``identity``, validated as a pipeline file is
    (its limits included), read in the identity's log format; its name must be the
    identity's ``pipeline_name`` and its run id (:attr:`~cirl_study.study.spec.Pipeline.run_id`:
    the name and the start of the hash) the identity's ``run_id``. Every reader of a run is
    given it (:data:`~cirl_study.logs.provenance.PipelineOf`). A collecting pipeline's
    demonstrations are those collected in ``run_dir`` (:func:`with_collected`; none without
    it), read once for every file of the run while the collection does not change.

    Raises:
        ValueError: any of these does not hold; the message names the provenance key.
        UserError: a collected demonstration is damaged, of another run, or not a legal one:
            the run directory's fault, not a file's.
    """
    try:
        pipeline = _parsed(
            identity.pipeline_text,
            identity.pipeline_file,
            identity.log_format,
            identity.demonstrations,
        )
    except UserError as error:
        raise ValueError(f"provenance's {error}") from None
    if identity.pipeline_name != pipeline.name:
        raise ValueError(
            f"provenance's {PIPELINE_NAME_KEY} '{terminal(identity.pipeline_name)}' is not "
            f"the name its {PIPELINE_TEXT_KEY} gives ({pipeline.name!r})"
        )
    if identity.run_id != pipeline.run_id:
        raise ValueError(
            f"provenance's {RUN_ID_KEY} '{terminal(identity.run_id)}' is not the run id of "
            f"its pipeline ({pipeline.run_id!r}: the name and the start of its "
            f"{PIPELINE_SHA_KEY})"
        )
    if run_dir is None or pipeline.participants is None or not pipeline.participants.collect:
        return pipeline
    return _collected_pipeline(pipeline, run_dir, _listing(run_dir / COLLECTED_DIRECTORY))


def pipelines_in(run_dir: Path) -> Callable[[RunIdentity], Pipeline]:
    """The :data:`~cirl_study.logs.provenance.PipelineOf` of the run in ``run_dir``:
    :func:`logged_pipeline` with the demonstrations collected there."""
    return functools.partial(logged_pipeline, run_dir=run_dir)


def _listing(folder: Path) -> tuple[tuple[str, int, int], ...]:
    """What identifies the collected files' contents: each one's name, size and change time."""
    if not folder.is_dir() or folder.is_symlink():
        return ()
    found = []
    for path in folder.glob("*/*.mcap"):
        status = path.lstat()
        found.append((str(path.relative_to(folder)), status.st_size, status.st_mtime_ns))
    return tuple(sorted(found))


@functools.lru_cache(maxsize=4)
def _collected_pipeline(
    pipeline: Pipeline, run_dir: Path, listing: tuple[tuple[str, int, int], ...]
) -> Pipeline:
    """:func:`with_collected`, once per collection (``listing``)."""
    return with_collected(pipeline, run_dir)


@functools.lru_cache(maxsize=4)
def _parsed(text: str, file: str, log_format: str, demonstrations: str) -> Pipeline:
    """A logged pipeline text parsed, once per process (every file of a run carries the same
    text, and each is checked by several readers), with the logged file of demonstrations
    (never a file the text names: a log makes no one read a file)."""
    rename = functools.partial(pipeline_table, log_format=log_format)
    return parse_pipeline(
        text,
        Path(file),
        label=PIPELINE_TEXT_KEY,
        rename=rename,
        demonstrations=demonstrations,
    )


def pipeline_search_path() -> tuple[Path, ...]:
    """Directories searched for a pipeline given by name, in order.

    ``./pipelines`` (the current directory's), then the ``pipelines`` directory at the
    root of the source tree this package is imported from (an editable install).
    """
    here = Path.cwd() / PIPELINES_DIRECTORY
    repository = Path(__file__).resolve().parents[2] / PIPELINES_DIRECTORY
    return (here,) if here.resolve() == repository else (here, repository)


def resolve_pipeline(name_or_path: str) -> Path:
    """The file a ``cirl-study run PIPELINE`` argument means.

    An existing file is taken as it is; otherwise a bare name ``x`` (or ``x.toml``)
    is looked up as ``x.toml`` in :func:`pipeline_search_path`.
    """
    given = Path(name_or_path)
    if given.is_file():
        return given
    if given.is_dir():
        raise UserError(f"{name_or_path}: is a directory, not a pipeline file")
    if given.name == name_or_path:
        file_name = name_or_path if name_or_path.endswith(".toml") else f"{name_or_path}.toml"
        for directory in pipeline_search_path():
            candidate = directory / file_name
            if candidate.is_file():
                return candidate
        available = sorted(
            {p.stem for d in pipeline_search_path() if d.is_dir() for p in d.glob("*.toml")}
        )
        known = f"known pipelines: {', '.join(available)}" if available else "none shipped"
        if name_or_path.endswith(".toml"):
            raise UserError(f"{name_or_path}: no such file, nor a shipped pipeline ({known})")
        raise UserError(f"no pipeline named {name_or_path!r} ({known})")
    raise UserError(f"{name_or_path}: no such pipeline file")
