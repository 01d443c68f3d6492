"""A teaching study end to end: its ``[teaching]`` table, a run, its report and its verdicts.

A pipeline with teaching players (the ``pedagogic`` or ``regret_optimal`` human, the
``literal_observer`` or ``pragmatic`` robot) declares their hypothesis space in ``[teaching]``
(:mod:`cirl_study.study.spec`); every trial carries it (:mod:`cirl_study.study.plan`); the run
is analysed by :mod:`cirl_study.analysis.study` into the report of
:mod:`cirl_study.analysis.report.study_sections`.
"""

from __future__ import annotations

import json
import math
import shutil
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest
from test_logs_helpers import run_records
from typer.testing import CliRunner

from cirl_study.analysis.results.study import analyse, with_claims
from cirl_study.cli import app
from cirl_study.core.gridworld import Gridworld
from cirl_study.core.hypotheses import MAX_PATHS, path_count
from cirl_study.core.maxent import Phase
from cirl_study.errors import UserError
from cirl_study.logs.validate import validate_run
from cirl_study.measure_registry import MEASURES, PAPER_MEASURES
from cirl_study.record import MAIN, TrialRecord, TrialRow, encode
from cirl_study.study.engines import LocalEngine
from cirl_study.study.pipeline_file import logged_pipeline, parse_pipeline
from cirl_study.study.runner import run_pipeline
from cirl_study.study.spec import Pipeline, TeachingSpec

SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"

TEACHING = """
[teaching]
hypotheses = 16
includes_truth = true
alpha = 1.0
demonstration = "draw"
"""
"""A valid ``[teaching]`` table (the tests edit it by string replacement)."""

MULTIVERSE = """
[multiverse.alone]
steps = [5]
"""
"""A valid ``[multiverse]`` table for the smoke pipeline (one robot, equal horizons)."""

HUMANS = '["expert", "best_response", "literal", "pedagogic", "regret_optimal"]'
ROBOTS = '["map", "literal_observer", "pragmatic"]'


def smoke_text(
    *,
    humans: str | None = None,
    robots: str | None = None,
    sweep: bool = True,
    extra: str = "",
) -> str:
    """``pipelines/smoke.toml`` with ``main.humans`` and ``main.robots`` replaced, its
    ``[lambda_sweep]`` kept or cut (it is the file's last table) and ``extra`` appended."""
    text = SMOKE.read_text()
    assert text.count("[lambda_sweep]") == 1 and text.rstrip().endswith("]")
    if humans is not None:
        old = 'humans = ["expert", "best_response"]'
        assert old in text
        text = text.replace(old, f"humans = {humans}")
    if robots is not None:
        assert 'robots = ["map"]' in text
        text = text.replace('robots = ["map"]', f"robots = {robots}")
    if not sweep:
        text = text[: text.index("[lambda_sweep]")]
    return text + extra


def teaching_text(**changes: str) -> str:
    """The :data:`TEACHING` table with ``key = value`` lines replaced (value as TOML text)."""
    text = TEACHING
    for key, value in changes.items():
        lines = [line for line in text.splitlines() if line.startswith(f"{key} = ")]
        assert len(lines) == 1, key
        text = text.replace(lines[0], f"{key} = {value}")
    return text


def refused(text: str, path: Path) -> str:
    """The one-line message with which ``parse_pipeline`` refuses ``text`` (read as ``path``)."""
    with pytest.raises(UserError) as caught:
        parse_pipeline(text, path)
    message = str(caught.value)
    assert message.startswith(f"{path}: "), message
    assert "\n" not in message, message
    return message


# ---------------------------------------------------------------------------------------------
# 1. The [teaching] table


def paths_of(width: int, height: int, start: tuple[int, int], steps: int) -> int:
    """Learning paths of a ``steps``-move phase from ``start`` (the demonstrator may stay)."""
    grid = Gridworld(width, height)
    return path_count(Phase(grid.demonstrator_moves(True), grid.index(*start), steps))


