"""The sections and figures of a study's report, by the ``results.json`` key they present.

A claim's ``evidence`` names these keys; :func:`link` turns one into a link to its section
or figure, so every renderer of a section and every claim agree on its name.
"""

from __future__ import annotations

from typing import NamedTuple

from cirl_study.analysis.report.markdown import anchor
from cirl_study.analysis.results.types import study_tests

HEADINGS = {
    "claims": "Claims",
    "claims.data": "Claims on this run's data",
    "claims.theory": "Theorems checked exactly",
    "claims.not_tested": "Claims not tested",
    "cells": "Cell means",
    **{key: registered.test.heading for key, registered in study_tests().items()},
    "paper.cronbach_alpha": "Cronbach's alpha",
    "lambda_sweep": "Lambda sweep",
    "eta_cv": "Eta cross-validation",
    "paper.figure1": "Figure 1",
    "robots": "Robots",
    "milli_dragan": "Milli & Dragan's 2 x 2: literal or pedagogic human, the robot reading each",
    "best_response_vs_pedagogic": "The paper's best response against the pedagogic human",
    "regret_optimal": "How far from the regret-optimal demonstration",
    "participants": "People",
    "rules": "How the verdicts are decided",
}
"""Section headings of ``report.md``, by the ``results.json`` key they present (a registered
test's, its :attr:`~cirl_study.analysis.results.registry.StudyTest.heading`)."""


class Figure(NamedTuple):
    """A figure of the report: the file name of its PNG, and the text of a link to it."""

    file: str
    label: str


FIGURE1 = Figure("figure1_reward_maps.png", "Figure 1")
FIGURE2_MEASURES = Figure("figure2_measures.png", "Figure 2, left")
OTHER_MEASURES = Figure("other_measures.png", "the other measures")
FIGURE2_LAMBDA = Figure("figure2_lambda.png", "Figure 2, right")
ETA_CV_CURVE = Figure("eta_cv.png", "eta curve")
ROBOTS_LAMBDA = Figure("robots_lambda.png", "robots against lambda")
CELL_MEANS = Figure("cell_means.png", "cell means")
PARTICIPANTS = Figure("participants.png", "participants")

FIGURES = {
    "figure1": FIGURE1,
    "figure2_measures": FIGURE2_MEASURES,
    "other_measures": OTHER_MEASURES,
    "figure2_lambda": FIGURE2_LAMBDA,
    "eta_cv_curve": ETA_CV_CURVE,
    "robots": ROBOTS_LAMBDA,
    "cell_means": CELL_MEANS,
    "participants": PARTICIPANTS,
}
"""Every figure, by the key a claim's ``evidence`` names it with."""


def heading(level: int, key: str) -> str:
    """The Markdown heading of the section of ``key``."""
    return f"{'#' * level} {HEADINGS[key]}"


def link(key: str) -> str:
    """A link to the section or figure of ``key`` (a section first); another key links to
    itself as a relative path."""
    if key in HEADINGS:
        return f"[{HEADINGS[key]}](#{anchor(HEADINGS[key])})"
    if key in FIGURES:
        figure = FIGURES[key]
        return f"[{figure.label}]({figure.file})"
    return f"[{key}]({key})"
