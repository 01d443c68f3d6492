"""A file of participants' demonstrations: what people showed, read and checked whole.

The file a pipeline's ``[participants]`` names (docs/participants.md) is a CSV table with one
row per cell of a demonstration, long and tidy, as experiment software logs a key press and as
Ho et al. (2016) published their data::

    participant,condition,task,step,x,y,seconds
    P01,show,oox,0,0,2,0.0
    P01,show,oox,1,1,2,1.42
    ...

* ``participant``: the participant's id (:data:`~cirl_study.record.ParticipantId`);
* ``condition``: one of the pipeline's ``participants.conditions``;
* ``task``: one of the pipeline's ``[tasks]``;
* ``step``: ``t = 0, 1, ..., T``, the cell's position in the path (``0`` the start);
* ``x``, ``y``: the cell ``s_t``;
* optional ``seconds``: when the participant arrived in the cell, since the task began;
* optional ``order``: the task's 1-based position in the participant's sequence.

One row per cell, rather than one row per demonstration with its path in a cell, because a
spreadsheet holds it without nested text, a move's time has a column of its own, and a table
of moves (Ho et al.'s has the action of each move) becomes it by a cumulative sum
(docs/participants.md shows the conversion). Rows may come in any order.

:func:`read_demonstrations` checks the whole file against the pipeline before anything is
played, each fault one :class:`~cirl_study.errors.UserError` line naming the file and line:
its size (:data:`MAX_DEMONSTRATIONS_BYTES`) and encoding; its columns; every value; each
demonstration's steps ``0..T`` once each, starting on the game's start, moving to a
neighbouring cell (or staying, where ``game.demonstrator_stays``) on the grid, and ending in a
goal on entering it within ``game.learning_steps`` moves (in a game with goals) or taking
exactly ``learning_steps`` moves (without); a participant's one demonstration of each task
(in each condition, ``design = "within"``) and, between participants, one condition.
The file is a text format, parsed by :mod:`csv`: nothing in it is executed or unpickled.
"""

from __future__ import annotations

import csv
import hashlib
import io
import math
import re
from collections.abc import Iterator, Sequence

from cirl_study.errors import UserError
from cirl_study.escape import terminal
from cirl_study.logs.format import MAX_DEMONSTRATIONS_BYTES
from cirl_study.record import Collected, Recorded
from cirl_study.study.spec import Demonstrations, GameSpec, Shown, Task

REQUIRED_COLUMNS = ("participant", "condition", "task", "step", "x", "y")
"""The columns every file has."""

OPTIONAL_COLUMNS = ("seconds", "order")
"""The columns a file may have."""

PARTICIPANT = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")
"""A participant's id (:data:`cirl_study.record.ParticipantId`)."""

_INTEGER = re.compile(r"[0-9]{1,9}")


def file_text(raw: bytes, label: str) -> str:
    """The text of a file of demonstrations read as ``raw`` (at most one byte more than
    :data:`MAX_DEMONSTRATIONS_BYTES`): UTF-8, a leading byte-order mark (a spreadsheet's "CSV
    UTF-8") dropped."""
    if len(raw) > MAX_DEMONSTRATIONS_BYTES:
        raise UserError(
            f"{label}: more than {MAX_DEMONSTRATIONS_BYTES >> 20} MiB, too large for a file of "
            "demonstrations"
        )
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as error:
        raise UserError(f"{label}: not UTF-8 text (byte {error.start})") from None