def big_grid_text() -> str:
    """A teaching pipeline on the paper's 10x10 grid with 12 learning steps: too many paths."""
    text = smoke_text(humans='["expert", "pedagogic"]', sweep=False, extra=TEACHING)
    for old, new in [
        ("width = 5", "width = 10"),
        ("height = 5", "height = 10"),
        ("start = [2, 2]", "start = [5, 5]"),
        ("learning_steps = 4", "learning_steps = 12"),
    ]:
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    return text


REFUSALS: list[tuple[str, Callable[[], str], str]] = [
    (
        "a teaching human without [teaching]",
        lambda: smoke_text(humans='["expert", "pedagogic"]'),
        "teaching is missing (pedagogic need a hypothesis space)",
    ),
    (
        "the regret-optimal human without [teaching]",
        lambda: smoke_text(humans='["expert", "regret_optimal"]'),
        "teaching is missing (regret_optimal need a hypothesis space)",
    ),
    (
        "a teaching robot without [teaching]",
        lambda: smoke_text(robots='["map", "pragmatic"]'),
        "teaching is missing (pragmatic need a hypothesis space)",
    ),
    (
        "the literal observer without [teaching]",
        lambda: smoke_text(robots='["literal_observer"]'),
        "teaching is missing (literal_observer need a hypothesis space)",
    ),
    (
        "[teaching] with [lambda_sweep]",
        lambda: smoke_text(humans='["expert", "pedagogic"]', extra=TEACHING),
        "lambda_sweep must not be given with [teaching] (its study has no sweep)",
    ),
    (
        "[teaching] with [multiverse]",
        lambda: (
            smoke_text(humans='["expert", "pedagogic"]', sweep=False, extra=TEACHING) + MULTIVERSE
        ),
        "teaching must not be given with [multiverse]",
    ),
    (
        "one hypothesis",
        lambda: smoke_text(
            humans='["expert", "pedagogic"]', sweep=False, extra=teaching_text(hypotheses="1")
        ),
        'teaching.hypotheses must be an integer of at least 2, or "tasks", got 1',
    ),
    (
        "alpha = 0",
        lambda: smoke_text(
            humans='["expert", "pedagogic"]', sweep=False, extra=teaching_text(alpha="0")
        ),
        "teaching.alpha must be a number in [0.001, 1000]",
    ),
    (
        "alpha a string",
        lambda: smoke_text(
            humans='["expert", "pedagogic"]', sweep=False, extra=teaching_text(alpha='"1.0"')
        ),
        "teaching.alpha must be a number in [0.001, 1000] (from a choice all but uniform to all "
        'but the mode), got "1.0"',
    ),
    (
        "an unknown demonstration",
        lambda: smoke_text(
            humans='["expert", "pedagogic"]',
            sweep=False,
            extra=teaching_text(demonstration='"best"'),
        ),
        'teaching.demonstration must be one of draw, mode, got "best"',
    ),
    (
        "an unknown key",
        lambda: smoke_text(
            humans='["expert", "pedagogic"]', sweep=False, extra=TEACHING + "prior = 2\n"
        ),
        "teaching.prior is not a known key (expected one of: hypotheses, includes_truth, "
        "alpha, demonstration)",
    ),
    (
        "too many learning paths",
        big_grid_text,
        f"game.learning_steps gives {paths_of(10, 10, (5, 5), 12):,} learning paths, more "
        f"than the {MAX_PATHS:,} a hypothesis space enumerates",
    ),
]


@pytest.mark.parametrize(
    ("text_of", "expected"),
    [(text_of, expected) for _, text_of, expected in REFUSALS],
    ids=[name for name, _, _ in REFUSALS],
)
def test_a_bad_teaching_pipeline_is_refused_in_one_line(
    text_of: Callable[[], str], expected: str, tmp_path: Path
) -> None:
    """Each misuse of ``[teaching]`` is one ``UserError`` line naming the file and the key."""
    message = refused(text_of(), tmp_path / "teach.toml")
    assert expected in message, message


def test_the_path_limit_lies_between_the_paper_phase_and_the_refused_one() -> None:
    """The refused phase really has too many paths, and the paper's own does not."""
    assert paths_of(10, 10, (5, 5), 9) <= MAX_PATHS < paths_of(10, 10, (5, 5), 12)


