"""Deterministic policy pairs of a CIRL game and their exact value.

A human policy ``pi_H`` maps ``(history, theta)`` to an action of ``H``; a robot
policy ``pi_R`` maps a history to an action of ``R`` (paper section 3.1: both see
the common history, only ``H`` sees ``theta``). Both are plain dictionaries of
indices. The value of a pair is

    V(pi_H, pi_R) = E_{(s_0, theta) ~ P0} [ sum_{t<H} gamma^t R(s_t, a_H,t, a_R,t; theta) ].
"""

from __future__ import annotations

from collections.abc import Mapping
from fractions import Fraction
from typing import TypeAlias

from cirl_study.errors import UserError
from cirl_study.theory.game import CIRLGame, History, Number, round_of

HumanPolicy: TypeAlias = Mapping[tuple[History, int], int]
"""``pi_H[(history, theta)] = a_H`` (indices)."""

RobotPolicy: TypeAlias = Mapping[History, int]
"""``pi_R[history] = a_R`` (indices)."""


def human_action(game: CIRLGame, human: HumanPolicy, history: History, theta: int) -> int:
    """``pi_H(history, theta)``, checked to exist and to be available."""
    action = human.get((history, theta))
    if action is None or action not in game.human_available[history[-1]]:
        raise UserError(
            f"the human policy has no available action for theta={game.thetas[theta]!r} "
            f"at history {history}"
        )
    return action


def robot_action(game: CIRLGame, robot: RobotPolicy, history: History) -> int:
    """``pi_R(history)``, checked to exist and to be available."""
    action = robot.get(history)
    if action is None or action not in game.robot_available[history[-1]]:
        raise UserError(f"the robot policy has no available action at history {history}")
    return action


def value_given_theta(
    game: CIRLGame, human: HumanPolicy, robot: RobotPolicy, history: History, theta: int
) -> Number:
    """Expected discounted reward from ``history`` on (rounds ``t..H-1``), given ``theta``,
    discounted to round ``t``."""
    if round_of(history) == game.horizon:
        return Fraction(0)
    s = history[-1]
    a_h = human_action(game, human, history, theta)
    a_r = robot_action(game, robot, history)
    future = sum(
        (
            p * value_given_theta(game, human, robot, (*history, a_h, a_r, s_next), theta)
            for s_next, p in game.transition[(s, a_h, a_r)]
        ),
        start=Fraction(0),
    )
    return game.reward[(s, a_h, a_r)][theta] + game.gamma * future


def root_value(game: CIRLGame, human: HumanPolicy, robot: RobotPolicy, s0: int) -> Number:
    """``sum_theta P0(s0, theta) V(s0 | theta)``: the initial state's share of the value."""
    return sum(
        (
            p * value_given_theta(game, human, robot, (s0,), theta)
            for theta, p in enumerate(game.initial[s0])
            if p > 0
        ),
        start=Fraction(0),
    )


def evaluate(game: CIRLGame, human: HumanPolicy, robot: RobotPolicy) -> Number:
    """The value ``V(pi_H, pi_R)`` of a policy pair, exact for exact games."""
    return sum((root_value(game, human, robot, s0) for s0 in game.roots), start=Fraction(0))


def demonstration_by_expert(game: CIRLGame) -> dict[tuple[History, int], int]:
    """The demonstration-by-expert policy ``pi^E`` (paper section 3.3).

    ``H`` greedily maximises immediate reward: ``pi^E(h, theta) = argmax_{a_H}
    R(s_t, a_H, a_R; theta)``. In a turn-based game ``R``'s action is ignored on
    ``H``'s turn; in general the reward is averaged over ``R``'s available actions.
    Ties go to the first available action. Defined at every history.
    """
    policy: dict[tuple[History, int], int] = {}
    for history in game.histories():
        s = history[-1]
        robot = game.robot_available[s]
        for theta in range(len(game.thetas)):
            policy[(history, theta)] = max(
                game.human_available[s],
                key=lambda a_h, s=s, theta=theta: sum(
                    game.reward[(s, a_h, a_r)][theta] for a_r in robot
                ),
            )
    return policy


def reachable_histories(
    game: CIRLGame, human: HumanPolicy, robot: RobotPolicy
) -> dict[History, tuple[int, ...]]:
    """Decision histories reached with positive probability under the pair, each with the
    thetas (indices) that reach it, in round order."""
    layer: dict[History, list[int]] = {}
    for s0 in game.roots:
        layer[(s0,)] = [theta for theta, p in enumerate(game.initial[s0]) if p > 0]
    reached: dict[History, tuple[int, ...]] = {}
    for _ in range(game.horizon):
        following: dict[History, list[int]] = {}
        for history, thetas in layer.items():
            reached[history] = tuple(thetas)
            a_r = robot_action(game, robot, history)
            for theta in thetas:
                a_h = human_action(game, human, history, theta)
                for s_next, _ in game.transition[(history[-1], a_h, a_r)]:
                    following.setdefault((*history, a_h, a_r, s_next), []).append(theta)
        layer = following
    return reached


def describe_pair(game: CIRLGame, human: HumanPolicy, robot: RobotPolicy) -> str:
    """One line per reachable history: the path so far, the human's decision rule on the
    thetas that reach it (when she has a choice) and the robot's action (when it has one)."""
    lines = []
    for history, thetas in reachable_histories(game, human, robot).items():
        s = history[-1]
        steps = [str(game.states[history[0]])]
        for k in range(1, len(history), 3):
            a_h, a_r, s_next = history[k : k + 3]
            steps.append(f"--({game.human_actions[a_h]}, {game.robot_actions[a_r]})-->")
            steps.append(str(game.states[s_next]))
        parts = [f"t={round_of(history)} {' '.join(steps)}:"]
        if len(game.human_available[s]) > 1:
            decisions = (human_action(game, human, history, theta) for theta in thetas)
            rule = ", ".join(
                f"{game.thetas[theta]} -> {game.human_actions[a_h]}"
                for theta, a_h in zip(thetas, decisions, strict=True)
            )
            parts.append(f"H: {rule};")
        if len(game.robot_available[s]) > 1:
            parts.append(f"R: {game.robot_actions[robot_action(game, robot, history)]}")
        lines.append(" ".join(parts).rstrip(";"))
    return "\n".join(lines)
