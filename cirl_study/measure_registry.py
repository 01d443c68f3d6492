"""The measures by name: what every trial's record logs, and how the reports read it.

A measure is a :class:`Measure`: the function that computes it for a batch of played trials
(an :class:`~cirl_study.core.apprenticeship.Outcome`), how the reports print it (its
``label`` in figures, its ``short`` name in tables, its ``unit``), which way is better, the
range its values lie in, where it has no value, and whether the analysis tests it. The
built-in ones are registered here, in the order every record's row, the trial table's columns
and every section of the results list them; a new measure is one module holding its
computation and one line here::

    register_measure("order_agreement", Measure("cirl_study.core.order_agreement:order_agreement",
                     label="feature order agreement", ...))

after which it is computed for every trial played, logged in its record, checked when the
record is read, a column of the trial table and, unless ``analysed=False``, in every per-measure
section of a study's results, its figures and its report (``tests/test_measure_registry.py``
registers one for a test). In a script, :func:`register_measure` adds a measure for the process.

A computation is named by ``"module:function"`` and imported when a batch is first measured
(:meth:`Measure.computed`): reading, checking and analysing logs need only the registry's
names and what they imply for a record and a report, and so never load the numerical core
(numba and the compiled kernels).

The paper's three measures are a named set, :data:`PAPER_MEASURES`: Cronbach's alpha, the
paper's figure of the measures and every published claim read exactly those, whatever else is
registered.
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Measure:
    """One measure: how it is computed and how it reads.

    Attributes:
        compute: ``"module:function"``, where ``function(outcome)`` returns the ``B`` values of
            an :class:`Outcome` in order, each a finite number, or ``None`` where the measure is
            undefined for the trial (see ``undefined``).
        label: the measure as figures name it (``"KL divergence"``).
        short: the measure as tables and the report's text name it (``"KL"``).
        unit: the unit of its values.
        lower_is_better: whether it is a loss (a lower value is better) or a score.
        minimum, maximum: the range of its values in exact arithmetic; a logged value outside
            it by more than :data:`ROUNDING` is a fault of the record.
        undefined: where a trial has no value of it (``null`` in its record), in words; ``None``
            for a measure every record has a value of.
        analysed: whether the analysis tests it (every measure is logged and is a column of
            the trial table).
    """

    compute: str
    label: str
    short: str
    unit: str
    lower_is_better: bool = True
    minimum: float = -math.inf
    maximum: float = math.inf
    undefined: str | None = None
    analysed: bool = True

    def computed(self, outcome: Any) -> list[float | None]:
        """The measure of every trial of ``outcome``: a float (converted from the
        computation's number) or ``None``, in order.

        Raises:
            ValueError: the computation returned another number of values than trials.
        """
        module, _, function = self.compute.partition(":")
        values = getattr(importlib.import_module(module), function)(outcome)
        if len(values) != len(outcome.theta):
            raise ValueError(
                f"{self.compute} returned {len(values)} values for {len(outcome.theta)} trials"
            )
        return [None if value is None else float(value) for value in values]


ROUNDING = 1e-9
"""How far past its range (:attr:`Measure.minimum`, :attr:`Measure.maximum`) a logged value may
lie: the rounding of a measure that is, say, non-negative in exact arithmetic."""

MEASURES: dict[str, Measure] = {}
"""Every measure, by the name a record (``measures``), the trial table and the results use, in
the order registered."""

PAPER_MEASURES: tuple[str, ...] = ("regret", "kl", "reward_l2")
"""The paper's three measures (docs/design.md §4), in its order: those Cronbach's alpha, Figure 2
and the claims read."""


def register_measure(name: str, measure: Measure) -> None:
    """Make ``measure`` computed, logged and analysed as ``name``."""
    if name in MEASURES:
        raise ValueError(f"a measure named {name!r} is already registered")
    MEASURES[name] = measure


def analysed_measures() -> tuple[str, ...]:
    """The names of the measures the analysis tests (:attr:`Measure.analysed`), in order."""
    return tuple(name for name, measure in MEASURES.items() if measure.analysed)


def measure_faults(measures: Mapping[str, object]) -> list[str]:
    """Every way a record's ``measures`` break the registry (empty for sound ones): a name
    that is not a registered measure, a registered one missing, a value that is neither a
    finite number nor ``None``, ``None`` for a measure every record has a value of, or a value
    outside its measure's range by more than :data:`ROUNDING`. The one statement of these
    rules, for a record about to be logged (:class:`cirl_study.logs.writer.TrialLogWriter`) and
    one read back (:mod:`cirl_study.logs.record_checks`).

    Examples:
        >>> measures = {"regret": -0.5, "kl": math.nan, "reward_l2": None, "x": 1}
        >>> for fault in measure_faults(measures):
        ...     print(fault)
        measures.x is not a registered measure
        measures has no regret_under_estimate
        measures has no order_agreement
        measures.regret is -0.5 < 0
        measures.kl is nan, not a finite number
        measures.reward_l2 is null, but every record has a value of it
    """
    faults = [
        f"measures.{name} is not a registered measure" for name in measures if name not in MEASURES
    ]
    faults += [f"measures has no {name}" for name in MEASURES if name not in measures]
    for name, measure in MEASURES.items():
        value = measures.get(name)
        if value is None:
            if name in measures and measure.undefined is None:
                faults.append(f"measures.{name} is null, but every record has a value of it")
        elif isinstance(value, bool) or not isinstance(value, float | int):
            faults.append(f"measures.{name} is a {type(value).__name__}, not a number")
        elif not math.isfinite(value):
            faults.append(f"measures.{name} is {value}, not a finite number")
        elif value < measure.minimum - ROUNDING:
            faults.append(f"measures.{name} is {value} < {measure.minimum:g}")
        elif value > measure.maximum + ROUNDING:
            faults.append(f"measures.{name} is {value} > {measure.maximum:g}")
    return faults


register_measure(
    "regret",
    Measure("cirl_study.core.measures:regret_of", label="regret", short="regret",
            unit="reward", minimum=0.0),
)  # fmt: skip
register_measure(
    "kl",
    Measure("cirl_study.core.measures:kl_of", label="KL divergence", short="KL", unit="nats",
            minimum=0.0),
)  # fmt: skip
register_measure(
    "reward_l2",
    Measure("cirl_study.core.measures:reward_l2_of", label="reward L2 distance", short="L2",
            unit="reward", minimum=0.0),
)  # fmt: skip
register_measure(
    "regret_under_estimate",
    Measure("cirl_study.core.measures:regret_under_estimate_of",
            label="regret under the estimate", short="regret under the estimate",
            unit="reward", minimum=0.0, analysed=False,
            undefined="in a record of a log format before 7, which did not log it"),
)  # fmt: skip
register_measure(
    "order_agreement",
    Measure("cirl_study.core.order_agreement:order_agreement", label="feature order agreement",
            short="order agreement", unit="fraction", lower_is_better=False, minimum=0.0,
            maximum=1.0, undefined="where theta has no two different weights, and in a record "
            "of a log format before 8, which did not log it"),
)  # fmt: skip