def test_a_valid_teaching_pipeline_parses_into_its_spec(tmp_path: Path) -> None:
    """``[teaching]`` becomes ``pipeline.teaching``, and the study has no lambda sweep."""
    text = smoke_text(
        humans='["expert", "pedagogic"]',
        robots='["map", "literal_observer", "pragmatic"]',
        sweep=False,
        extra=teaching_text(
            hypotheses="12", includes_truth="false", alpha="2.5", demonstration='"mode"'
        ),
    )
    pipeline = parse_pipeline(text, tmp_path / "teach.toml")
    # 569 paths of 4 moves from the center of the 5 x 5 grid (5^4 = 625 less those that leave it).
    assert pipeline.teaching == TeachingSpec(
        hypotheses=12, includes_truth=False, alpha=2.5, demonstration="mode", learning_paths=569
    )
    assert isinstance(pipeline.teaching.alpha, float)
    assert pipeline.lambda_sweep is None
    assert pipeline.multiverse is None
    assert pipeline.main.robots == ("map", "literal_observer", "pragmatic")


def test_a_pipeline_without_teaching_players_has_no_teaching(tmp_path: Path) -> None:
    """The smoke pipeline needs no hypothesis space and keeps its sweep."""
    pipeline = parse_pipeline(smoke_text(), tmp_path / "smoke.toml")
    assert pipeline.teaching is None
    assert pipeline.lambda_sweep is not None and pipeline.lambda_sweep.subjects == 4


# ---------------------------------------------------------------------------------------------
# 2. A small teaching run


def small_teaching_text() -> str:
    """The small teaching pipeline: 5x5, 4 learning steps, 3 draws per level (2 for eta),
    every human with every robot, 8 hypotheses."""
    text = smoke_text(
        humans=HUMANS,
        robots=ROBOTS,
        sweep=False,
        extra=teaching_text(hypotheses="8"),
    )
    for old, new in [
        ("[eta_cv]\nsubjects = 3\n", "[eta_cv]\nsubjects = 2\n"),
        ("[main]\nsubjects = 4\n", "[main]\nsubjects = 3\n"),
    ]:
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    return text


@dataclass(frozen=True)
class TeachingRuns:
    """The small teaching pipeline, played once with two workers and once with one."""

    pipeline: Pipeline
    two_workers: Path
    one_worker: Path
    played: tuple[int, int]
    totals: tuple[int, int]


@pytest.fixture(scope="module")
def teaching_runs(tmp_path_factory: pytest.TempPathFactory) -> TeachingRuns:
    """Play the small teaching pipeline with ``LocalEngine(2)`` and ``LocalEngine(1)``."""
    root = tmp_path_factory.mktemp("teaching")
    path = root / "teach.toml"
    path.write_text(small_teaching_text())
    pipeline = parse_pipeline(path.read_text(), path)
    two = run_pipeline(pipeline, root / "run2", LocalEngine(2))
    one = run_pipeline(pipeline, root / "run1", LocalEngine(1))
    return TeachingRuns(
        pipeline, root / "run2", root / "run1", (two.played, one.played), (two.total, one.total)
    )


def test_the_small_teaching_run_plays_every_trial_and_validates(
    teaching_runs: TeachingRuns,
) -> None:
    """eta_cv: 2 levels x 2 draws x 3 etas (best response only); main: 2 x 3 x 5 humans x 3
    robots; no sweep. Both runs are complete and sound."""
    assert teaching_runs.totals == (102, 102) and teaching_runs.played == (102, 102)
    for run in (teaching_runs.two_workers, teaching_runs.one_worker):
        verdict = validate_run(run, logged_pipeline)
        assert verdict.ok, verdict


def sorted_records(run: Path) -> list[TrialRecord]:
    """Every record of ``run``, by trial id."""
    return sorted(run_records(run), key=lambda record: record.trial_id)


