"""The per-measure tests of a study, each declared once: where its rows go, its heading, its
computation and its renderer.

A test is registered by the field of the results that holds its rows
(:mod:`cirl_study.analysis.results.types`), annotated with its :class:`StudyTest`::

    wilcoxon: Annotated[
        Rows[WilcoxonRow],
        StudyTest(
            "Wilcoxon signed-rank tests",
            "cirl_study.analysis.results.per_measure:wilcoxon",
            "cirl_study.analysis.report.paper_sections:wilcoxon",
        ),
    ]

The field's name is the test's key in ``results.json``, its place the key's place, and its row
type (``Rows[R]``) the type of the rows. A field of
:class:`~cirl_study.analysis.results.types.StudyResults` holds a test of the ``main`` block's
trials, one of :class:`~cirl_study.analysis.results.types.PaperSection` (key ``paper.<name>``)
a test of the paper's (the reference robot's trials of the expert and the best response,
where the run has them). Registered, a test is computed for every measure the analysis tests,
on the trials that have a value of it (:func:`~cirl_study.analysis.results.per_measure.measured`),
the measures in the registry's order; its rows are in the typed results and ``results.json``;
and its section is in ``report.md``, with the main block's tests after the cell means and the
paper's after them, each in field order, its heading a link target for a claim's
``evidence`` (:mod:`cirl_study.analysis.report.sections`). A new test is its computation and
renderer (in any module), its row type, and its field.

Computations and renderers are named ``"module:function"`` and imported when first used, as
the measures' computations are (:mod:`cirl_study.measure_registry`): the types of the results
load no statistics library, and no module imports the other's renderers.
"""

from __future__ import annotations

import functools
import importlib
import typing
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

if TYPE_CHECKING:
    import pandas as pd

    from cirl_study.analysis.results.cells import Design


def _imported(name: str) -> Callable[..., Any]:
    """The function ``"module:function"``."""
    module, _, function = name.partition(":")
    return getattr(importlib.import_module(module), function)


@dataclass(frozen=True)
class StudyTest:
    """One per-measure test of a study.

    Attributes:
        heading: the heading of its section in ``report.md``.
        compute: ``"module:function"``, where ``function(frame, measure, design)`` returns
            the test's rows of one measure (a sequence of the field's row type) from ``frame``,
            the trials it tests that have a value of ``measure``, in a study of ``design``
            (:class:`~cirl_study.analysis.results.cells.Design`); no rows where the design has
            nothing for it. A family of p-values adjusted together lies within one measure's rows.
        render: ``"module:function"``, where ``function(rows, results)`` returns the lines of
            its section below the heading, from its rows (a
            :class:`~cirl_study.analysis.results.types.Table`) and the whole typed results;
            none to leave the section out.
    """

    heading: str
    compute: str
    render: str

    def computed(self, frame: pd.DataFrame, measure: str, design: Design) -> Sequence[Any]:
        """The rows of ``measure``: see :attr:`compute`."""
        return _imported(self.compute)(frame, measure, design)

    def rendered(self, rows: Sequence[Any], results: Any) -> list[str]:
        """The lines of the section below its heading: see :attr:`render`."""
        return _imported(self.render)(rows, results)


class Registered(NamedTuple):
    """A registered test: the name of its field, the type of its rows, and the test."""

    name: str
    row_type: type
    test: StudyTest


@functools.cache
def registered(record: type) -> tuple[Registered, ...]:
    """The tests registered by the fields of the results record ``record`` (a class of
    :mod:`cirl_study.analysis.results.types`, which this module does not import: the types
    import the registry), in field order."""
    found = []
    for name, hint in typing.get_type_hints(record, include_extras=True).items():
        if typing.get_origin(hint) is not typing.Annotated:
            continue
        rows, *metadata = typing.get_args(hint)
        for test in metadata:
            if isinstance(test, StudyTest):
                (row_type,) = typing.get_args(rows)
                found.append(Registered(name, row_type, test))
    return tuple(found)


def held_tests(results: Any) -> list[tuple[str, Registered, Sequence[Any]]]:
    """Every registered test the study's results ``results``
    (:class:`~cirl_study.analysis.results.types.StudyResults`) hold, with its key and its rows:
    the main block's, then the paper's where the run has its section."""
    held: list[tuple[str, Any]] = [("", results)]
    if results.paper is not None:
        held.append(("paper.", results.paper))
    return [
        (prefix + test.name, test, getattr(record, test.name))
        for prefix, record in held
        for test in registered(type(record))
    ]
