"""A finite CIRL game as data (paper Definition 1).

``M = <S, {A_H, A_R}, T, {Theta, R}, P0, gamma>`` with finite ``S``, ``A_H``,
``A_R`` and ``Theta`` and a finite horizon ``H``: the players act at rounds
``t = 0, ..., H - 1``. At round ``t`` both observe the state ``s_t`` and all past
actions; the human ``H`` also knows ``theta``. Both receive
``R(s_t, a_H, a_R; theta)``, discounted by ``gamma^t``, and the next state is drawn
from ``T(s' | s_t, a_H, a_R)`` (which does not depend on ``theta``).

A state may restrict which actions are available to each player (a turn-based
game gives the waiting player a single action). Everything is stored by index:
a *history* is the tuple ``(s_0, a_H0, a_R0, s_1, ..., s_t)`` of indices, the common
knowledge of both players at round ``t = len(history) // 3``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Hashable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from fractions import Fraction
from functools import cached_property
from numbers import Real

from cirl_study.errors import UserError

Number = Fraction | float
"""A reward or probability: exact (``Fraction``) or floating point."""

History = tuple[int, ...]
"""``(s_0, a_H0, a_R0, s_1, ..., s_t)`` as indices; its round is ``len // 3``."""

Outcomes = tuple[tuple[int, Number], ...]
"""The successors ``((s', T(s' | s, a_H, a_R)), ...)`` with positive probability."""


def as_number(value: object, what: str) -> Number:
    """Check a number from user input; integers become exact ``Fraction`` values."""
    if isinstance(value, bool) or not isinstance(value, Real):
        raise UserError(f"{what} must be a number, got {value!r}")
    if isinstance(value, Fraction):
        return value
    if isinstance(value, int):
        return Fraction(value)
    number = float(value)
    if not math.isfinite(number):
        raise UserError(f"{what} must be finite, got {value!r}")
    return number


def is_one(total: Number) -> bool:
    """Whether probabilities sum to one: exactly for fractions, to 1e-9 for floats."""
    if isinstance(total, Fraction):
        return total == 1
    return math.isclose(total, 1.0, abs_tol=1e-9)


def check_labels(name: str, labels: tuple[Hashable, ...]) -> None:
    """A game's labels must be present and distinct."""
    if not labels:
        raise UserError(f"a CIRL game needs at least one of {name}")
    if len(set(labels)) != len(labels):
        raise UserError(f"{name} has repeated labels")


def round_of(history: History) -> int:
    """The round ``t`` at which ``history = (s_0, ..., s_t)`` is the common knowledge."""
    return len(history) // 3


@dataclass(frozen=True, eq=False)
class CIRLGame:
    """A finite-horizon CIRL game ``M`` with every table indexed by position.

    ``transition[(s, a_H, a_R)]`` and ``reward[(s, a_H, a_R)]`` exist exactly for the
    available action pairs of each state; ``reward[...]`` holds one entry per
    ``theta``. ``initial[s][theta] = P0(s, theta)``. Build one from labels and
    functions with :func:`make_game`.
    """

    states: tuple[Hashable, ...]
    human_actions: tuple[Hashable, ...]
    robot_actions: tuple[Hashable, ...]
    thetas: tuple[Hashable, ...]
    human_available: tuple[tuple[int, ...], ...]
    robot_available: tuple[tuple[int, ...], ...]
    transition: Mapping[tuple[int, int, int], Outcomes]
    reward: Mapping[tuple[int, int, int], tuple[Number, ...]]
    initial: tuple[tuple[Number, ...], ...]
    gamma: Number
    horizon: int

    def __post_init__(self) -> None:
        """Check shapes and probabilities; raise :class:`UserError` on a malformed game."""
        for name in ("states", "human_actions", "robot_actions", "thetas"):
            check_labels(name, getattr(self, name))
        if self.horizon < 1:
            raise UserError(f"the horizon must be at least 1, got {self.horizon}")
        if not 0 <= self.gamma <= 1:
            raise UserError(f"gamma must lie in [0, 1], got {self.gamma}")
        if len(self.initial) != len(self.states) or any(
            len(row) != len(self.thetas) for row in self.initial
        ):
            raise UserError("P0 must give a probability to every (state, theta)")
        if any(p < 0 for row in self.initial for p in row) or not is_one(
            sum(p for row in self.initial for p in row)
        ):
            raise UserError("P0 must be a probability distribution over states x thetas")
        for available, actions in (
            (self.human_available, self.human_actions),
            (self.robot_available, self.robot_actions),
        ):
            if len(available) != len(self.states) or any(
                not 0 <= a < len(actions) for row in available for a in row
            ):
                raise UserError("the available actions must be action indices, one set per state")
        for s in range(len(self.states)):
            if not self.human_available[s] or not self.robot_available[s]:
                raise UserError(f"state {self.states[s]!r} leaves a player without actions")
            for a_h in self.human_available[s]:
                for a_r in self.robot_available[s]:
                    self._check_pair(s, a_h, a_r)

    def _check_pair(self, s: int, a_h: int, a_r: int) -> None:
        where = f"{self.states[s]!r}, {self.human_actions[a_h]!r}, {self.robot_actions[a_r]!r}"
        outcomes = self.transition.get((s, a_h, a_r))
        rewards = self.reward.get((s, a_h, a_r))
        if outcomes is None or rewards is None or len(rewards) != len(self.thetas):
            raise UserError(f"T and R must be defined for every theta at ({where})")
        if any(p <= 0 for _, p in outcomes) or not is_one(sum(p for _, p in outcomes)):
            raise UserError(f"T( . | {where}) must be a probability distribution")

    @cached_property
    def roots(self) -> tuple[int, ...]:
        """Initial states with positive probability under ``P0``."""
        return tuple(s for s, row in enumerate(self.initial) if any(p > 0 for p in row))

    def histories(self) -> list[History]:
        """Every history at which the players act, for any policies (rounds ``0..H-1``)."""
        layer: list[History] = [(s,) for s in self.roots]
        every: list[History] = []
        for _ in range(self.horizon):
            every.extend(layer)
            layer = [child for history in layer for child in self.children(history)]
        return every

    def children(self, history: History) -> list[History]:
        """Histories one round later: every available action pair and possible successor."""
        s = history[-1]
        return [
            (*history, a_h, a_r, s_next)
            for a_h in self.human_available[s]
            for a_r in self.robot_available[s]
            for s_next, _ in self.transition[(s, a_h, a_r)]
        ]


