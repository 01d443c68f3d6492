"""People: a file of participants' demonstrations read and refused in one line, the recorded
human replayed exactly, and a run of participants played, resumed and analysed from its logs
alone."""

from __future__ import annotations

import csv
import io
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from msgspec.structs import replace
from test_logs_helpers import run_records
from test_tiles import SMALL

import cirl_study
from cirl_study.analysis.statistics.anova import repeated_measures_anova
from cirl_study.core.gridworld import gridworld
from cirl_study.core.trial import play_trials
from cirl_study.errors import UserError
from cirl_study.logs.collection import collected, collected_path, store
from cirl_study.logs.format import MAX_DEMONSTRATIONS_BYTES
from cirl_study.logs.provenance import RunIdentity
from cirl_study.logs.record_checks import record_faults
from cirl_study.measure_registry import MEASURES
from cirl_study.record import RECORDED, Collected, Recorded
from cirl_study.study.participants import check_demonstration, file_text
from cirl_study.study.pipeline_file import load_pipeline, parse_pipeline
from cirl_study.study.plan import study_trials, trial_counts

REPO = Path(__file__).resolve().parent.parent
PEOPLE = REPO / "pipelines" / "people.toml"

PIPELINE = (
    SMALL.split("[eta_cv]")[0].replace('"tiles-small"', '"people-small"')
    + """[participants]
file = "moves.csv"
conditions = ["do", "show"]
design = "DESIGN"

[eta_cv]
subjects = 2
etas = [1.0]
rationality = 1.0

[main]
rationality = 1.0
humans = ["expert", "recorded"]
robots = ["map", "posterior_mean"]
"""
)
"""The small tile game of tests/test_tiles.py (two tasks) with participants."""

# The goal y is [3, 1]; from the start [0, 1]: straight along the middle row (3 moves), or
# round by the top row (5 moves).
STRAIGHT = [(0, 1), (1, 1), (2, 1), (3, 1)]
ROUND = [(0, 1), (0, 0), (1, 0), (2, 0), (3, 0), (3, 1)]


def _rows(participant: str, condition: str, task: str, path, seconds=True) -> list[list]:
    return [
        [participant, condition, task, step, x, y, *([f"{0.5 * step:.1f}"] if seconds else [])]
        for step, (x, y) in enumerate(path)
    ]


def moves(within: bool = False) -> list[list]:
    """Four participants, two per condition (each in both, within), both tasks."""
    rows = []
    for number, condition in enumerate(["do", "do", "show", "show"], start=1):
        conditions = ["do", "show"] if within else [condition]
        for shown in conditions:
            for task in ("ab", "ba"):
                path = STRAIGHT if (shown == "do") == (number % 2 == 1) else ROUND
                rows += _rows(f"P{number}", shown, task, path)
    return rows


def write(directory: Path, rows: list[list], header=None, design: str = "between") -> Path:
    header = header or ["participant", "condition", "task", "step", "x", "y", "seconds"]
    text = io.StringIO()
    csv.writer(text, lineterminator="\n").writerows([header, *rows])
    (directory / "moves.csv").write_text(text.getvalue())
    pipeline = directory / "people-small.toml"
    pipeline.write_text(PIPELINE.replace("DESIGN", design))
    return pipeline


def refusal(tmp_path: Path, rows: list[list], header=None, design: str = "between") -> str:
    with pytest.raises(UserError) as error:
        load_pipeline(write(tmp_path, rows, header, design))
    message = str(error.value)
    assert "\n" not in message
    return message


def test_a_file_of_moves_becomes_one_demonstration_each(tmp_path: Path) -> None:
    pipeline = load_pipeline(write(tmp_path, moves()))
    shown = pipeline.participants.shown()
    assert [(s.recorded.participant, s.task) for s in shown.shown] == [
        (p, t) for p in ("P1", "P2", "P3", "P4") for t in ("ab", "ba")
    ]
    first = shown.shown[0].recorded
    assert first == Recorded(
        participant="P1", condition="do", path=tuple(STRAIGHT), seconds=(0.0, 0.5, 1.0, 1.5)
    )
    # 2 tasks x 2 robots for the expert, 8 demonstrations x 2 robots for the recorded human.
    assert trial_counts(pipeline)["main"] == 2 * 2 + 8 * 2
    ids = {spec.trial_id for spec in study_trials(pipeline, {})}
    assert "main:participant-P3:recorded:task=ba:lambda=1.0:robot=map" in ids


