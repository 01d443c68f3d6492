"""One trial of the study: the whole two-phase apprenticeship game (docs/design.md §1-4, §7).

A trial (:class:`~cirl_study.record.TrialSpec`) fixes a gridworld, its features (of any kind,
:mod:`cirl_study.features`), the true reward weights :math:`\\theta`, the robot's rationality
:math:`\\lambda`, the human (with its trade-off :math:`\\eta` where it has one), the
robot, the two horizons and the goal cells, if any (:func:`phases`). It plays:

1. **Learning phase.** The human demonstrates a ``learning_steps`` path from the fixed start
   cell (:data:`cirl_study.core.players.HUMANS`), without the ``stay`` action unless
   ``demonstrator_stays``; the robot's model of the phase has the same moves. In a game with
   goals the path ends on entering one, within at most ``learning_steps`` moves.
2. **Inference.** The robot estimates :math:`\\hat\\theta` from the demonstration
   (:data:`cirl_study.core.players.ROBOTS`).
3. **Deployment phase.** The robot acts optimally for :math:`r_{\\hat\\theta}` for
   ``deployment_steps`` steps (at most, with goals) from a uniformly drawn start
   (``deployment_start = "uniform"``; the measures take the exact expectation over that start,
   :mod:`cirl_study.core.measures`) or from the learning phase's start. Every registered
   measure is computed (:data:`cirl_study.measure_registry.MEASURES`).

:func:`play_trials` plays many trials at once, vectorised over trials that share the game's
shape and rationality: each human's demonstrations together, each demonstration once however
many robots watch it, then each robot's estimates together. It returns one
:class:`~cirl_study.record.TrialRecord` per trial. A record depends only on its own spec,
never on the other trials in the batch.
"""

from __future__ import annotations

import dataclasses
from collections import defaultdict
from collections.abc import Hashable, Iterator, Sequence
from typing import Any

import numpy as np
from msgspec.structs import replace

from cirl_study.core.apprenticeship import Apprenticeship, Outcome
from cirl_study.core.estimate import Estimate
from cirl_study.core.gridworld import (
    Gridworld,
    feature_matrix,
    gridworld,
    paths_actions,
    paths_cells,
)
from cirl_study.core.hypotheses import HypothesisSpace, draw_hypotheses
from cirl_study.core.maxent import MaxEnt, Phase
from cirl_study.core.planning import HardPlan, IntArray, follow_policy, optimal_plan
from cirl_study.core.players import HUMANS, ROBOTS, origin, player_faults
from cirl_study.errors import PlayerFault
from cirl_study.measure_registry import MEASURES
from cirl_study.record import (
    Cell,
    Demonstration,
    Deployment,
    FitDiagnostics,
    TrialRecord,
    TrialSpec,
    setting_faults,
    validated,
)

DEPLOYMENT_ROLLOUTS = 4
"""Deployment start cells per trial whose robot paths are logged for replay."""


def check_playable(spec: TrialSpec) -> None:
    """Raise ``ValueError`` unless ``spec`` is well-typed, names a known human and robot and
    fits its game."""
    validated(spec)
    faults = player_faults(spec.human, spec.robot, spec.eta, spec.teaching is not None)
    faults += setting_faults(spec)
    if not faults:
        faults += _game_faults(spec)
    if faults:
        raise ValueError(f"{spec.trial_id}: {'; '.join(faults)}")


def _game_faults(spec: TrialSpec) -> list[str]:
    """How a sound spec's game cannot be played: with goals, no goal within reach of the
    learning phase's start in ``learning_steps`` moves, or of any deployment start."""
    if not spec.goals:
        return []
    learning, deployment = phases(spec)
    faults = []
    if not learning.reachable[0, learning.start_cell]:
        faults.append(f"no goal is within {spec.learning_steps} moves of start {list(spec.start)}")
    if not deployment.starts.any():
        faults.append(f"no deployment start has a goal within {spec.deployment_steps} moves")
    return faults


