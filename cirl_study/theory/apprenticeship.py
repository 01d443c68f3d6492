"""Apprenticeship CIRL (ACIRL, paper Definition 2): a turn-based CIRL game.

A learning phase of ``learning_steps`` rounds in which the human acts and the robot
watches, then a deployment phase of ``deployment_steps`` rounds in which the robot
acts alone. The waiting player's only available action is :data:`WAIT`, which the
game ignores (paper: "R's action is ignored when t=0 and H's is ignored when
t=1"); being a single action, it tells the other player nothing. States are
``(world_state, t)``; after the last round the game moves to the sink :data:`END`.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Sequence
from numbers import Real

from cirl_study.errors import UserError
from cirl_study.theory.game import CIRLGame, make_game

WAIT = "wait"
"""The action of the player whose turn it is not."""

END = "end"
"""The sink state after the last round."""


def apprenticeship_game(
    *,
    initial_state: Hashable,
    human_actions: Sequence[Hashable],
    robot_actions: Sequence[Hashable],
    step: Callable[[Hashable, Hashable], Hashable],
    reward: Callable[[Hashable, Hashable, Hashable], Real],
    thetas: Sequence[Hashable],
    prior: Sequence[Real],
    learning_steps: int,
    deployment_steps: int,
    gamma: Real = 1,
) -> CIRLGame:
    """Build an ACIRL game with deterministic world dynamics.

    ``step(world_state, action)`` is the next world state after the acting player's
    ``action``; ``reward(world_state, action, theta)`` is the reward of that action.
    ``prior[i]`` is ``P(theta = thetas[i])``; the game starts in ``initial_state``.
    (Stochastic or simultaneous-move games are posed directly with
    :func:`cirl_study.theory.game.make_game`.)
    """
    if learning_steps < 0 or deployment_steps < 0 or learning_steps + deployment_steps < 1:
        raise UserError("an apprenticeship game needs at least one round")
    if len(prior) != len(thetas):
        raise UserError("the prior needs one probability per theta")
    human_actions, robot_actions = tuple(human_actions), tuple(robot_actions)
    if WAIT in human_actions or WAIT in robot_actions:
        raise UserError(f"{WAIT!r} is reserved for the waiting player")
    rounds = learning_steps + deployment_steps
    layers = [[initial_state]]
    for t in range(rounds - 1):
        acting = human_actions if t < learning_steps else robot_actions
        layers.append(list(dict.fromkeys(step(w, a) for w in layers[-1] for a in acting)))
    states = [(w, t) for t, layer in enumerate(layers) for w in layer] + [END]

    def learning(state: Hashable) -> bool:
        return state != END and state[1] < learning_steps

    def transition(state: Hashable, a_h: Hashable, a_r: Hashable) -> dict[Hashable, int]:
        if state == END or state[1] == rounds - 1:
            return {END: 1}
        world, t = state
        return {(step(world, a_h if learning(state) else a_r), t + 1): 1}

    def payoff(state: Hashable, a_h: Hashable, a_r: Hashable, theta: Hashable) -> Real:
        if state == END:
            return 0
        return reward(state[0], a_h if learning(state) else a_r, theta)

    return make_game(
        states=states,
        human_actions=(*human_actions, WAIT),
        robot_actions=(*robot_actions, WAIT),
        thetas=thetas,
        transition=transition,
        reward=payoff,
        initial={((initial_state, 0), theta): p for theta, p in zip(thetas, prior, strict=True)},
        horizon=rounds,
        gamma=gamma,
        human_available=lambda state: human_actions if learning(state) else (WAIT,),
        robot_available=lambda state: (WAIT,) if learning(state) else robot_actions,
    )
