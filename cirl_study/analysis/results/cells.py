"""What an analysis or a claim needs of a run's design: its cells.

A study's design is its humans (within subjects, the first the baseline), its robots (within
subjects), its feature levels (between subjects) and the rationalities of its sweep
(:class:`Design`). A section of the results is computed, and a claim judged, exactly when the
design has the :class:`Cells` it names; the same constants serve both, so a claim is tested
exactly when its evidence exists.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from cirl_study import record


@dataclass(frozen=True)
class Design:
    """The factors of a run's ``main`` block and its sweep, in the pipeline's order."""

    humans: tuple[str, ...]
    robots: tuple[str, ...]
    feature_levels: tuple[int, ...]
    sweep_rationalities: tuple[float, ...]
    conditions: tuple[str, ...] = ()
    """The conditions of the run's participants (none without ``[participants]``)."""

    @property
    def baseline(self) -> str | None:
        """The human every other is compared with: the pipeline's first (``None`` in a run of
        participants alone)."""
        return self.humans[0] if self.humans else None


def papers_own(humans: Sequence[str], robots: Sequence[str]) -> bool:
    """Whether a design is the paper's own: exactly its two humans, watched by one robot.

    Examples:
        >>> papers_own(["best_response", "expert"], ["map"]), papers_own(["expert"], ["map"])
        (True, False)
    """
    return sorted(humans) == sorted(record.PAPER_HUMANS) and len(robots) == 1


@dataclass(frozen=True)
class Cells:
    """The cells a section or a claim needs: these humans and robots (among others), at
    least ``feature_levels`` feature levels, at least ``rationalities`` rationalities in the
    sweep, when given, this ``baseline`` human, and these ``conditions`` of participants.

    Examples:
        >>> design = Design(("expert", "best_response"), ("map",), (3, 10), ())
        >>> PAPER.lacking(design) is None
        True
        >>> Cells(humans=("expert",), rationalities=3).lacking(design)
        'a lambda sweep of at least 3 rationalities'
    """

    humans: tuple[str, ...] = ()
    robots: tuple[str, ...] = ()
    feature_levels: int = 1
    rationalities: int = 0
    baseline: str | None = None
    conditions: tuple[str, ...] = ()

    def lacking(self, design: Design) -> str | None:
        """What ``design`` lacks of these cells, in words; ``None`` when it has them all."""
        missing = [f"the human {h}" for h in self.humans if h not in design.humans]
        missing += [f"the robot {r}" for r in self.robots if r not in design.robots]
        if len(design.feature_levels) < self.feature_levels:
            missing.append(f"at least {self.feature_levels} feature levels")
        if len(design.sweep_rationalities) < self.rationalities:
            missing.append(f"a lambda sweep of at least {self.rationalities} rationalities")
        if self.baseline is not None and design.humans[:1] != (self.baseline,):
            missing.append(f"{self.baseline} as the baseline human")
        absent = [c for c in self.conditions if c not in design.conditions]
        if absent:
            missing.append(
                f"participants in the condition{'s' * (len(absent) > 1)} " + " and ".join(absent)
            )
        return "; ".join(missing) or None


PAPER = Cells(humans=record.PAPER_HUMANS)
"""The paper's own analysis (Hadfield-Menell et al. 2016, section 4): expert and best response,
watched by the reference robot."""

MILLI_DRAGAN = Cells(
    humans=(record.LITERAL, record.PEDAGOGIC), robots=(record.LITERAL_OBSERVER, record.PRAGMATIC)
)
"""Milli & Dragan's (2019) 2 x 2: literal or pedagogic human, literal observer or pragmatic
robot."""

VERSUS_PEDAGOGIC = Cells(humans=(record.BEST_RESPONSE, record.PEDAGOGIC))
"""The paper's best response against the pedagogic human of Ho et al. (2016)."""

REGRET_OPTIMAL_GAP = Cells(humans=(record.REGRET_OPTIMAL,), robots=(record.MAP,))
"""Every human against the demonstration with the lowest MAP regret the search finds."""

SHOW_AND_DO = Cells(conditions=("do", "show"))
"""Ho et al.'s (2016) two conditions: participants told to do the task, or to show it."""