def test_the_run_does_not_depend_on_the_number_of_workers(teaching_runs: TeachingRuns) -> None:
    """Two workers and one play the very same records, byte for byte."""
    two = sorted_records(teaching_runs.two_workers)
    one = sorted_records(teaching_runs.one_worker)
    assert [r.trial_id for r in two] == [r.trial_id for r in one]
    assert len({r.trial_id for r in two}) == len(two) == 102
    for a, b in zip(two, one, strict=True):
        assert encode(a) == encode(b), a.trial_id


def test_every_trial_carries_its_subjects_hypothesis_space(teaching_runs: TeachingRuns) -> None:
    """``teaching`` is set on every record, with the pipeline's settings; its seed is one per
    subject and differs between subjects."""
    records = run_records(teaching_runs.two_workers)
    spec = teaching_runs.pipeline.teaching
    assert spec is not None
    seeds: dict[str, set[int]] = defaultdict(set)
    for record in records:
        teaching = record.teaching
        assert teaching is not None, record.trial_id
        assert (teaching.hypotheses, teaching.includes_truth) == (8, True)
        assert (teaching.alpha, teaching.demonstration) == (1.0, "draw")
        assert teaching.search_etas == teaching_runs.pipeline.eta_cv.etas
        seeds[record.subject].add(teaching.hypothesis_seed)
    assert all(len(subject_seeds) == 1 for subject_seeds in seeds.values()), seeds
    assert len(seeds) == 2 * 3 + 2 * 2  # main and cross-validation draws at K = 3 and 10
    one_each = [next(iter(subject_seeds)) for subject_seeds in seeds.values()]
    assert len(set(one_each)) == len(one_each)


def test_every_robot_watches_the_same_demonstration(teaching_runs: TeachingRuns) -> None:
    """Records of one subject, block, human (and eta) but different robots show the same
    demonstration: the robot is a within-subjects factor (a design property)."""
    records = run_records(teaching_runs.two_workers)
    shown: dict[tuple[Any, ...], dict[str, bytes]] = defaultdict(dict)
    for record in records:
        key = (record.block, record.subject, record.human, record.rationality, record.eta)
        shown[key][record.robot] = encode(record.demonstration)
    main = {key: by_robot for key, by_robot in shown.items() if key[0] == MAIN}
    assert len(main) == 2 * 3 * 5
    assert all(
        set(by_robot) == {"map", "literal_observer", "pragmatic"} for by_robot in main.values()
    )
    differing = {
        key: sorted(by_robot) for key, by_robot in shown.items() if len(set(by_robot.values())) != 1
    }
    assert not differing, differing


# ---------------------------------------------------------------------------------------------
# 3. The report of the run

QUESTIONS = {
    "paper_best_response",
    "milli_dragan_crossover",
    "milli_dragan_robustness",
    "best_response_vs_pedagogic",
    "regret_optimal_gap",
}

REPORT_FILES = {
    "report.md",
    "results.json",
    "trials.csv",
    "cell_means.png",
    "cell_means.svg",
}


def analyze(run: Path, out: Path) -> str:
    """``cirl-study analyze RUN --out OUT``; its output, once it succeeded."""
    result = CliRunner().invoke(app, ["analyze", str(run), "--out", str(out)])
    assert result.exit_code == 0, result.output
    return result.output


@pytest.fixture(scope="module")
def teaching_report(
    teaching_runs: TeachingRuns, tmp_path_factory: pytest.TempPathFactory
) -> tuple[Path, str]:
    """The report directory of the two-worker run, and what ``analyze`` printed."""
    out = tmp_path_factory.mktemp("teaching-report") / "report"
    return out, analyze(teaching_runs.two_workers, out)