def phases(spec: TrialSpec) -> tuple[Phase, Phase]:
    """The dynamics of a trial's learning and deployment phases: the grid's moves (the
    human's without ``stay`` unless ``demonstrator_stays``), their starts, horizons and
    goals."""
    grid = gridworld(spec)
    start = grid.index(*spec.start)
    goals = tuple(grid.index(*goal) for goal in spec.goals)
    learning = Phase(
        grid.demonstrator_moves(spec.demonstrator_stays), start, spec.learning_steps, goals
    )
    deployment_start = start if spec.deployment_start == "demonstration" else None
    deployment = Phase(grid.successors, deployment_start, spec.deployment_steps, goals)
    return learning, deployment


def _group_key(spec: TrialSpec) -> Hashable:
    """What the trials played together share: the game's shape and dynamics, its rationality
    and the teaching settings (every human and robot of a subject are played in one group)."""
    return (
        spec.grid, spec.start, spec.goals, spec.learning_steps, spec.deployment_steps,
        spec.num_features, spec.rationality, spec.demonstrator_stays, spec.deployment_start,
        None if spec.teaching is None else replace(spec.teaching, hypothesis_seed=0),
    )  # fmt: skip


def play_trials(specs: Sequence[TrialSpec]) -> list[TrialRecord]:
    """Play every trial and return their records, in the order given."""
    return _play(specs, None)


def play_watched(specs: Sequence[TrialSpec], demos: np.ndarray) -> list[TrialRecord]:
    """The records of trials whose demonstrations are given, ``demos[b]`` ``(B, T + 1)``
    (cell indices, each a path of its learning phase): the robots' fits, the measures and the
    deployment, as :func:`play_trials` plays them after its humans have shown theirs."""
    return _play(specs, np.asarray(demos, dtype=np.int64))


def _play(specs: Sequence[TrialSpec], demos: np.ndarray | None) -> list[TrialRecord]:
    """Every trial's record, its demonstration shown by its human (``demos`` None) or given."""
    records: list[TrialRecord | None] = [None] * len(specs)
    for positions, group, setting in _settings(specs):
        shown = (
            _demonstrations(setting.game, group, setting.theta, setting.seeds)
            if demos is None
            else demos[positions]
        )
        for position, record in zip(positions, _watched(setting, group, shown), strict=True):
            records[position] = record
    return records  # type: ignore[return-value]


def first_move_paths(specs: Sequence[TrialSpec]) -> np.ndarray:
    """Every trial's path ``(B, T + 1)`` that takes the first available move at each step: a
    path of its learning phase found without any compiled kernel (so the robots' kernels can
    be compiled on it while the humans' compile elsewhere, as
    :func:`cirl_study.study.runner.warm_up` does)."""
    paths = []
    for spec in specs:
        phase = phases(spec)[0]
        path = [phase.start_cell]
        for t in range(1, spec.learning_steps + 1):
            moves = phase.successors[path[-1]]
            path.append(int(next(c for c in moves if c >= 0 and phase.reachable[t, c])))
        paths.append(path)
    return np.array(paths, dtype=np.int64)


def _groups(specs: Sequence[TrialSpec]) -> list[list[int]]:
    """The positions of ``specs`` played together (:func:`_group_key`), once each is checked
    (:func:`check_playable`)."""
    for spec in specs:
        check_playable(spec)
    groups: dict[Hashable, list[int]] = defaultdict(list)
    for position, spec in enumerate(specs):
        groups[_group_key(spec)].append(position)
    return list(groups.values())


def _settings(
    specs: Sequence[TrialSpec],
) -> Iterator[tuple[list[int], list[TrialSpec], _Setting]]:
    """Each group of ``specs`` played together (:func:`_groups`): its positions, its specs
    and their :class:`_Setting`."""
    for positions in _groups(specs):
        group = [specs[p] for p in positions]
        yield positions, group, _Setting.of(group)


