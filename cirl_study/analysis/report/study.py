"""The report of a run: ``report.md``, ``results.json``, ``trials.csv`` and the figures.

:func:`write_report` turns trial records of any study into a directory that reads well on
GitHub: every claim (:mod:`cirl_study.analysis.results.claims`) with its verdict and links to the
tables and figures that support it (the claims on the run's data, the theorems checked exactly
and the claims not tested apart), then every section the run's design has
(:mod:`~cirl_study.analysis.report.study_sections`,
:mod:`~cirl_study.analysis.report.paper_sections`,
:mod:`~cirl_study.analysis.report.teaching_sections`). The output is a deterministic function of the
records (their order does not matter): no timestamps, no machine paths, and byte-identical
files for identical input.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import msgspec

from cirl_study import escape
from cirl_study.analysis.report import figures
from cirl_study.analysis.report import paper_sections as paper_report
from cirl_study.analysis.report import participants_sections as participants_report
from cirl_study.analysis.report import study_sections as study_report
from cirl_study.analysis.report import teaching_sections as teaching_report
from cirl_study.analysis.report.markdown import document, measure_name, number, svg_name, table
from cirl_study.analysis.report.output import csv_file, write_report_directory
from cirl_study.analysis.report.sections import (
    CELL_MEANS,
    ETA_CV_CURVE,
    FIGURE1,
    FIGURE2_LAMBDA,
    FIGURE2_MEASURES,
    FIGURES,
    OTHER_MEASURES,
    PARTICIPANTS,
    ROBOTS_LAMBDA,
    heading,
    link,
)
from cirl_study.analysis.results.cells import papers_own
from cirl_study.analysis.results.claims import (
    DATA,
    MIN_SUBJECTS,
    NOT_TESTED,
    THEORY,
    count_claims,
)
from cirl_study.analysis.results.registry import held_tests
from cirl_study.analysis.results.study import estimates, tests, with_claims
from cirl_study.analysis.results.types import ClaimRow, Estimates, StudyResults, Teaching, Undefined
from cirl_study.analysis.table import check_design, trial_table
from cirl_study.measure_registry import MEASURES, PAPER_MEASURES, analysed_measures
from cirl_study.record import BEST_RESPONSE, EXPERT, MAIN, PAPER_HUMANS, TrialRecord, TrialRow
from cirl_study.study.spec import Pipeline
from cirl_study.workers import Call

VERDICTS = {True: "✅ reproduced", False: "❌ not reproduced", None: "💬 answered"}
"""A tested claim's verdict as the report shows it; ``None``: a question, answered."""


THEOREM_VERDICTS = {True: "✅ holds", False: "❌ does not hold"}
"""A theorem's verdict as the report shows it."""


def _verdict(claim: ClaimRow) -> str:
    if not claim.tested:
        return "➖ not tested"
    if claim.kind == THEORY and claim.reproduced is not None:
        return THEOREM_VERDICTS[claim.reproduced]
    return VERDICTS[claim.reproduced]


def _capital(text: str) -> str:
    """``text`` with its first letter a capital."""
    return text[:1].upper() + text[1:]


def _claim_rows(claims: Sequence[ClaimRow], first: int, tested: bool) -> list[list[str]]:
    """The rows of a table of ``claims``, numbered from ``first``: with what was measured,
    the verdict and the evidence (``tested``), else with why not."""
    if not tested:
        return [
            [str(position), claim.claim, claim.source, claim.measurement.removeprefix(NOT_TESTED)]
            for position, claim in enumerate(claims, start=first)
        ]
    return [
        [
            str(position),
            claim.claim,
            claim.source,
            claim.measurement,
            _verdict(claim),
            ", ".join(link(key) for key in claim.evidence),
        ]
        for position, claim in enumerate(claims, start=first)
    ]