def test_rows_in_any_order_and_a_spreadsheet_bom_read_alike(tmp_path: Path) -> None:
    ordered = load_pipeline(write(tmp_path, moves())).participants.shown()
    raw = (tmp_path / "moves.csv").read_text().splitlines()
    shuffled = [raw[0], *reversed(raw[1:])]
    (tmp_path / "moves.csv").write_bytes(b"\xef\xbb\xbf" + "\n".join(shuffled).encode())
    again = load_pipeline(tmp_path / "people-small.toml").participants.shown()
    assert again.participants == ("P4", "P3", "P2", "P1")  # in order of first appearance
    assert {(s.recorded, s.task) for s in again.shown} == {
        (s.recorded, s.task) for s in ordered.shown
    }


def _with(rows: list[list], index: int, column: int, value) -> list[list]:
    changed = [list(row) for row in rows]
    changed[index][column] = value
    return changed


CASES = {
    "unknown task": (lambda r: _with(r, 0, 2, "zz"), "line 2: task 'zz' is not one of"),
    "unknown condition": (lambda r: _with(r, 0, 1, "watch"), "condition 'watch' is not one"),
    "participant id": (lambda r: _with(r, 0, 0, "P 1"), "participant 'P 1' is not an id"),
    "leaves the grid": (lambda r: _with(r, 1, 5, 7), "leaves the 4x3 grid at step 1"),
    "illegal move": (lambda r: _with(r, 1, 4, 2), "jumps from [0, 1] to [2, 1] at step 1"),
    "stays put": (lambda r: _with(r, 1, 4, 0), "stays put from [0, 1] to [0, 1] at step 1"),
    "wrong start": (
        lambda r: (
            [row for row in r if not (row[0] == "P1" and row[2] == "ab" and row[3] == 0)]
            + _rows("P1", "do", "ab", [(1, 0)])[:1]
        ),
        "starts in [1, 0], not on the game's start [0, 1]",
    ),
    "no goal": (
        lambda r: [row for row in r if not (row[0] == "P1" and row[2] == "ab" and row[3] == 3)],
        "ends in [2, 1], not in a goal",
    ),
    "duplicate": (lambda r: r + r[:1], "P1's demonstration of task ab has step 0 twice"),
    "two conditions": (
        lambda r: _with(r, 4, 1, "show"),
        "participant P1 is in condition show here and in do on line 2",
    ),
    "missing step": (
        lambda r: [row for row in r if not (row[0] == "P1" and row[2] == "ab" and row[3] == 1)],
        "has step 3 but no step 1",
    ),
    "seconds decrease": (lambda r: _with(r, 2, 6, "0.1"), "seconds decrease"),
    "not a number": (lambda r: _with(r, 0, 3, "one"), "step 'one' is not a whole number"),
    "bad seconds": (lambda r: _with(r, 0, 6, "nan"), "seconds 'nan' is not a finite number"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_every_fault_of_a_row_is_one_line_naming_file_and_line(tmp_path: Path, case: str) -> None:
    change, expected = CASES[case]
    message = refusal(tmp_path, change(moves()))
    assert "participants.file moves.csv" in message
    assert expected in message


def test_too_many_moves_is_refused(tmp_path: Path) -> None:
    long = [(0, 1), (0, 0), (1, 0), (2, 0), (2, 1), (1, 1), (1, 0), (2, 0), (3, 0), (3, 1)]
    rows = [row for row in moves() if not (row[0] == "P2" and row[2] == "ba")]
    message = refusal(tmp_path, rows + _rows("P2", "do", "ba", long))
    assert "takes 9 moves, more than game.learning_steps = 5" in message


def test_a_path_that_goes_on_after_its_goal_is_refused(tmp_path: Path) -> None:
    rows = [row for row in moves() if not (row[0] == "P2" and row[2] == "ba")]
    message = refusal(tmp_path, rows + _rows("P2", "do", "ba", [*STRAIGHT, (3, 0)]))
    assert "goes on after entering the goal [3, 1] at step 3" in message


@pytest.mark.parametrize(
    ("header", "expected"),
    [
        (["participant", "condition", "task", "step", "x", "y", "mood"], "column 'mood' is not"),
        (["participant", "condition", "task", "step", "x", "z", "seconds"], "column 'z' is not"),
        (["participant", "condition", "task", "step", "x", "x", "seconds"], "named twice"),
    ],
)
def test_a_header_it_cannot_read_is_refused(tmp_path: Path, header, expected) -> None:
    assert expected in refusal(tmp_path, moves(), header)


def test_a_missing_column_is_named(tmp_path: Path) -> None:
    rows = [row[:5] + row[6:] for row in moves()]
    header = ["participant", "condition", "task", "step", "x", "seconds"]
    assert "has no column y" in refusal(tmp_path, rows, header)


def test_a_file_too_large_or_not_text_is_refused() -> None:
    with pytest.raises(UserError, match="too large for a file of demonstrations"):
        file_text(b"x" * (MAX_DEMONSTRATIONS_BYTES + 1), "moves.csv")
    with pytest.raises(UserError, match="moves.csv: not UTF-8 text"):
        file_text(b"participant\xff", "moves.csv")


def test_within_participants_show_every_task_in_every_condition(tmp_path: Path) -> None:
    pipeline = load_pipeline(write(tmp_path, moves(within=True), design="within"))
    assert len(pipeline.participants.shown().shown) == 16
    ids = {spec.trial_id for spec in study_trials(pipeline, {})}
    assert "main:participant-P1:recorded:task=ab:condition=show:lambda=1.0:robot=map" in ids
    # Between participants, the same file puts each participant in two conditions.
    assert "is in condition show here" in refusal(tmp_path, moves(within=True))


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (lambda t: t.replace('"expert", "recorded"', '"expert"'), "without the recorded human"),
        (lambda t: t.replace('file = "moves.csv"', 'file = "../moves.csv"'), "without . or .."),
        (lambda t: t.replace('file = "moves.csv"', 'file = "gone.csv"'), "cannot read"),
        (lambda t: t.split("[participants]")[0] + t.split('design = "between"\n')[1],
         "participants is missing"),
    ],
)  # fmt: skip
def test_a_pipeline_of_people_is_checked_whole(tmp_path: Path, edit, expected) -> None:
    write(tmp_path, moves())
    with pytest.raises(UserError, match=expected):
        parse_pipeline(edit(PIPELINE.replace("DESIGN", "between")), tmp_path / "p.toml")


