"""What travels between the experiment's server and the participant's page: JSON of these
Structs, each request decoded into its type (so a field of another type or an unknown shape is
refused before anything reads it), each answer encoded from one."""

from __future__ import annotations

from typing import Annotated, Literal

import msgspec

Stage = Literal["consent", "instructions", "practice", "task", "done"]
"""Where a participant is: the consent page, her condition's instructions, the practice task,
one of her tasks, or the end."""

MAX_SECONDS = 7 * 24 * 3600.0
"""Latest time of a move, since its task began, that a demonstration may give (a week)."""

Coordinate = Annotated[int, msgspec.Meta(ge=-(2**31), le=2**31 - 1)]
Time = Annotated[float, msgspec.Meta(ge=0.0, le=MAX_SECONDS)]


class Tile(msgspec.Struct, frozen=True, kw_only=True):
    """How the page draws the cells of one character of the layout: its ``letter`` (``""``
    for a plain cell), its ``colour`` (``#rrggbb``), the ``feature`` it carries (``None``:
    none) and whether it is a ``goal``."""

    letter: str
    colour: str
    text_colour: str
    feature: str | None
    goal: bool


class Board(msgspec.Struct, frozen=True, kw_only=True):
    """The tile game's grid, the same in every task: ``rows`` of the layout, top row
    (``y = height - 1``) first; each character's :class:`Tile`; the ``start`` cell
    ``[x, y]``; at most ``max_moves`` moves; whether the participant may ``stay`` put (a
    move to her own cell)."""

    width: int
    height: int
    rows: tuple[str, ...]
    tiles: dict[str, Tile]
    start: tuple[int, int]
    max_moves: int
    stay: bool


class Meaning(msgspec.Struct, frozen=True, kw_only=True):
    """What a feature is worth in a task: its name, the ``letters`` and ``colour`` of its
    cells, its weight, and ``kind``: ``safe`` (0), ``dangerous`` (below 0) or ``good``."""

    feature: str
    letters: str
    colour: str
    weight: float
    kind: Literal["safe", "dangerous", "good"]


class TaskView(msgspec.Struct, frozen=True, kw_only=True):
    """The task a participant is on: its ``name``, which her submission repeats; its
    ``number`` among her ``count`` tasks (0 for the practice); what each colour is worth
    (``legend``) and each move (``move_weight``, ``None`` without a step feature)."""

    name: str
    number: int
    count: int
    practice: bool
    legend: tuple[Meaning, ...]
    move_weight: float | None


class State(msgspec.Struct, frozen=True, kw_only=True):
    """A participant's place: her ``stage``; ``text``, the consent or her condition's
    instructions on those pages; her ``task`` on a task or the practice; at the end the
    ``completion_code`` to show or the ``completion_url`` to go to. ``token`` is given once,
    when the session starts or resumes on another page: every later request carries it."""

    participant: str
    stage: Stage
    done: int
    count: int
    token: str | None = None
    condition: str | None = None
    text: str | None = None
    task: TaskView | None = None
    completion_code: str | None = None
    completion_url: str | None = None


class Setup(msgspec.Struct, frozen=True, kw_only=True):
    """What the page needs before a session: the study's ``title``, the URL parameter that
    carries the platform's id of the participant (``None``: none), and the ``board``."""

    title: str
    participant_parameter: str | None
    board: Board


class Start(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """A request to start or resume: the platform's id from the page's address, if any, and
    the token the page holds from an earlier start, if any."""

    participant: str | None = None
    token: str | None = None


class Submission(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """A demonstration the page submits: the ``task`` shown (:attr:`TaskView.name`), the
    cells ``path`` from the start, and ``seconds``, the time of arriving in each cell since
    the task was first shown (``seconds[0]`` is 0)."""

    task: str
    path: tuple[tuple[Coordinate, Coordinate], ...]
    seconds: tuple[Time, ...]


class Problem(msgspec.Struct, frozen=True, kw_only=True):
    """A refused request: one line saying why."""

    error: str


class ConditionStatus(msgspec.Struct, frozen=True, kw_only=True):
    """One condition's count of participants ``started`` (sessions in it) and ``finished``
    (every task of it stored), and of its ``demonstrations`` stored."""

    condition: str
    started: int
    finished: int
    demonstrations: int


class Status(msgspec.Struct, frozen=True, kw_only=True):
    """The experimenter's view: the run's id, and each condition's counts."""

    run_id: str
    participants: int
    conditions: tuple[ConditionStatus, ...]