def _claims(results: StudyResults) -> list[str]:
    """The claims section: the counts, then a table each of the claims on the run's data
    (with a warning when their cells are small), the theorems checked exactly, and the claims
    not tested."""
    counts = count_claims(results.claims)
    data = [c for c in results.claims if c.tested and c.kind == DATA]
    theory = [c for c in results.claims if c.tested and c.kind == THEORY]
    untested = [c for c in results.claims if not c.tested]
    measured = ["#", "Claim", "Source", "We measured", "Verdict", "Evidence"]
    right = [True, False, False, False, False, False]
    lines = [heading(2, "claims"), "", f"{_capital(counts.summary())}."]
    if data:
        lines += ["", heading(3, "claims.data"), ""]
        if counts.few_subjects:
            lines += [
                f"**{_capital(counts.subjects_text() or '')}.** "
                f"A claim's verdict wants at least {MIN_SUBJECTS} subjects (reward draws) "
                "per cell: with fewer, its tests miss even large effects.",
                "",
            ]
        lines += [
            table(measured, _claim_rows(data, 1, True), right),
            "",
            "Each verdict is computed from the data by a fixed rule; see "
            f"{link('rules')}. The fewest subjects in a claim's cells are in "
            "[`results.json`](results.json) (`claims`, `subjects`).",
        ]
    if theory:
        lines += [
            "",
            heading(3, "claims.theory"),
            "",
            "Exact results of the paper's theory (the office-supplies example), computed with "
            "fractions: they do not depend on the run.",
            "",
            table(
                ["#", "Theorem", "Source", "We computed", "Verdict", "Evidence"],
                _claim_rows(theory, len(data) + 1, True),
                right,
            ),
        ]
    if untested:
        lines += [
            "",
            heading(3, "claims.not_tested"),
            "",
            "The run lacks the cells these claims need.",
            "",
            table(
                ["#", "Claim", "Source", "Why not tested"],
                _claim_rows(untested, len(data) + len(theory) + 1, False),
                [True, False, False, False],
            ),
        ]
    return lines


def _rules(results: StudyResults) -> list[str]:
    return [
        heading(2, "rules"),
        "",
        *(f"- `{claim.id}` ({claim.source}): {claim.rule}." for claim in results.claims),
        "",
        "A claim is *not tested* when the run lacks the humans, robots, feature levels or "
        "rationalities it needs. A claim judged on cells of fewer than "
        f"{MIN_SUBJECTS} subjects (reward draws) is flagged: its verdict means little. The "
        "theorems are checked on exact fractions, whatever the run. Every number of this "
        "report is in "
        "[`results.json`](results.json) at full precision; the trials are in "
        "[`trials.csv`](trials.csv). What made the run and this report (commit, date, "
        "platform, CPU, BLAS and package versions) is in [`provenance.json`](provenance.json).",
    ]


def _hypothesis_space(teaching: Teaching) -> str:
    hypotheses = teaching.hypotheses
    if teaching.of_tasks:
        members = "the pipeline's tasks, the subject's own among them"
    elif teaching.includes_truth:
        members = f"the true theta and {hypotheses - 1} prior draws"
    else:
        members = "all prior draws, the true theta not among them"
    shows = (
        "draws her demonstration"
        if teaching.demonstration == "draw"
        else "shows her most likely demonstration"
    )
    return (
        f"{hypotheses} reward hypotheses per {'task' if teaching.of_tasks else 'reward draw'} "
        f"({members}), pedagogic exponent "
        f"alpha = {number(teaching.alpha)}, the pedagogic human {shows}"
    )


def _directions() -> str:
    """One sentence: the measures the analysis tests, with their units, which are losses and
    which scores."""
    named = {m: f"{measure_name(m)} ({MEASURES[m].unit})" for m in analysed_measures()}
    losses = [text for m, text in named.items() if MEASURES[m].lower_is_better]
    scores = [text for m, text in named.items() if not MEASURES[m].lower_is_better]
    sentence = f"The measures: {_listed(losses)} {'are losses' if losses[1:] else 'is a loss'} "
    sentence += "(lower is better)"
    if scores:
        sentence += f"; {_listed(scores)} {'are scores' if scores[1:] else 'is a score'} "
        sentence += "(higher is better: the sign of a difference reads the other way)"
    return sentence + "."