def _by(specs: Sequence[TrialSpec], *names: str) -> dict[Any, IntArray]:
    """The positions of ``specs`` by their value of the field ``names[0]`` (or the tuple of
    their values of several fields), in order of appearance."""
    positions: dict[Any, list[int]] = defaultdict(list)
    for position, spec in enumerate(specs):
        values = tuple(getattr(spec, name) for name in names)
        positions[values if len(names) > 1 else values[0]].append(position)
    return {value: np.array(rows, dtype=np.int64) for value, rows in positions.items()}


def _demonstrations(
    game: Apprenticeship, specs: Sequence[TrialSpec], theta: np.ndarray, seeds: np.ndarray
) -> np.ndarray:
    """Every trial's demonstration ``(B, T + 1)``, each distinct one played once.

    Trials of one human with the same seed (the demonstration's, see
    :func:`cirl_study.study.plan.trial_seed`) and ``eta`` show the same path, whichever robot
    watches: it is computed for the first of them and shared.
    """
    demos = np.empty((len(specs), game.learning.phase.horizon + 1), dtype=np.int64)
    for name, rows in _by(specs, "human").items():
        first: dict[tuple[int, float | None], int] = {}
        for row in rows:
            first.setdefault((specs[row].seed, specs[row].eta), int(row))
        distinct = np.array(list(first.values()), dtype=np.int64)
        human = HUMANS[name]
        eta = (
            np.array([specs[row].eta for row in distinct], dtype=np.float64)
            if human.takes_eta
            else None
        )
        shown = human.demonstrate(game.take(distinct), theta[distinct], eta, seeds[distinct])
        _check_paths(game, name, shown, [specs[row].trial_id for row in distinct])
        which = {key: index for index, key in enumerate(first)}
        demos[rows] = shown[[which[specs[row].seed, specs[row].eta] for row in rows]]
    return demos


def _estimates(
    game: Apprenticeship, specs: Sequence[TrialSpec], demos: np.ndarray, seeds: np.ndarray
) -> list[tuple[Estimate, int]]:
    """Every trial's estimate by its robot, one call per robot and settings
    (``gradient_ascent``, which its game carries): for each trial, in order, its robot's
    :class:`Estimate` of the batch it watched and the trial's row in it."""
    fitted: list[tuple[Estimate, int] | None] = [None] * len(specs)
    for (robot, settings), rows in _by(specs, "robot", "gradient_ascent").items():
        watched = dataclasses.replace(game.take(rows), gradient_ascent=settings)
        found = ROBOTS[robot].estimate(watched, demos[rows], seeds[rows])
        due = (len(rows), game.learning.features.shape[2])
        _check_estimate(robot, found, due, [specs[row].trial_id for row in rows])
        for index, row in enumerate(rows):
            fitted[row] = (found, index)
    return fitted  # type: ignore[return-value]


def _check_paths(game: Apprenticeship, human: str, paths: object, trials: list[str]) -> None:
    """Raise :class:`PlayerFault` unless the human ``human`` showed one path of the learning
    phase per trial of ``trials`` (:meth:`~cirl_study.core.maxent.Phase.path_faults`)."""
    faults = game.learning.phase.path_faults(paths)
    if not faults and len(paths) != len(trials):  # type: ignore[arg-type]
        faults = [f"{len(paths)} paths for {len(trials)} trials"]  # type: ignore[arg-type]
    if faults:
        first = _path_number(faults[0])
        trial = trials[first] if first is not None and first < len(trials) else trials[0]
        raise PlayerFault(
            f"human {human!r} ({origin(human)}) showed a demonstration that is not a path of "
            f"the game in trial {trial}: {faults[0]}"
        )


def _path_number(fault: str) -> int | None:
    """The path a fault of :meth:`~cirl_study.core.maxent.Phase.path_faults` names."""
    words = fault.split()
    return int(words[1]) if words[0] == "path" else None