def read_demonstrations(
    text: str,
    label: str,
    game: GameSpec,
    tasks: Sequence[Task],
    conditions: Sequence[str],
    within: bool,
) -> Demonstrations:
    """The demonstrations of the CSV ``text`` (the file ``label``), every row checked against
    the ``game``, its ``tasks`` and the ``conditions`` (the module docstring); ``within``:
    each participant may show each task once in every condition, else in one condition only.

    Raises:
        UserError: the first fault, in one line: ``<label> line <n>: <what>``.
    """
    reader = csv.reader(io.StringIO(text, newline=""), strict=True)
    try:
        header = next(reader)
    except StopIteration:
        raise UserError(f"{label}: is empty; the first line names the columns") from None
    except csv.Error as error:
        raise UserError(f"{label} line 1: not CSV: {error}") from None
    columns = _columns(header, label)
    task_names = [task.name for task in tasks]
    moves: dict[tuple[str, str, str], dict[int, tuple[int, tuple[int, int], float | None]]] = {}
    orders: dict[tuple[str, str, str], tuple[int | None, int]] = {}
    first_condition: dict[str, tuple[str, int]] = {}
    for line, row in _rows(reader, label, len(header)):
        where = f"{label} line {line}"
        value = {name: row[index].strip() for name, index in columns.items()}
        participant, condition, task = value["participant"], value["condition"], value["task"]
        if not PARTICIPANT.fullmatch(participant):
            raise UserError(
                f"{where}: participant '{terminal(participant[:64])}' is not an id (a letter "
                "or digit, then letters, digits, _ . or -; at most 64)"
            )
        if condition not in conditions:
            raise UserError(
                f"{where}: condition '{terminal(condition[:64])}' is not one of the "
                f"pipeline's participants.conditions ({', '.join(conditions)})"
            )
        if task not in task_names:
            raise UserError(
                f"{where}: task '{terminal(task[:64])}' is not one of the pipeline's "
                f"[tasks] ({', '.join(task_names)})"
            )
        if not within:
            seen = first_condition.setdefault(participant, (condition, line))
            if seen[0] != condition:
                raise UserError(
                    f"{where}: participant {participant} is in condition {condition} here and "
                    f"in {seen[0]} on line {seen[1]}; conditions are between participants "
                    '(participants.design = "between")'
                )
        step = _integer(value["step"], "step", where)
        cell = (_integer(value["x"], "x", where), _integer(value["y"], "y", where))
        seconds = _seconds(value.get("seconds"), where)
        key = (participant, condition, task)
        steps = moves.setdefault(key, {})
        if step in steps:
            shown = f"{participant}'s demonstration of task {task}"
            if within:
                shown += f" in condition {condition}"
            raise UserError(f"{where}: {shown} has step {step} twice (also line {steps[step][0]})")
        steps[step] = (line, cell, seconds)
        order = _order(value.get("order"), where)
        known_order = orders.setdefault(key, (order, line))
        if known_order[0] != order:
            raise UserError(
                f"{where}: order {order} differs from the order {known_order[0]} of the same "
                f"demonstration on line {known_order[1]}"
            )
    if not moves:
        raise UserError(f"{label}: has no demonstrations, only its header")
    rank = {name: index for index, name in enumerate(task_names)}
    first_seen = {p: i for i, p in enumerate(dict.fromkeys(key[0] for key in moves))}
    keys = sorted(
        moves,
        key=lambda k: (first_seen[k[0]], list(conditions).index(k[1]), rank[k[2]]),
    )
    shown = tuple(_demonstration(key, moves[key], orders[key][0], label, game) for key in keys)
    raw = text.encode()
    return Demonstrations(shown, hashlib.sha256(raw).hexdigest(), text)


def _columns(header: list[str], label: str) -> dict[str, int]:
    """The position of each known column in ``header``."""
    names = [name.strip() for name in header]
    for name in names:
        if name not in REQUIRED_COLUMNS + OPTIONAL_COLUMNS:
            raise UserError(
                f"{label} line 1: column '{terminal(name[:64])}' is not known (columns: "
                f"{', '.join(REQUIRED_COLUMNS)}, and optionally {', '.join(OPTIONAL_COLUMNS)})"
            )
    if len(set(names)) != len(names):
        twice = next(name for name in names if names.count(name) > 1)
        raise UserError(f"{label} line 1: column {twice} is named twice")
    missing = [name for name in REQUIRED_COLUMNS if name not in names]
    if missing:
        raise UserError(
            f"{label} line 1: has no column {missing[0]} (needs {', '.join(REQUIRED_COLUMNS)})"
        )
    return {name: names.index(name) for name in names}


def _rows(reader: Iterator[list[str]], label: str, width: int) -> Iterator[tuple[int, list[str]]]:
    """Each data row with its line number, blank lines skipped; a row of another width than the
    header's, or text that is not CSV, refused."""
    line = 1
    while True:
        try:
            row = next(reader)
        except StopIteration:
            return
        except csv.Error as error:
            raise UserError(f"{label} line {line + 1}: not CSV: {error}") from None
        line = reader.line_num  # type: ignore[attr-defined]
        if not row or all(not cell.strip() for cell in row):
            continue
        if len(row) != width:
            raise UserError(f"{label} line {line}: has {len(row)} values, the header {width}")
        yield line, row


def _integer(text: str, column: str, where: str) -> int:
    if not _INTEGER.fullmatch(text):
        raise UserError(
            f"{where}: {column} '{terminal(text[:32])}' is not a whole number from 0 to 999999999"
        )
    return int(text)


def _order(text: str | None, where: str) -> int | None:
    if text is None or text == "":
        return None
    order = _integer(text, "order", where)
    if order < 1:
        raise UserError(f"{where}: order must be at least 1 (the first task is 1), got 0")
    return order


def _seconds(text: str | None, where: str) -> float | None:
    if text is None or text == "":
        return None
    try:
        seconds = float(text)
    except ValueError:
        seconds = math.nan
    if not (math.isfinite(seconds) and seconds >= 0):
        raise UserError(
            f"{where}: seconds '{terminal(text[:32])}' is not a finite number of seconds >= 0"
        )
    return seconds