def _listed(names: Sequence[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    return " and ".join(filter(None, [", ".join(names[:-1]), names[-1]]))


def _header(results: StudyResults) -> list[str]:
    trials, design = results.trials, results.design
    per_level = ", ".join(f"{n} at {k} features" for k, n in design.subjects_per_level.items())
    blocks = ", ".join(
        f"{n} in {escape.markdown(block)}" for block, n in trials.items() if block != "total"
    )
    lambdas = ", ".join(f"{value:g}" for value in design.main_rationality)
    etas = (
        "; ".join(
            f"{', '.join(f'{eta:g}' for eta in values)} at {level} features"
            for level, values in design.main_eta.items()
            if values
        )
        or "–"
    )
    space = design.teaching
    return [
        *_partial_title(results),
        f"# Report: {escape.markdown(results.pipeline)}",
        "",
        "On the gridworld of Cooperative Inverse Reinforcement Learning (Hadfield-Menell et "
        "al., NeurIPS 2016, section 4), with the paper's measures: the published claims "
        "beside what this run measured. Every human demonstrates to every robot on the same "
        "reward draws (within subjects); the number of features varies between them. "
        f"{_directions()}",
        "",
        f"- Humans: {', '.join(escape.markdown(h) for h in design.humans)} (baseline "
        f"{escape.markdown(design.baseline)}); robots: "
        f"{', '.join(escape.markdown(r) for r in design.robots)} "
        f"(reference {escape.markdown(design.reference_robot)}); rationality λ = {lambdas}; "
        f"best-response η = {etas}.",
        f"- Trials: {trials['total']} ({blocks}); reward draws {per_level}.",
        *([f"- Hypothesis space: {_hypothesis_space(space)}."] if space else []),
        *(_undefined(row) for row in results.undefined or ()),
    ]


def _undefined(row: Undefined) -> str:
    """A line of the header: a measure some trials have no value of, and what is left out."""
    where = MEASURES[row.measure].undefined or "not logged"
    return (
        f"- No {measure_name(row.measure)} for {row.trials} trial(s) of {row.subjects} reward "
        f"draw(s) ({where}): those draws are left out of its statistics."
    )


def _partial_title(results: StudyResults) -> list[str]:
    """The report's first lines for a partial run: what it lacks."""
    partial = results.partial
    if partial is None:
        return []
    lacks = [
        partial.missing,
        f"{partial.damaged_files} damaged file(s) salvaged" if partial.damaged_files else "",
        f"{partial.main_subjects_left_out} main-block subject(s) without every cell left out"
        if partial.main_subjects_left_out
        else "",
    ]
    return [
        f"**PARTIAL RUN: {partial.logged} of {partial.planned} planned trials logged; "
        f"{'; '.join(text for text in lacks if text)}. Every number below is provisional.**",
        "",
    ]


def _tests(results: StudyResults) -> list[list[str]]:
    """The section of every registered test the results hold (:func:`.study_tests.held_tests`)
    that has something to show: its heading, then its renderer's lines."""
    sections = []
    for key, registered, rows in held_tests(results):
        lines = registered.test.rendered(rows, results)
        if lines:
            sections.append([heading(3, key), "", *lines])
    return sections


def render_markdown(results: StudyResults) -> str:
    """The text of ``report.md`` for ``results`` (with their ``claims``): every section the
    run's design has, in a fixed order; the registered tests' after the cell means."""
    sections = [
        _header(results),
        _claims(results),
        ["## Main study"],
        study_report.cells(results),
        *_tests(results),
        paper_report.cronbach(results) if results.paper else [],
        study_report.lambda_sweep(results),
        study_report.eta_cv(results),
        paper_report.figure1(results) if results.paper else [],
        paper_report.robots(results),
        teaching_report.milli_dragan(results),
        teaching_report.versus(results),
        teaching_report.regret_optimal(results),
        participants_report.participants(results),
        _rules(results),
    ]
    return document(sections)


def _figure1_records(
    trials: Sequence[TrialRow],
    records_of: Callable[[set[str]], Sequence[TrialRecord]],
    subject: str,
    robot: str,
) -> dict[str, TrialRecord]:
    """The ``main``-block records of ``subject`` watched by ``robot``, by human."""
    wanted = {
        row.trial_id
        for row in trials
        if row.block == MAIN and row.subject == subject and row.robot == robot
    }
    found = {record.human: record for record in records_of(wanted)}
    return {human: found[human] for human in PAPER_HUMANS}


FIGURE2_TITLE = "Lower is better: the three measures by human and number of features"
"""The title of Figure 2 (left): the paper's three measures, all losses."""

OTHERS_TITLE = "the other measures by human and number of features"
"""The title of the figure of the measures beyond the paper's, after which way is better."""


def _drawings(
    trials: Sequence[TrialRow],
    records_of: Callable[[set[str]], Sequence[TrialRecord]],
    estimated: Estimates,
) -> dict[str, Call]:
    """The drawing of every figure the estimates
    (:func:`~cirl_study.analysis.results.study.estimates`) support, by PNG name. Figure 1 draws two
    whole records, fetched by trial id with ``records_of``."""
    design = estimated.design
    reference = design.reference_robot
    drawings: dict[str, Call] = {}
    chosen = estimated.figure1
    if chosen is not None:
        pair = _figure1_records(trials, records_of, chosen.subject, chosen.robot)
        title = f"Reward draw {chosen.subject} ({chosen.num_features} features)"
        drawings[FIGURE1.file] = (
            figures.reward_maps,
            (pair[EXPERT], pair[BEST_RESPONSE], title),
        )
        paper_cells = estimated.cells.filter(
            lambda row: row.robot == reference and row.human in PAPER_HUMANS
        )
        drawings[FIGURE2_MEASURES.file] = (
            figures.measure_bars,
            (paper_cells.to_frame(), PAPER_MEASURES, FIGURE2_TITLE),
        )
        others = study_report.other_measures(row.measure for row in paper_cells)
        if others:
            drawings[OTHER_MEASURES.file] = (
                figures.measure_bars,
                (paper_cells.to_frame(), others, f"{figures.better(others)}: {OTHERS_TITLE}"),
            )
        if estimated.lambda_sweep:  # every human and robot of the sweep
            drawings[FIGURE2_LAMBDA.file] = (
                figures.lambda_curve,
                (estimated.lambda_sweep.to_frame(), design.humans, design.robots),
            )
    if design.humans and not papers_own(design.humans, design.robots):
        drawings[CELL_MEANS.file] = (
            figures.cell_bars,
            (estimated.cells.to_frame(), design.humans, design.robots),
        )
    if estimated.eta_cv.means:
        drawings[ETA_CV_CURVE.file] = (
            figures.eta_curve,
            (estimated.eta_cv.means.to_frame(), estimated.eta_cv.uncertainty.to_frame()),
        )
    people = estimated.participants
    if people is not None and people.means:
        drawings[PARTICIPANTS.file] = (
            figures.participant_points,
            (people.means.to_frame(), people.design.conditions, people.design.robots),
        )
    robots = estimated.robots
    if (
        robots is not None
        and robots.lambda_sweep
        and len(robots.others) == 1
        and tuple(design.humans) == PAPER_HUMANS
    ):
        drawings[ROBOTS_LAMBDA.file] = (
            figures.robot_difference_curve,
            (robots.lambda_sweep.to_frame(), reference, robots.others[0]),
        )
    return drawings


CSV_IN_MEMORY_ROWS = 200_000
"""Up to this many trials, trials.csv is made in this process while the figures are drawn in
workers, after the tests, whose end would otherwise leave it waiting for the figures; a
larger run's table is written row by row at the end, so its text is never held whole (its
memory: ``benchmarks/README.md``, *The analysis's choices*)."""


def write_report(
    trials: Sequence[TrialRow],
    out_dir: Path | str,
    pipeline: Pipeline,
    *,
    records_of: Callable[[set[str]], Sequence[TrialRecord]],
    run_id: str | None = None,
    theory: Mapping[str, Any] | None = None,
    provenance: Mapping[str, Any] | None = None,
    partial: Mapping[str, Any] | None = None,
    progress: Callable[[str], None] = lambda stage: None,
) -> StudyResults:
    """Analyse a run's trials and write the report directory.

    Writes ``report.md``, ``results.json`` (every number at full precision), ``trials.csv``
    (the trial table) and the figures of :data:`FIGURES`, each as PNG and SVG, into
    ``out_dir`` (created if needed); a figure the run has no data for is not written, and a
    stale copy of it is removed. ``provenance`` (what made the run and the report) goes to
    ``provenance.json``, apart from the numbers, since it differs from machine to machine
    while they must not.

    Args:
        trials: the rows of the trial records (:class:`~cirl_study.record.TrialRow`), in
            any order.
        out_dir: the report directory.
        pipeline: the run's pipeline (its name, and the order of its humans and robots).
        records_of: the whole records of the given trial ids (for Figure 1), e.g. read
            back from the logs (:attr:`cirl_study.analysis.reading.AnalysedRun.records`).
        run_id: the run's id, stored as ``run_id`` in ``results.json``.
        theory: optional extra claims (see
        :func:`cirl_study.analysis.results.claims.external_claims`);
            stored under ``theory`` in ``results.json``.
        provenance: optional provenance, written as ``provenance.json``.
        partial: for a report on an incomplete run, what it lacks (``planned``, ``logged``,
            ``missing``, ``damaged_files``, ``main_subjects_left_out``); stored under
            ``partial`` in ``results.json`` and stated in the report's first line.
        progress: called with the name of each stage as it begins.

    Returns:
        The typed content of ``results.json``.

    Raises:
        UserError: the design cannot be analysed (see
            :func:`~cirl_study.analysis.table.check_design`).
    """
    check_design(trials)
    progress("statistics and figures")
    everything = trial_table(trials)
    estimated = estimates(trials, everything, pipeline)
    # The figures need only the estimates: they are drawn in workers while the tests, the
    # claims, the markdown and, up to CSV_IN_MEMORY_ROWS, trials.csv are made here.
    with figures.drawing(_drawings(trials, records_of, estimated)) as drawn:
        results = with_claims(
            tests(estimated, everything, pipeline),
            run_id=run_id,
            partial=partial,
            theory=theory,
        )
        markdown = render_markdown(results)
        trials_csv = csv_file(everything) if len(everything) <= CSV_IN_MEMORY_ROWS else everything
        made = drawn()
    names = [n for figure in FIGURES.values() for n in (figure.file, svg_name(figure.file))]
    write_report_directory(
        out_dir,
        markdown=markdown,
        results=msgspec.to_builtins(results),
        tables={"trials.csv": trials_csv},
        figures={file_name: made.get(file_name) for file_name in names},
        provenance=provenance,
    )
    return results