@settings(max_examples=12, deadline=None)
@given(
    task=st.sampled_from(["ab", "ba"]),
    human=st.sampled_from(["expert", "literal"]),
    seed=st.integers(0, 2**53 - 1),
    robot=st.sampled_from(["map", "posterior_mean"]),
)
def test_a_recorded_demonstration_is_watched_exactly_as_the_simulated_one(
    tmp_path_factory, task: str, human: str, seed: int, robot: str
) -> None:
    """A simulated human's path, written to a file and replayed as a person's, gives every
    measure of the simulated trial to 1e-12."""
    directory = tmp_path_factory.mktemp("replay")
    pipeline = load_pipeline(write(directory, moves()))
    (spec,) = [
        s for s in study_trials(pipeline, {})
        if s.human == "expert" and s.task == task and s.robot == robot
    ]  # fmt: skip
    simulated = play_trials([replace(spec, human=human, seed=seed)])[0]
    shown = Recorded(participant="P9", condition="do", path=simulated.demonstration.states)
    replayed = play_trials([replace(spec, human=RECORDED, seed=seed, recorded=shown)])[0]
    assert replayed.demonstration == simulated.demonstration
    for name in MEASURES:
        want, got = simulated.measures[name], replayed.measures[name]
        assert (want is None and got is None) or got == pytest.approx(want, rel=1e-12, abs=1e-12)
    np.testing.assert_allclose(replayed.theta_hat, simulated.theta_hat, rtol=1e-12, atol=1e-12)


def test_a_run_of_people_replays_the_file_and_analyses_from_its_logs(tmp_path: Path) -> None:
    pipeline_file = write(tmp_path, moves())
    run = cirl_study.run(pipeline_file, tmp_path / "run", workers=1)
    records = [r for r in run_records(run) if r.human == RECORDED]
    assert len(records) == 16
    shown = {
        (s.recorded.participant, s.task): s.recorded
        for s in load_pipeline(pipeline_file).participants.shown().shown
    }
    for record in records:
        assert record.recorded == shown[record.recorded.participant, record.task]
        assert record.demonstration.states == record.recorded.path
    # The file may go: the logs carry it.
    (tmp_path / "moves.csv").unlink()
    results = cirl_study.analyze(run)
    people = results.participants
    assert people.design.participants == {"do": 2, "show": 2}
    assert {row.effect for row in people.anova if row.measure == "regret"} >= {
        "condition", "task", "task:condition", "robot"
    }  # fmt: skip
    assert len(people.closest) == 4
    table = cirl_study.load_trials(run)
    assert set(table.loc[table["human"] == RECORDED, "condition"]) == {"do", "show"}