def test_analyze_writes_the_teaching_report(teaching_report: tuple[Path, str]) -> None:
    """The teaching report's files, its questions and its design."""
    out, output = teaching_report
    assert output.startswith(f"report of 102 trials written to {out}: ")
    data, theory, *untested = output.rstrip().split(": ", 1)[1].split("; ")
    assert "2 questions answered" in data and "fewer than 20: the verdicts mean little" in data
    assert theory == "4 theorems checked exactly, independent of the run: 4 hold"
    assert REPORT_FILES | {"provenance.json"} <= {p.name for p in out.iterdir()}
    assert all((out / name).stat().st_size > 0 for name in REPORT_FILES)
    results = json.loads((out / "results.json").read_text(encoding="utf-8"))
    claims = {claim["id"]: claim for claim in results["claims"]}
    assert set(claims) >= QUESTIONS
    assert all(claims[question]["tested"] for question in QUESTIONS)
    design = results["design"]
    assert design["humans"] == json.loads(HUMANS) and design["robots"] == json.loads(ROBOTS)
    assert design["feature_levels"] == [3, 10]
    assert design["subjects_per_level"] == {"3": 3, "10": 3}
    assert results["trials"] == {"total": 102, "main": 90, "eta_cv": 12}
    assert design["teaching"] == {
        "hypotheses": 8,
        "includes_truth": True,
        "alpha": 1.0,
        "demonstration": "draw",
        "learning_paths": 569,
    }
    assert results["run_id"].startswith("smoke-")
    report = (out / "report.md").read_text(encoding="utf-8")
    assert report.startswith("# Report: `smoke`")
    trials = (out / "trials.csv").read_text(encoding="utf-8").splitlines()
    assert len(trials) == 1 + 102


def test_reanalysing_gives_the_same_report(
    teaching_runs: TeachingRuns, teaching_report: tuple[Path, str], tmp_path: Path
) -> None:
    """The report is a function of the trials: analysing the run again (over its report) or
    the run played by one worker writes byte-identical ``report.md`` and ``results.json``."""
    out, _ = teaching_report
    first = {name: (out / name).read_bytes() for name in ("report.md", "results.json")}
    analyze(teaching_runs.two_workers, out)  # the same run's report: overwritten unforced
    other = tmp_path / "other"
    analyze(teaching_runs.one_worker, other)
    for name, data in first.items():
        assert (out / name).read_bytes() == data, name
        assert (other / name).read_bytes() == data, name


def test_no_demonstration_beats_the_regret_optimal_one(teaching_report: tuple[Path, str]) -> None:
    """The regret-optimal search starts from the expert's and every best response's path, so
    neither of them can do better than what it finds (MAP robot)."""
    out, _ = teaching_report
    results = json.loads((out / "results.json").read_text(encoding="utf-8"))
    gaps = results["regret_optimal"]["gaps"]
    checked = [g for g in gaps if g["human"] in ("expert", "best_response")]
    assert {(g["human"], g["num_features"]) for g in checked} == {
        (human, k) for human in ("expert", "best_response") for k in (3, 10)
    }
    for gap in checked:
        assert gap["n"] == 3
        assert gap["smallest_gap"] >= -1e-9, gap
        assert gap["mean_gap"] >= -1e-9, gap


# ---------------------------------------------------------------------------------------------
# 4. The verdicts of Milli & Dragan's 2 x 2, on synthetic rows

SYNTHETIC_HUMANS = ("expert", "literal", "pedagogic")
SYNTHETIC_ROBOTS = ("map", "literal_observer", "pragmatic")


def synthetic_pipeline(tmp_path: Path) -> Pipeline:
    """A teaching pipeline naming the synthetic study's humans and robots."""
    text = smoke_text(
        humans=json.dumps(list(SYNTHETIC_HUMANS)),
        robots=json.dumps(list(SYNTHETIC_ROBOTS)),
        sweep=False,
        extra=TEACHING,
    )
    return parse_pipeline(text, tmp_path / "synthetic.toml")


