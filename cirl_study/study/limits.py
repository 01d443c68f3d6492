"""What one run may plan: the limits every pipeline is held to, read from its file or from a
run's logs (:func:`cirl_study.study.pipeline_file.parse_pipeline` applies :func:`check_resources`,
and to a multiverse, before any of its universes is built, :func:`check_universe_count` and
:func:`single_study_problem` of each level of each axis).

A pipeline that passes them plays on the machine this study is sized for; one that does not
is refused before anything is written, and a run's logs that carry one are refused before
the trials it plans are listed (a run's plan is held in memory).
"""

from __future__ import annotations

from cirl_study.core.players import HUMANS
from cirl_study.errors import UserError
from cirl_study.logs.bounds import MAX_FILE_RECORDS, MAX_FILE_TRIALS
from cirl_study.study.plan import trial_counts
from cirl_study.study.spec import Pipeline

MAX_BATCH = MAX_FILE_TRIALS
"""Most trials sent to a worker at once (and logged in one file): what a reader takes of a
file (:data:`cirl_study.logs.bounds.MAX_FILE_TRIALS`)."""

MAX_TRIALS = 2_000_000
"""Most trials a pipeline may plan: the plan holds every trial's spec in memory (of the order
of a kilobyte each), so this keeps it within a few gigabytes."""

BATCH_MEMORY_BUDGET = 4 * 2**30
"""Bytes a worker may need to play one batch (:func:`batch_memory`): the 2-core, 24 GiB
machine this study is sized for runs two workers beside the parent with room to spare."""


MAX_SEARCH_STEPS = 14
"""Most learning steps of a pipeline where a human plays whose demonstration is the exact
nearest-path search (:attr:`cirl_study.core.players.Human.path_search`: ``best_response``,
and ``regret_optimal``'s candidates; :func:`cirl_study.core.path_search.nearest_paths`). Its
branch and bound visits, at worst, every one of the about ``5^T`` paths, and its time grows
about fourfold a step whatever the memory: measured on the paper's 10x10 grid from the
center (``eta_cv`` trials, both feature levels, every eta of the paper's grid, one core of a
busy 2-core machine), a trial's search takes on average (at most) 0.6 ms (2 ms) at ``T = 9``,
1.5 ms (6 ms) at 10, 16 ms (61 ms) at 12, 0.17 s (0.75 s) at 14, 1.1 s (3.3 s) at 15 and
6.9 s (22 s) at 16. At 14 steps the paper's 10,800 best-response trials search for about half
an hour on one core; at 16, for most of a day, and every further step multiplies that again
(``docs/pipelines.md``)."""

ENUMERATION_BYTES_PER_PATH = 200
"""Peak bytes per learning path of enumerating a teaching study's visit classes
(:class:`cirl_study.core.hypotheses.VisitClasses`), an upper bound of the peak at the paper's
1,910,313 paths (``benchmarks/README.md``, *Memory of a batch*)."""


def batch_memory(pipeline: Pipeline) -> int:
    """Estimated peak bytes of playing one batch of :data:`MAX_BATCH` trials.

    The dynamic programmes of a trial hold, for every step ``t <= T`` and cell, at most a
    float per action (5), per feature (``K``) and per pair of features (``K^2``, the
    covariance of the feature counts), so a batch needs at most about
    ``MAX_BATCH (T + 1) S (5 + K + K^2) 8`` bytes with ``T`` the longer horizon, ``S`` the
    cells and ``K`` the largest feature level: an upper bound of the peak
    (``benchmarks/README.md``, *Memory of a batch*, holds it against measured peaks). A teaching
    study adds the enumeration of its
    learning phase's paths (:data:`ENUMERATION_BYTES_PER_PATH` each), for the
    hypotheses' log-partitions, each trial's features once per hypothesis
    (``MAX_BATCH H S K 8`` bytes), and the pedagogic path probabilities it keeps for reuse
    (at most :data:`~cirl_study.core.hypotheses.TEACHING_CACHE_BYTES`).
    """
    game = pipeline.game
    steps = max(game.learning_steps, game.deployment_steps) + 1
    k = max(game.feature_levels)
    cells = game_cells(pipeline)
    trials = MAX_BATCH * steps * cells * (5 + k + k * k) * 8
    teaching = pipeline.teaching
    if teaching is None:
        return trials
    # The hypotheses' log-partitions repeat each trial's features once per hypothesis.
    repeated = MAX_BATCH * pipeline.hypothesis_count * cells * k * 8
    # The numerical core is loaded already: the learning paths were counted with it.
    from cirl_study.core.hypotheses import TEACHING_CACHE_BYTES

    enumeration = enumeration_bytes(game.learning_steps, cells) * teaching.learning_paths
    return trials + repeated + enumeration + TEACHING_CACHE_BYTES