def _check_estimate(robot: str, found: object, shape: tuple[int, int], trials: list[str]) -> None:
    """Raise :class:`PlayerFault` unless the robot ``robot`` returned, for the ``B`` trials
    ``trials``, an :class:`Estimate` a record can hold (:func:`estimate_faults`)."""
    faults = estimate_faults(found, shape, ROBOTS[robot].leaves_box)
    if faults:
        row, what, detail = faults[0]
        raise PlayerFault(
            f"robot {robot!r} ({origin(robot)}) {what} in trial {trials[row]}"
            + (f": {detail}" if detail else "")
        )


def estimate_faults(
    found: object, shape: tuple[int, int], leaves_box: bool
) -> list[tuple[int, str, str]]:
    """What makes ``found`` not an :class:`Estimate` of ``B`` trials of ``K`` weights
    (``shape``) that their records can hold: each fault as the first row it names, what is
    wrong, and the values that show it (``""`` if none). Every
    array of length ``B``; ``theta_hat`` ``(B, K)`` finite, in the box :math:`[-1, 1]^K`
    unless ``leaves_box``; ``log_likelihood`` finite; ``iterations`` whole numbers ``>= 0``;
    ``converged`` booleans; ``theta_hat_se`` (if given) ``(B, K)`` and
    ``effective_sample_size`` (if given) ``(B,)``, finite and ``>= 0``.

    >>> estimate_faults("0.5", (1, 2), False)
    [(0, 'returned a str, not an Estimate,', '')]
    """
    if not isinstance(found, Estimate):
        return [(0, f"returned a {type(found).__name__}, not an Estimate,", "")]
    count, _ = shape
    fields: list[tuple[str, object, tuple[int, ...], str, bool]] = [
        ("theta_hat", found.theta_hat, shape, "fiu", True),
        ("log_likelihood", found.log_likelihood, (count,), "fiu", True),
        ("iterations", found.iterations, (count,), "iu", False),
        ("converged", found.converged, (count,), "b", False),
        ("theta_hat_se", found.theta_hat_se, shape, "fiu", False),
        ("effective_sample_size", found.effective_sample_size, (count,), "fiu", False),
    ]
    for name, value, due, kinds, signed in fields:
        if value is None and name in ("theta_hat_se", "effective_sample_size"):
            continue
        array = np.asarray(value)
        if array.shape != due or array.dtype.kind not in kinds:
            return [(0, f"returned {name} of shape {array.shape} and dtype {array.dtype}, "
                        f"where {due} values of kind {kinds!r} were due,", "")]  # fmt: skip
        if kinds == "b":
            continue
        bad = ~np.isfinite(array) if signed else ~(np.isfinite(array) & (array >= 0))
        if bad.any():
            row = int(np.flatnonzero(bad.reshape(count, -1).any(axis=1))[0])
            what = "not finite" if signed else "not a finite number >= 0"
            return [(row, f"returned a {name} that is {what}", str(array[row].tolist()))]
    theta_hat = np.asarray(found.theta_hat)
    outside = (np.abs(theta_hat) > 1.0).any(axis=1)
    if not leaves_box and outside.any():
        row = int(np.flatnonzero(outside)[0])
        detail = f"{theta_hat[row].tolist()} (a robot whose estimate may leave the box says so: "
        return [(row, "returned a theta_hat outside [-1, 1]^K", detail + "leaves_box=True)")]
    return []


def demonstrations(specs: Sequence[TrialSpec]) -> np.ndarray:
    """Every trial's demonstration ``(B, T + 1)``, in the order given: the learning phase of
    :func:`play_trials` alone, the same paths (cell indices) it plays.

    Lets the humans' kernels be compiled apart from the robots' and the measures'
    (:func:`cirl_study.study.runner.warm_up`).
    """
    demos: list[np.ndarray | None] = [None] * len(specs)
    for positions, group, setting in _settings(specs):
        shown = _demonstrations(setting.game, group, setting.theta, setting.seeds)
        for position, path in zip(positions, shown, strict=True):
            demos[position] = path
    return np.array(demos)


