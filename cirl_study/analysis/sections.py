"""The sections and figures of a study's report, by the ``results.json`` key they present.

A claim's ``evidence`` names these keys; :func:`link` turns one into a link to its section
or figure, so every renderer of a section and every claim agree on its name.
"""

from __future__ import annotations

from cirl_study.analysis.markdown import anchor

HEADINGS = {
    "claims": "Claims",
    "cells": "Cell means",
    "anova": "Repeated-measures ANOVA",
    "pairwise": "Pairwise comparisons",
    "against_baseline": "Every human against the baseline",
    "paper.anova": "The paper's mixed ANOVA",
    "paper.simple_effects": "Simple effects of human",
    "paper.tukey_hsd": "Tukey HSD",
    "paper.wilcoxon": "Wilcoxon signed-rank tests",
    "paper.cronbach_alpha": "Cronbach's alpha",
    "lambda_sweep": "Lambda sweep",
    "eta_cv": "Eta cross-validation",
    "paper.figure1": "Figure 1",
    "robots": "Robots",
    "milli_dragan": "Milli & Dragan's 2 x 2: literal or pedagogic human, the robot reading each",
    "best_response_vs_pedagogic": "The paper's best response against the pedagogic human",
    "regret_optimal": "How far from the regret-optimal demonstration",
    "rules": "How the verdicts are decided",
}
"""Section headings of ``report.md``, by the ``results.json`` key they present."""

FIGURES = {
    "figure1": ("figure1_reward_maps.png", "Figure 1"),
    "figure2_measures": ("figure2_measures.png", "Figure 2, left"),
    "other_measures": ("other_measures.png", "the other measures"),
    "figure2_lambda": ("figure2_lambda.png", "Figure 2, right"),
    "eta_cv_curve": ("eta_cv.png", "eta curve"),
    "robots": ("robots_lambda.png", "robots against lambda"),
    "cell_means": ("cell_means.png", "cell means"),
}
"""File name and link text of each figure, by key."""


def heading(level: int, key: str) -> str:
    """The Markdown heading of the section of ``key``."""
    return f"{'#' * level} {HEADINGS[key]}"


def link(key: str) -> str:
    """A link to the section or figure of ``key`` (a section first); another key links to
    itself as a relative path."""
    if key in HEADINGS:
        return f"[{HEADINGS[key]}](#{anchor(HEADINGS[key])})"
    if key in FIGURES:
        file_name, label = FIGURES[key]
        return f"[{label}]({file_name})"
    return f"[{key}]({key})"