def synthetic_rows(
    pragmatic_with_pedagogic: float,
    pragmatic_with_literal: float,
    subjects: int = 30,
    seed: int = 0,
) -> list[TrialRow]:
    """The ``main`` block of a complete teaching design on made-up measures.

    Every human with every robot on ``subjects`` draws at K = 3 and at K = 10. Every measure of
    a trial is the subject's level (around 1) plus small noise, plus
    ``pragmatic_with_pedagogic`` (resp. ``pragmatic_with_literal``) for the pragmatic robot
    watching the pedagogic (resp. literal) human: the robot effect ``pragmatic - literal_observer``
    under each human of the 2 x 2.
    """
    rng = np.random.default_rng(seed)
    shift = {
        ("pedagogic", "pragmatic"): pragmatic_with_pedagogic,
        ("literal", "pragmatic"): pragmatic_with_literal,
    }
    rows = []
    for k in (3, 10):
        for index in range(subjects):
            subject = f"main-k{k:02d}-s{index + 1:04d}"
            level = 1.0 + 0.2 * rng.uniform()
            for human in SYNTHETIC_HUMANS:
                for robot in SYNTHETIC_ROBOTS:
                    value = level + shift.get((human, robot), 0.0)
                    measures = {m: value + rng.normal(0.0, 0.05) for m in PAPER_MEASURES}
                    assert min(measures.values()) > 0
                    rows.append(
                        TrialRow(
                            trial_id=f"main:{subject}:{human}:lambda=1.0:robot={robot}",
                            run_id="synthetic-run",
                            universe=None,
                            block="main",
                            subject=subject,
                            human=human,
                            robot=robot,
                            num_features=k,
                            rationality=1.0,
                            eta=None,
                            seed=int(rng.integers(0, 2**53)),
                            measures=tuple(measures.get(m) for m in MEASURES),
                            converged=True,
                            draw=f"draw-of-{subject}",
                        )
                    )
    return rows


def analysed(rows: list[TrialRow], pipeline: Pipeline) -> dict[str, Any]:
    """The results of ``rows`` with their claims judged, as ``results.json`` has them."""
    judged = with_claims(analyse(rows, pipeline), run_id=None, partial=None, theory=None)
    return msgspec.to_builtins(judged)