@dataclasses.dataclass(frozen=True)
class _Setting:
    """What trials played together share: their grid, the game (which carries the trials'
    features), and per trial its true ``theta`` ``(B, K)`` and ``seed`` ``(B,)``."""

    grid: Gridworld
    game: Apprenticeship
    theta: np.ndarray
    seeds: np.ndarray

    @classmethod
    def of(cls, specs: Sequence[TrialSpec]) -> _Setting:
        """The setting of ``specs``, trials of one group (:func:`_group_key`)."""
        first = specs[0]
        grid = gridworld(first)
        theta = np.array([spec.theta for spec in specs], dtype=np.float64)
        features = np.stack([feature_matrix(spec) for spec in specs])
        learning_phase, deployment_phase = phases(first)
        learning = MaxEnt(learning_phase, features, first.rationality)
        deployment = MaxEnt(deployment_phase, features, first.rationality)
        hypotheses = _hypotheses(specs, learning, theta)
        recorded = _recorded_paths(grid, learning_phase, specs)
        game = Apprenticeship(learning, deployment, hypotheses, first.teaching, None, recorded)
        seeds = np.array([spec.seed for spec in specs], dtype=np.int64)
        return cls(grid, game, theta, seeds)


def _watched(setting: _Setting, specs: Sequence[TrialSpec], demos: np.ndarray) -> list[TrialRecord]:
    """The records of trials of one group (:func:`_group_key`) that watched ``demos``,
    vectorised: each robot's estimates together, then the measures and the deployment."""
    grid, game, theta = setting.grid, setting.game, setting.theta
    deployment = game.deployment
    fitted = _estimates(game, specs, demos, setting.seeds)
    theta_hat = np.array([estimate.theta_hat[row] for estimate, row in fitted])
    outcome = Outcome(game, theta, theta_hat)
    measured = {name: measure.computed(outcome) for name, measure in MEASURES.items()}
    phase = deployment.phase
    robot_plan = optimal_plan(
        deployment.cell_rewards(theta_hat), phase.successors, phase.horizon, phase.finishing
    )
    rollouts = [
        _path_cells(grid, phase, path) for path in _deployment_rollouts(specs, phase, robot_plan)
    ]
    learning = game.learning.phase
    shown, actions = _path_cells(grid, learning, demos), _path_actions(grid, learning, demos)
    return [
        TrialRecord(
            **{name: getattr(spec, name) for name in TrialSpec.__struct_fields__},
            theta_hat=tuple(float(v) for v in theta_hat[b]),
            demonstration=Demonstration(states=shown[b], actions=actions[b]),
            measures={name: values[b] for name, values in measured.items()},
            **_fit_fields(*fitted[b]),
            deployment=Deployment(
                starts=tuple(path[b][0] for path in rollouts),
                paths=tuple(path[b] for path in rollouts),
            ),
        )
        for b, spec in enumerate(specs)
    ]


def _path_cells(grid: Gridworld, phase: Phase, paths: IntArray) -> list[tuple[Cell, ...]]:
    """The ``[x, y]`` cells of each ``(B, T + 1)`` path of ``phase`` as a record holds it: the
    path actually taken, up to its goal in a phase with goals."""
    if phase.sink is None:
        return paths_cells(grid, paths)
    cells = paths_cells(grid, np.where(paths == phase.sink, 0, paths))
    ends = phase.path_ends(paths)
    return [path[: end + 1] for path, end in zip(cells, ends.tolist(), strict=True)]


def _path_actions(grid: Gridworld, phase: Phase, paths: IntArray) -> list[tuple[str, ...]]:
    """The moves of each path of :func:`_path_cells`."""
    if phase.sink is None:
        return paths_actions(grid, paths)
    ends = phase.path_ends(paths).tolist()
    return [
        paths_actions(grid, path[None, : end + 1])[0] for path, end in zip(paths, ends, strict=True)
    ]