def _demonstration(
    key: tuple[str, str, str],
    steps: dict[int, tuple[int, tuple[int, int], float | None]],
    order: int | None,
    label: str,
    game: GameSpec,
) -> Shown:
    """The demonstration of ``key`` (participant, condition, task) from its rows ``steps``
    (by step: line, cell, seconds), checked as a path of the game's learning phase."""
    participant, condition, task = key
    what = f"{participant}'s demonstration of task {task}"
    count = len(steps)
    missing = next((t for t in range(count) if t not in steps), None)
    if missing is not None:
        last = max(steps)
        raise UserError(
            f"{label} line {steps[last][0]}: {what} has step {last} but no step {missing}"
        )
    path = tuple(steps[t][1] for t in range(count))
    lines = [steps[t][0] for t in range(count)]
    fault = path_fault(game, path)
    if fault is not None:
        step, text = fault
        raise UserError(f"{label} line {lines[step]}: {what} {text}")
    times = [steps[t][2] for t in range(count)]
    seconds: tuple[float, ...] | None = None
    if any(time is not None for time in times):
        if any(time is None for time in times):
            t = times.index(None)
            raise UserError(f"{label} line {lines[t]}: {what} has no seconds at step {t}")
        fault = seconds_fault(times)  # type: ignore[arg-type]
        if fault is not None:
            step, text = fault
            raise UserError(f"{label} line {lines[step]}: {what} {text}")
        seconds = tuple(times)  # type: ignore[arg-type]
    recorded = Recorded(
        participant=participant, condition=condition, path=path, seconds=seconds, order=order
    )
    return Shown(task=task, recorded=recorded, line=lines[0])


def path_fault(game: GameSpec, path: Sequence[tuple[int, int]]) -> tuple[int, str] | None:
    """The first way ``path`` (cells ``s_0..s_T``) is not a demonstration of the ``game``'s
    learning phase, with the step at fault (the module docstring's rules), else ``None``."""
    goals = set(game.goals)
    for t, (x, y) in enumerate(path):
        if not (0 <= x < game.width and 0 <= y < game.height):
            return t, f"leaves the {game.width}x{game.height} grid at step {t} ([{x}, {y}])"
        if t == 0:
            if (x, y) != tuple(game.start):
                return t, f"starts in [{x}, {y}], not on the game's start {list(game.start)}"
            continue
        px, py = path[t - 1]
        distance = abs(x - px) + abs(y - py)
        if distance > 1 or (distance == 0 and not game.demonstrator_stays):
            move = "stays put" if distance == 0 else "jumps"
            allowed = "a neighbouring cell" + (" or stay" if game.demonstrator_stays else "")
            return (
                t,
                f"{move} from [{px}, {py}] to [{x}, {y}] at step {t}: a move goes to {allowed}",
            )
        if (px, py) in goals:
            return t, f"goes on after entering the goal [{px}, {py}] at step {t - 1}"
    moves, last = len(path) - 1, len(path) - 1
    if moves > game.learning_steps:
        return last, f"takes {moves} moves, more than game.learning_steps = {game.learning_steps}"
    if goals and tuple(path[-1]) not in goals:
        return last, f"ends in {list(path[-1])}, not in a goal"
    if not goals and moves != game.learning_steps:
        return last, (
            f"takes {moves} moves; a game without goals has paths of exactly "
            f"game.learning_steps = {game.learning_steps}"
        )
    return None


def seconds_fault(seconds: Sequence[float]) -> tuple[int, str] | None:
    """The first step whose time comes before the previous step's, else ``None``."""
    for t in range(1, len(seconds)):
        if seconds[t] < seconds[t - 1]:
            return t, f"arrives at step {t} before step {t - 1} (seconds decrease)"
    return None


def check_demonstration(
    game: GameSpec, tasks: Sequence[Task], conditions: Sequence[str], shown: Collected
) -> None:
    """Refuse ``shown`` unless it is a demonstration a file of them could hold: a known task
    and condition, a path of the game's learning phase (:func:`path_fault`) with a time per
    cell that never decreases.

    Raises:
        UserError: one line saying what is wrong.
    """
    recorded = shown.recorded
    what = f"{recorded.participant}'s demonstration of task {shown.task}"
    if shown.task not in [task.name for task in tasks]:
        raise UserError(f"{what}: task {shown.task} is not one of the pipeline's [tasks]")
    if recorded.condition not in conditions:
        raise UserError(f"{what}: condition {recorded.condition} is not one of {list(conditions)}")
    fault = path_fault(game, recorded.path)
    if fault is None and recorded.seconds is not None:
        if len(recorded.seconds) != len(recorded.path):
            fault = 0, f"has {len(recorded.seconds)} times for {len(recorded.path)} cells"
        else:
            fault = seconds_fault(recorded.seconds)
    if fault is not None:
        raise UserError(f"{what} {fault[1]}")
