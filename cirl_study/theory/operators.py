"""Best-response operators ``br`` of a CIRL game (paper section 3.3).

* :func:`robot_best_response` — ``br(pi_H)``: the robot keeps the Bayesian (IRL)
  posterior ``b_h`` over ``theta`` given ``pi_H`` (see :mod:`cirl_study.theory.beliefs`)
  and, by backward induction over histories, picks at each history the action
  maximising its expected value under ``b_h``.
* :func:`human_best_response` — ``br(pi_R)``: knowing ``theta`` and ``pi_R``, the
  human faces a finite-horizon MDP over histories and solves it exactly.

Both return complete policies (an action at every history of the game, so that
any other policy may be played against them). Ties go to the first available
action.
"""

from __future__ import annotations

from fractions import Fraction

from cirl_study.theory.beliefs import Belief, initial_belief, update
from cirl_study.theory.game import CIRLGame, History, Number, round_of
from cirl_study.theory.policies import HumanPolicy, RobotPolicy, human_action, robot_action


def robot_best_response(game: CIRLGame, human: HumanPolicy) -> dict[History, int]:
    """``br(pi_H)``: Bayes-update on ``H``'s actions, then act optimally under the belief.

    At history ``h`` with belief ``b_h`` the robot picks
    ``argmax_{a_R} sum_theta b_h(theta) [R(s, pi_H(h, theta), a_R; theta)
    + gamma sum_{s'} T(s' | s, pi_H(h, theta), a_R) v(h', theta)]``, where ``v(h', theta)``
    is the value from the child history under the robot's own (already chosen)
    later actions. Every reachable history is weighted by its probability, so
    this maximises ``V(pi_H, pi_R)`` over ``pi_R``.
    """
    policy: dict[History, int] = {}
    for s0 in game.roots:
        _robot_values(game, human, (s0,), initial_belief(game, s0), policy)
    return policy


def _robot_values(
    game: CIRLGame,
    human: HumanPolicy,
    history: History,
    belief: Belief,
    policy: dict[History, int],
) -> dict[int, Number]:
    """Fill ``policy`` below ``history``; return ``v(history, theta)`` on the belief's support."""
    if round_of(history) == game.horizon:
        return {theta: Fraction(0) for theta, p in enumerate(belief) if p > 0}
    s = history[-1]
    acts = {
        theta: human_action(game, human, history, theta) for theta, p in enumerate(belief) if p > 0
    }
    beliefs = {a_h: update(game, human, belief, history, a_h) for a_h in game.human_available[s]}
    best: tuple[Number, int, dict[int, Number]] | None = None
    for a_r in game.robot_available[s]:
        child_values = {
            (a_h, s_next): _robot_values(
                game, human, (*history, a_h, a_r, s_next), beliefs[a_h], policy
            )
            for a_h in game.human_available[s]
            for s_next, _ in game.transition[(s, a_h, a_r)]
        }
        values = {
            theta: game.reward[(s, a_h, a_r)][theta]
            + game.gamma
            * sum(
                (
                    p * child_values[(a_h, s_next)][theta]
                    for s_next, p in game.transition[(s, a_h, a_r)]
                ),
                start=Fraction(0),
            )
            for theta, a_h in acts.items()
        }
        expected = sum((belief[theta] * v for theta, v in values.items()), start=Fraction(0))
        if best is None or expected > best[0]:
            best = (expected, a_r, values)
    assert best is not None  # every state has an available robot action
    policy[history] = best[1]
    return best[2]


def human_best_response(game: CIRLGame, robot: RobotPolicy) -> dict[tuple[History, int], int]:
    """``br(pi_R)``: for each ``theta``, the optimal policy of the MDP over histories

    v(h, theta) = max_{a_H} R(s, a_H, pi_R(h); theta)
                  + gamma sum_{s'} T(s' | s, a_H, pi_R(h)) v(h', theta).
    """
    policy: dict[tuple[History, int], int] = {}
    for theta in range(len(game.thetas)):
        for s0 in game.roots:
            _human_value(game, robot, (s0,), theta, policy)
    return policy


def _human_value(
    game: CIRLGame,
    robot: RobotPolicy,
    history: History,
    theta: int,
    policy: dict[tuple[History, int], int],
) -> Number:
    """Fill ``policy`` for ``theta`` below ``history`` (also after robot actions other than
    ``pi_R``'s, so the policy is complete); return ``v(history, theta)``."""
    if round_of(history) == game.horizon:
        return Fraction(0)
    s = history[-1]
    chosen = robot_action(game, robot, history)
    best: tuple[Number, int] | None = None
    for a_r in game.robot_available[s]:
        for a_h in game.human_available[s]:
            future = sum(
                (
                    p * _human_value(game, robot, (*history, a_h, a_r, s_next), theta, policy)
                    for s_next, p in game.transition[(s, a_h, a_r)]
                ),
                start=Fraction(0),
            )
            value = game.reward[(s, a_h, a_r)][theta] + game.gamma * future
            if a_r == chosen and (best is None or value > best[0]):
                best = (value, a_h)
    assert best is not None  # the robot's action is available, and so is some human action
    policy[(history, theta)] = best[1]
    return best[0]