def game_cells(pipeline: Pipeline) -> int:
    """The cells every dynamic programme of a trial runs over: the grid's, and in a game
    with goals the sink that follows them (:class:`cirl_study.core.maxent.Phase`)."""
    game = pipeline.game
    return game.width * game.height + (1 if game.goals else 0)


def enumeration_bytes(learning_steps: int, cells: int) -> int:
    """Peak bytes per learning path of enumerating a teaching study's visit classes on
    ``cells`` cells: each path's ``T + 1`` 32-bit cells, their sorted copy and its key are
    held a few times over, so the bound grows with the path's length, and more once a
    class's key no longer fits in 63 bits (a bit string per path instead of one integer).
    :data:`ENUMERATION_BYTES_PER_PATH` at the paper's ``T = 9`` (156 measured); measured on
    the tile game of ``pipelines/tiles.toml``: 325 at ``T = 13`` (bit-string keys, bound
    448), 345 at ``T = 15`` (bound 512)."""
    packed = max(1, (cells - 1).bit_length()) * learning_steps <= 63
    per_cell = ENUMERATION_BYTES_PER_PATH // 10 if packed else 32
    return per_cell * max(learning_steps + 1, 10)


def batch_messages(pipeline: Pipeline) -> int:
    """Messages of the log file of one batch of :data:`MAX_BATCH` trials: per trial its
    record, two reward maps and a message per step of the demonstration and of the
    deployment (:func:`cirl_study.logs.episode.replay_counts`)."""
    game = pipeline.game
    return MAX_BATCH * (3 + game.learning_steps + 1 + game.deployment_steps + 1)


def check_resources(pipeline: Pipeline, label: str) -> None:
    """Refuse a pipeline that cannot fit the machine, or whose log files its readers would
    refuse, in one line beginning with ``label`` (the file it was read from).

    Raises:
        UserError: more than :data:`MAX_TRIALS` trials, or a problem of
            :func:`single_study_problem` (of a multiverse, its base universe's; each level of
            its axes is held to it as the file is read).
    """
    total = sum(trial_counts(pipeline).values())
    if total > MAX_TRIALS:
        raise UserError(
            f"{label}: plans {total} trials, more than the {MAX_TRIALS} one run may "
            "hold; split the study into several pipelines"
        )
    problem = single_study_problem(pipeline)
    if problem is not None:
        raise UserError(f"{label}: {problem}")


def single_study_problem(pipeline: Pipeline) -> str | None:
    """Why one batch of ``pipeline``'s trials cannot be played, if it cannot, as the end of a
    line naming the pipeline (or a level of a multiverse's axis): ``None`` when it can.

    A batch over :data:`BATCH_MEMORY_BUDGET` (:func:`batch_memory`); a batch's log file of
    more than half the records a reader takes of a file
    (:data:`~cirl_study.logs.bounds.MAX_FILE_RECORDS`; the other records of a file, its chunks
    and indexes, are far fewer than its messages); or more than :data:`MAX_SEARCH_STEPS`
    learning steps where a human plays who searches her path exactly.
    """
    need = batch_memory(pipeline)
    if need > BATCH_MEMORY_BUDGET:
        return (
            f"one batch of trials would need about {need / 2**30:.3g} GiB, more than the "
            f"{BATCH_MEMORY_BUDGET / 2**30:g} GiB budget; shrink the grid, the horizons or "
            "the largest feature level"
        )
    messages = batch_messages(pipeline)
    if messages > MAX_FILE_RECORDS // 2:
        return (
            f"one batch's log file would hold {messages} messages, more than the "
            f"{MAX_FILE_RECORDS // 2} a log file may; shorten the horizons"
        )
    steps = pipeline.game.learning_steps
    searching = [human for human in pipeline.main.humans if HUMANS[human].path_search]
    if searching and steps > MAX_SEARCH_STEPS:
        return (
            f"{steps} learning steps, more than the {MAX_SEARCH_STEPS} where {searching[0]} "
            "plays: her exact path search grows about fourfold a step (on the paper's 10x10 "
            "grid 0.2 s a trial at 14 steps, 7 s at 16); shorten the learning phase"
        )
    return None


def check_universe_count(label: str, universes: int, per_universe: int) -> None:
    """Refuse a multiverse of at most ``universes`` universes that play trials, each of
    ``per_universe`` trials, whose plan may exceed :data:`MAX_TRIALS`: counted from its axes
    (the product of the level counts of ``cross``, plus those of ``alone`` and the listed
    universes), before any universe is built, in one line beginning with ``label``."""
    if universes * per_universe > MAX_TRIALS:
        raise UserError(
            f"{label}: multiverse may plan {universes} universes of {per_universe} trials "
            f"each, {universes * per_universe} trials, more than the {MAX_TRIALS} one run may "
            "hold; vary fewer levels, or split the study into several pipelines"
        )