def test_another_file_is_another_run(tmp_path: Path) -> None:
    pipeline_file = write(tmp_path, moves())
    run = cirl_study.run(pipeline_file, tmp_path / "run", workers=1)
    rows = [row for row in moves() if not (row[0] == "P4" and row[2] == "ba")]
    write(tmp_path, rows + _rows("P4", "show", "ba", ROUND))
    with pytest.raises(UserError, match="made from another file of demonstrations"):
        cirl_study.run(pipeline_file, run, workers=1)


def test_the_shipped_example_reads(tmp_path: Path) -> None:
    pipeline = load_pipeline(PEOPLE)
    assert len(pipeline.participants.shown().participants) == 24
    copy = tmp_path / "elsewhere"
    shutil.copytree(REPO / "pipelines" / "people", copy / "people")
    shutil.copy(PEOPLE, copy / "people.toml")
    assert load_pipeline(copy / "people.toml").run_id == pipeline.run_id
    assert gridworld(study_trials(pipeline, {})[0]).num_cells == 30


def _collected(participant: str, condition: str, task: str, path) -> Collected:
    seconds = tuple(0.5 * step for step in range(len(path)))
    recorded = Recorded(
        participant=participant, condition=condition, path=tuple(path), seconds=seconds, order=1
    )
    return Collected(task=task, recorded=recorded)


def test_a_collected_demonstration_is_stored_once_and_read_back(tmp_path: Path) -> None:
    shown = _collected("P1", "do", "ab", STRAIGHT)
    assert store(tmp_path, "run-1", shown) is True
    assert store(tmp_path, "run-1", shown) is False  # the page resent what was saved
    with pytest.raises(UserError, match="already submitted another demonstration of task ab"):
        store(tmp_path, "run-1", _collected("P1", "do", "ab", ROUND))
    other = _collected("P2", "show", "ba", ROUND)
    store(tmp_path, "run-1", other)
    assert collected(tmp_path, "run-1") == [shown, other]
    assert not list((tmp_path / "collected").glob("*/.*"))  # no temporary file left
    with pytest.raises(UserError, match="a demonstration of run 'run-1', not of run-2"):
        collected(tmp_path, "run-2")


def test_a_damaged_or_misnamed_collected_file_is_refused(tmp_path: Path) -> None:
    shown = _collected("P1", "do", "ab", STRAIGHT)
    store(tmp_path, "run-1", shown)
    path = collected_path(tmp_path, shown)
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(UserError, match="not a whole collected demonstration"):
        collected(tmp_path, "run-1")
    path.unlink()
    store(tmp_path, "run-1", shown)
    path.rename(path.with_name("show.ab.mcap"))
    with pytest.raises(UserError, match="holds the demonstration of another name"):
        collected(tmp_path, "run-1")


def test_the_store_never_writes_through_a_link(tmp_path: Path) -> None:
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    run = tmp_path / "run"
    run.mkdir()
    (run / "collected").symlink_to(elsewhere)
    with pytest.raises(UserError, match="symbolic link"):
        store(run, "run-1", _collected("P1", "do", "ab", STRAIGHT))
    assert not list(elsewhere.iterdir())


@pytest.mark.parametrize(
    ("shown", "expected"),
    [
        (_collected("P1", "do", "zz", STRAIGHT), "task zz is not one of"),
        (_collected("P1", "watch", "ab", STRAIGHT), "condition watch is not one of"),
        (_collected("P1", "do", "ab", STRAIGHT[:3]), "ends in [2, 1], not in a goal"),
        (_collected("P1", "do", "ab", [(0, 1), (2, 1), (3, 1)]), "jumps from [0, 1] to [2, 1]"),
    ],
)
def test_a_submission_is_checked_as_a_file_row_is(tmp_path: Path, shown, expected) -> None:
    pipeline = load_pipeline(write(tmp_path, moves()))
    with pytest.raises(UserError, match=re.escape(expected)):
        check_demonstration(pipeline.game, pipeline.tasks, ("do", "show"), shown)