def make_game(
    *,
    states: Sequence[Hashable],
    human_actions: Sequence[Hashable],
    robot_actions: Sequence[Hashable],
    thetas: Sequence[Hashable],
    transition: Callable[[Hashable, Hashable, Hashable], Mapping[Hashable, Real]],
    reward: Callable[[Hashable, Hashable, Hashable, Hashable], Real],
    initial: Mapping[tuple[Hashable, Hashable], Real],
    horizon: int,
    gamma: Real = 1,
    human_available: Callable[[Hashable], Iterable[Hashable]] | None = None,
    robot_available: Callable[[Hashable], Iterable[Hashable]] | None = None,
) -> CIRLGame:
    """Build a :class:`CIRLGame` from labels and functions.

    ``transition(s, a_H, a_R)`` returns ``{s': T(s' | s, a_H, a_R)}``;
    ``reward(s, a_H, a_R, theta)`` returns ``R(s, a_H, a_R; theta)``; ``initial`` maps
    ``(s, theta)`` to ``P0(s, theta)`` (missing pairs have probability 0).
    ``human_available(s)`` / ``robot_available(s)`` list the actions a player may
    take in ``s`` (default: all). Integers become exact fractions, so a game posed
    with integers and ``Fraction`` values is solved in exact arithmetic.
    """
    states, human_actions = tuple(states), tuple(human_actions)
    robot_actions, thetas = tuple(robot_actions), tuple(thetas)
    for name, labels in (
        ("states", states),
        ("human_actions", human_actions),
        ("robot_actions", robot_actions),
        ("thetas", thetas),
    ):
        check_labels(name, labels)
    state_index = _index(states, "state")
    h_index, r_index = _index(human_actions, "human action"), _index(robot_actions, "robot action")
    theta_index = _index(thetas, "theta")

    def available(
        choose: Callable[[Hashable], Iterable[Hashable]] | None,
        actions: tuple[Hashable, ...],
        index: Callable[[Hashable], int],
    ) -> tuple[tuple[int, ...], ...]:
        if choose is None:
            return tuple(tuple(range(len(actions))) for _ in states)
        return tuple(tuple(sorted({index(a) for a in choose(s)})) for s in states)

    human_av = available(human_available, human_actions, h_index)
    robot_av = available(robot_available, robot_actions, r_index)
    transitions: dict[tuple[int, int, int], Outcomes] = {}
    rewards: dict[tuple[int, int, int], tuple[Number, ...]] = {}
    for s, state in enumerate(states):
        for a_h in human_av[s]:
            for a_r in robot_av[s]:
                key = (s, a_h, a_r)
                args = (state, human_actions[a_h], robot_actions[a_r])
                successors = transition(*args)
                transitions[key] = tuple(
                    (state_index(nxt), as_number(p, f"T({nxt!r} | {args!r})"))
                    for nxt, p in successors.items()
                    if p != 0
                )
                rewards[key] = tuple(
                    as_number(reward(*args, theta), f"R{(*args, theta)!r}") for theta in thetas
                )
    table = [[Fraction(0)] * len(thetas) for _ in states]
    for (state, theta), p in initial.items():
        table[state_index(state)][theta_index(theta)] = as_number(p, f"P0{(state, theta)!r}")
    return CIRLGame(
        states=states,
        human_actions=human_actions,
        robot_actions=robot_actions,
        thetas=thetas,
        human_available=human_av,
        robot_available=robot_av,
        transition=transitions,
        reward=rewards,
        initial=tuple(tuple(row) for row in table),
        gamma=as_number(gamma, "gamma"),
        horizon=int(horizon),
    )


def _index(labels: tuple[Hashable, ...], what: str) -> Callable[[Hashable], int]:
    """A lookup from label to index that reports unknown labels as user errors."""
    positions = {label: i for i, label in enumerate(labels)}

    def lookup(label: Hashable) -> int:
        try:
            return positions[label]
        except (KeyError, TypeError):
            raise UserError(f"unknown {what} {label!r}") from None

    return lookup