def questions_of(results: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The results' teaching claims by id."""
    return {claim["id"]: claim for claim in results["claims"] if claim["id"] in QUESTIONS}


def robot_effects(results: dict[str, Any], measure: str) -> dict[str, float]:
    """The pooled simple effect ``pragmatic - literal_observer`` robot of ``measure``, by human."""
    return {
        row["human"]: row["mean_diff"]
        for row in results["milli_dragan"]["robot_effect"]
        if row["measure"] == measure
    }


def test_a_crossover_whose_loss_exceeds_its_gain_is_crossover_and_robustness(
    tmp_path: Path,
) -> None:
    """The pragmatic robot gains 0.3 with the pedagogic human and loses 0.6 with the literal
    one: Milli & Dragan's crossover and the literal observer's robustness both hold."""
    results = analysed(synthetic_rows(-0.3, 0.6), synthetic_pipeline(tmp_path))
    questions = questions_of(results)
    assert {q for q, claim in questions.items() if claim["tested"]} == {
        "milli_dragan_crossover",
        "milli_dragan_robustness",
    }
    crossover = questions["milli_dragan_crossover"]
    robustness = questions["milli_dragan_robustness"]
    assert crossover["tested"] and crossover["reproduced"] is True
    assert crossover["values"]["by_measure"] == {m: True for m in PAPER_MEASURES}
    assert robustness["tested"] and robustness["reproduced"] is True
    assert robustness["values"]["by_measure"] == {m: True for m in PAPER_MEASURES}
    for measure in PAPER_MEASURES:
        effects = robot_effects(results, measure)
        assert math.isclose(effects["pedagogic"], -0.3, abs_tol=0.05), effects
        assert math.isclose(effects["literal"], 0.6, abs_tol=0.05), effects
    # no best response played: the paper's question is asked, not tested
    paper = questions["paper_best_response"]
    assert paper["tested"] is False and paper["reproduced"] is False
    assert results["regret_optimal"] is None and results["best_response_vs_pedagogic"] is None


def test_a_pragmatic_robot_better_under_both_humans_is_no_crossover(tmp_path: Path) -> None:
    """The pragmatic robot is ahead with either human: neither crossover nor robustness."""
    results = analysed(synthetic_rows(-0.3, -0.2), synthetic_pipeline(tmp_path))
    questions = questions_of(results)
    assert questions["milli_dragan_crossover"]["reproduced"] is False
    assert questions["milli_dragan_crossover"]["values"]["by_measure"] == {
        m: False for m in PAPER_MEASURES
    }
    assert questions["milli_dragan_robustness"]["reproduced"] is False
    assert questions["milli_dragan_robustness"]["values"]["by_measure"] == {
        m: False for m in PAPER_MEASURES
    }


def test_a_crossover_whose_gain_exceeds_its_loss_is_not_robustness(tmp_path: Path) -> None:
    """The pragmatic robot gains 0.6 with the pedagogic human and loses only 0.3 with the
    literal one: the crossover holds, but the literal observer is not the more robust choice."""
    results = analysed(synthetic_rows(-0.6, 0.3), synthetic_pipeline(tmp_path))
    questions = questions_of(results)
    assert questions["milli_dragan_crossover"]["reproduced"] is True
    assert questions["milli_dragan_robustness"]["reproduced"] is False
    assert questions["milli_dragan_robustness"]["values"]["by_measure"] == {
        m: False for m in PAPER_MEASURES
    }


def test_no_robot_effect_is_no_crossover(tmp_path: Path) -> None:
    """Robots that do equally well under both humans answer no to both questions."""
    results = analysed(synthetic_rows(0.0, 0.0), synthetic_pipeline(tmp_path))
    questions = questions_of(results)
    assert questions["milli_dragan_crossover"]["reproduced"] is False
    assert questions["milli_dragan_robustness"]["reproduced"] is False


def test_the_synthetic_verdicts_do_not_depend_on_row_order(tmp_path: Path) -> None:
    """``analyse`` is a function of the rows, not of the order they come in."""
    rows = synthetic_rows(-0.3, 0.6, subjects=6, seed=3)
    pipeline = synthetic_pipeline(tmp_path)
    forward = analysed(rows, pipeline)
    backward = analysed(rows[::-1], pipeline)
    assert json.dumps(forward, sort_keys=True) == json.dumps(backward, sort_keys=True)


def test_a_hypothesis_space_too_large_for_a_batch_is_refused_before_anything_runs(
    tmp_path: Path,
) -> None:
    """The log-partitions repeat each trial's features once per hypothesis: 200,000 hypotheses
    on the 5 x 5 grid at K = 10 would need about 93 GiB for one batch."""
    text = smoke_text(
        humans='["expert", "pedagogic"]',
        robots='["map"]',
        sweep=False,
        extra=teaching_text(
            hypotheses="200000", includes_truth="true", alpha="1.0", demonstration='"draw"'
        ),
    )
    with pytest.raises(UserError, match=r"one batch of trials would need about 93\.\d GiB"):
        parse_pipeline(text, tmp_path / "teach.toml")


def test_an_incomplete_teaching_run_is_refused_unless_partial(
    teaching_runs: TeachingRuns, tmp_path: Path
) -> None:
    """A teaching run missing one file: one line, exit 2, the resume command and the advice
    to use ``--partial``, no report; with ``--partial``, the report of the subjects that have
    every cell, marked partial. A teaching study is analysed like any other."""
    run = tmp_path / "run"
    shutil.copytree(teaching_runs.one_worker, run)
    next(iter(sorted(run.glob("main-*.mcap")))).unlink()
    out = tmp_path / "report"
    refused = CliRunner().invoke(app, ["analyze", str(run), "--out", str(out)])
    assert refused.exit_code == 2
    message = refused.output.strip()
    assert len(message.splitlines()) == 1 and message.startswith("error: ")
    assert "--partial" in message and "cirl-study run" in message
    assert not out.exists()
    partial = CliRunner().invoke(app, ["analyze", str(run), "--out", str(out), "--partial"])
    assert partial.exit_code == 0, partial.output
    assert partial.output.startswith("partial report of ")
    results = json.loads((out / "results.json").read_text(encoding="utf-8"))
    assert results["partial"]["main_subjects_left_out"] >= 1
    assert (out / "report.md").read_text(encoding="utf-8").startswith("**PARTIAL RUN:")