def test_a_collecting_run_plays_what_was_collected_and_resumes_with_more(
    tmp_path: Path,
) -> None:
    text = PIPELINE.replace("DESIGN", "between").replace('file = "moves.csv"', "collect = true")
    pipeline_file = tmp_path / "people-small.toml"
    pipeline_file.write_text(text)
    run_id = load_pipeline(pipeline_file).run_id
    run = tmp_path / "run"
    with pytest.raises(UserError, match="no demonstration collected yet"):
        cirl_study.run(pipeline_file, run, workers=1)
    for number, condition in ((1, "do"), (2, "show")):
        for task in ("ab", "ba"):
            store(run, run_id, _collected(f"P{number}", condition, task, STRAIGHT))
    cirl_study.run(pipeline_file, run, workers=1)
    assert set(cirl_study.load_trials(run)["participant"].dropna()) == {"P1", "P2"}
    for number, condition in ((3, "do"), (4, "show")):
        for task in ("ab", "ba"):
            store(run, run_id, _collected(f"P{number}", condition, task, ROUND))
    with pytest.raises(UserError, match="main: 8 of 20 trials missing"):
        cirl_study.analyze(run)  # the new demonstrations are planned, not yet played
    cirl_study.run(pipeline_file, run, workers=1)
    results = cirl_study.analyze(run)
    assert results.participants.design.participants == {"do": 2, "show": 2}
    seconds = {r.recorded.seconds for r in run_records(run) if r.recorded is not None}
    assert seconds == {(0.0, 0.5, 1.0, 1.5), (0.0, 0.5, 1.0, 1.5, 2.0, 2.5)}


@pytest.mark.parametrize(("design", "sums_of_squares"), [("between", 3), ("within", 2)])
def test_the_peoples_anova_is_the_anova_of_their_table(
    tmp_path: Path, design: str, sums_of_squares: int
) -> None:
    """The people's ANOVA is :func:`repeated_measures_anova` of the participants' trials
    (checked against R's afex in tests/test_analysis_anova.py), with the condition between or
    within and the pipeline's type of sums of squares; unequal groups make the types differ."""
    rows = moves(within=design == "within")
    if design == "between":  # a third participant who did: groups of 3 and 2
        rows += [r for task in ("ab", "ba") for r in _rows("P5", "do", task, ROUND)]
    pipeline_file = write(tmp_path, rows, design=design)
    text = pipeline_file.read_text().replace(
        f'design = "{design}"', f'design = "{design}"\nsums_of_squares = {sums_of_squares}'
    )
    pipeline_file.write_text(text)
    run = cirl_study.run(pipeline_file, tmp_path / "run", workers=1)
    people = cirl_study.analyze(run).participants
    assert people.design.sums_of_squares == sums_of_squares
    table = cirl_study.load_trials(run)
    table = table[table["participant"].notna()]
    within = ["task", "robot"] + (["condition"] if design == "within" else [])
    between = () if design == "within" else ("condition",)
    want = repeated_measures_anova(table, "kl", within, between, sums_of_squares=sums_of_squares)
    got = [row for row in people.anova if row.measure == "kl"]
    assert [row.effect for row in got] == [row.effect for row in want]
    np.testing.assert_allclose([r.F for r in got], [r.F for r in want], rtol=1e-12)
    if design == "between":
        other = repeated_measures_anova(table, "kl", within, between, sums_of_squares=2)
        assert abs(other[1].SS - got[1].SS) > 1e-9 * abs(got[1].SS)  # the task effect
    assert len(people.robots) == len(people.design.conditions) * 4  # 4 measures analysed
    assert people.cronbach_alpha is not None and people.cronbach_alpha.n_items == 3


def test_a_record_whose_path_is_not_its_participants_is_refused(tmp_path: Path) -> None:
    pipeline = load_pipeline(write(tmp_path, moves()))
    (spec,) = [
        s for s in study_trials(pipeline, {})
        if s.recorded is not None and s.robot == "map" and s.subject == "participant-P2"
        and s.task == "ab"
    ]  # fmt: skip
    record = play_trials([spec])[0]
    assert record_faults(record) == []
    assert record.recorded.path == tuple(ROUND)
    moved = replace(record, recorded=replace(record.recorded, path=tuple(STRAIGHT)))
    assert "demonstration.states is not the participant's recorded path" in record_faults(moved)


def test_a_logged_file_of_demonstrations_is_bounded() -> None:
    identity = RunIdentity("r", "p", "p.toml", "x", demonstrations="x")
    provenance = identity.provenance()
    provenance["participants_csv"] = "x" * (MAX_DEMONSTRATIONS_BYTES + 1)
    with pytest.raises(ValueError, match="longer than the 33554432 bytes"):
        RunIdentity.of(provenance)