def _fit_fields(estimate: Estimate, row: int) -> dict[str, object]:
    """The record's fields of the robot's fit of trial ``row`` of ``estimate``."""
    return {
        "theta_hat_se": None
        if estimate.theta_hat_se is None
        else tuple(float(v) for v in estimate.theta_hat_se[row]),
        "effective_sample_size": None
        if estimate.effective_sample_size is None
        else float(estimate.effective_sample_size[row]),
        "irl": FitDiagnostics(
            log_likelihood=float(estimate.log_likelihood[row]),
            iterations=int(estimate.iterations[row]),
            converged=bool(estimate.converged[row]),
        ),
    }


def _recorded_paths(grid: Gridworld, phase: Phase, specs: Sequence[TrialSpec]) -> IntArray | None:
    """The participants' demonstrations of ``specs`` as paths ``(B, T + 1)`` of the learning
    ``phase``: each ``recorded.path`` in cell indices, then the sink for every step after its
    goal; ``-1`` for a trial of another human; ``None`` for a batch without recorded trials.
    A path of more cells than the phase has steps keeps its first ``T + 1`` (and is refused
    as the human's fault, :func:`_check_paths`, as a cell off the grid is)."""
    if all(spec.recorded is None for spec in specs):
        return None
    paths = np.full((len(specs), phase.horizon + 1), -1, dtype=np.int64)
    for row, spec in enumerate(specs):
        if spec.recorded is None:
            continue
        cells = [
            grid.index(x, y) if grid.contains(x, y) else -1
            for x, y in spec.recorded.path[: phase.horizon + 1]
        ]
        paths[row, : len(cells)] = cells
        if phase.sink is not None:
            paths[row, len(cells) :] = phase.sink
    return paths


def _hypotheses(
    specs: Sequence[TrialSpec], learning: MaxEnt, theta: np.ndarray
) -> HypothesisSpace | None:
    """The trials' hypothesis spaces: the listed ones, each trial's own ``theta`` first, or
    drawn from each subject's ``hypothesis_seed``."""
    teaching = specs[0].teaching
    if teaching is None:
        return None
    if teaching.listed:
        thetas = np.array(
            [
                [spec.theta] + [listed for listed in teaching.listed if listed != spec.theta]
                for spec in specs
            ],
            dtype=np.float64,
        )
        return HypothesisSpace(learning, thetas, teaching.includes_truth, teaching.alpha)
    seeds = np.array([spec.teaching.hypothesis_seed for spec in specs])  # type: ignore[union-attr]
    thetas = draw_hypotheses(
        theta, seeds, teaching.hypotheses, includes_truth=teaching.includes_truth
    )
    return HypothesisSpace(learning, thetas, teaching.includes_truth, teaching.alpha)


def _deployment_rollouts(
    specs: Sequence[TrialSpec], phase: Phase, plan: HardPlan
) -> list[np.ndarray]:
    """The robot's paths ``(B, T + 1)`` from each trial's own few replay start cells,
    following ``plan`` (the first of tied actions).

    The start cells are drawn from the trial's ``seed``, without replacement, among the
    phase's starts when the deployment starts anywhere (``phase.start`` is ``None``); else
    the one path from the start.
    """
    if phase.start is not None:
        return [follow_policy(phase.successors, np.full(len(specs), phase.start), plan.actions)]
    candidates = np.flatnonzero(phase.starts)
    starts = np.array(
        [
            np.random.default_rng(spec.seed).choice(
                candidates, size=min(DEPLOYMENT_ROLLOUTS, len(candidates)), replace=False
            )
            for spec in specs
        ]
    )
    return [
        follow_policy(phase.successors, starts[:, i], plan.actions) for i in range(starts.shape[1])
    ]
