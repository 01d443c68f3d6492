"""Exact decision rules on ``Theta = [0, 1]`` with payoffs linear in ``theta``.

When every payoff is a line ``f_a(theta) = c_a + d_a theta``, the pointwise best
action changes only where two lines cross, so an optimal decision rule is a
partition of ``[0, 1]`` into intervals with rational end points (a *threshold
rule*). This module builds such rules as upper envelopes, and integrates lines
and posterior means over them under the uniform prior, all in ``Fraction``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from fractions import Fraction
from itertools import combinations


@dataclass(frozen=True)
class Line:
    """``f(theta) = intercept + slope * theta``."""

    intercept: Fraction
    slope: Fraction

    def __call__(self, theta: Fraction) -> Fraction:
        return self.intercept + self.slope * theta

    def __add__(self, other: Line) -> Line:
        return Line(self.intercept + other.intercept, self.slope + other.slope)

    def integral(self, lo: Fraction, hi: Fraction) -> Fraction:
        """``int_lo^hi f(theta) d theta``."""
        return self.intercept * (hi - lo) + self.slope * (hi * hi - lo * lo) / 2


@dataclass(frozen=True)
class Piece:
    """The interval from ``lo`` to ``hi`` (each end open or closed), mapped to ``action``."""

    lo: Fraction
    hi: Fraction
    lo_closed: bool
    hi_closed: bool
    action: int

    @property
    def length(self) -> Fraction:
        return self.hi - self.lo

    def __str__(self) -> str:
        if self.lo == self.hi:
            return f"{{{self.lo}}}"
        return (
            f"{'[' if self.lo_closed else '('}{self.lo}, {self.hi}{']' if self.hi_closed else ')'}"
        )


Rule = tuple[Piece, ...]
"""A decision rule ``delta: [0, 1] -> actions``: pieces in increasing order covering ``[0, 1]``."""


def rule_from_pieces(atoms: Sequence[Piece]) -> Rule:
    """Merge neighbouring pieces that take the same action."""
    merged: list[Piece] = []
    for atom in atoms:
        if merged and merged[-1].action == atom.action:
            last = merged.pop()
            atom = Piece(last.lo, atom.hi, last.lo_closed, atom.hi_closed, atom.action)
        merged.append(atom)
    return tuple(merged)


def upper_envelope(lines: Sequence[Line], priority: Sequence[int]) -> Rule:
    """The rule ``delta(theta) = argmax_a lines[a](theta)`` on ``[0, 1]``.

    Between consecutive crossing points the maximiser is constant (found at the
    midpoint); at a crossing point a tie goes to the action listed first in
    ``priority`` (a set of measure zero, which changes no expected value).
    """
    rank = {action: k for k, action in enumerate(priority)}
    points = {Fraction(0), Fraction(1)}
    for f, g in combinations(lines, 2):
        if f.slope != g.slope:
            crossing = (g.intercept - f.intercept) / (f.slope - g.slope)
            if 0 < crossing < 1:
                points.add(crossing)
    ordered = sorted(points)

    def best(theta: Fraction) -> int:
        return max(range(len(lines)), key=lambda a: (lines[a](theta), -rank[a]))

    atoms = [Piece(ordered[0], ordered[0], True, True, best(ordered[0]))]
    for lo, hi in zip(ordered, ordered[1:], strict=False):
        atoms.append(Piece(lo, hi, False, False, best((lo + hi) / 2)))
        atoms.append(Piece(hi, hi, True, True, best(hi)))
    return rule_from_pieces(atoms)


def preimage(rule: Rule, action: int) -> tuple[Piece, ...]:
    """``delta^{-1}(action)`` as pieces."""
    return tuple(piece for piece in rule if piece.action == action)


def posterior_mean(rule: Rule, action: int) -> Fraction | None:
    """``E[theta | delta(theta) = action]`` under the uniform prior, or ``None`` if the
    action has probability zero."""
    pieces = preimage(rule, action)
    mass = sum((piece.length for piece in pieces), start=Fraction(0))
    if mass == 0:
        return None
    identity = Line(Fraction(0), Fraction(1))
    return sum((identity.integral(p.lo, p.hi) for p in pieces), start=Fraction(0)) / mass


def expected_payoff(rule: Rule, payoff: Sequence[Line]) -> Fraction:
    """``int_0^1 payoff[delta(theta)](theta) d theta`` (uniform prior)."""
    return sum(
        (payoff[piece.action].integral(piece.lo, piece.hi) for piece in rule), start=Fraction(0)
    )


def thresholds(rule: Rule) -> tuple[Fraction, ...]:
    """The points of ``(0, 1)`` where the rule switches action."""
    return tuple(piece.lo for piece in rule[1:])


def action_at(rule: Rule, theta: Fraction) -> int:
    """``delta(theta)``."""
    for piece in rule:
        inside_lo = piece.lo < theta or (piece.lo == theta and piece.lo_closed)
        inside_hi = theta < piece.hi or (piece.hi == theta and piece.hi_closed)
        if inside_lo and inside_hi:
            return piece.action
    raise ValueError(f"{theta} is outside [0, 1]")
