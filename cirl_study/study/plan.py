"""The trials of a run: who plays what, under which id, with which random numbers.

Identity. A *subject* is one reward draw; its id names the group it belongs to (``cv`` for
the cross-validation draws, ``main`` for the test draws shared by the main study and the
lambda sweep), the number of features and a 1-based index, e.g. ``main-k03-s0001``, so it
is unique across feature levels and the two groups never share a draw. A *trial* is a
subject played in one block with one policy (and its ``eta``), rationality ``lambda`` and
robot; its id spells all of these out, e.g.
``lambda_sweep:main-k10-s0042:best_response:lambda=0.001:eta=0.316:robot=map`` (floats in
Python's shortest round-trip form; an expert trial has no ``eta`` part). Every robot of the
pipeline watches the same subjects under the same policies: the robot is a within-subjects
factor of the ``main`` and ``lambda_sweep`` blocks, and the eta cross-validation is played by
the reference robot alone (:attr:`cirl_study.study.spec.MainSpec.reference_robot`).

Randomness. Every stream is a :class:`numpy.random.SeedSequence` with the pipeline's root
seed as entropy and, as spawn key, the BLAKE2b hash of the identity string
(``subject:<subject id>`` or ``trial:<trial id>``). Nothing depends on the order in which
trials are planned, batched or played. A subject's stream draws, in this order, its ``K``
RBF centres uniformly over the continuous extent ``[0, width-1] x [0, height-1]`` and then
``theta ~ Uniform[-1, 1]^K``; every trial of the subject (both policies, every lambda) sees
the same centres and ``theta``. A trial's ``seed`` is the first 53 bits of its own stream
(an integer that every JSON reader holds exactly).
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from cirl_study.record import ETA_CV, LAMBDA_SWEEP, MAIN, Grid, RBFFeatures, TrialSpec
from cirl_study.study.spec import Pipeline

CV_GROUP = "cv"
"""Subject-id prefix of the cross-validation draws."""

TEST_GROUP = "main"
"""Subject-id prefix of the test draws (blocks ``main`` and ``lambda_sweep``)."""


def random_stream(root_seed: int, identity: str) -> np.random.SeedSequence:
    """The seed sequence of ``identity``: entropy ``root_seed``, spawn key BLAKE2b(identity)."""
    digest = hashlib.blake2b(identity.encode(), digest_size=16).digest()
    spawn_key = tuple(int(word) for word in np.frombuffer(digest, dtype="<u4"))
    return np.random.SeedSequence(entropy=root_seed, spawn_key=spawn_key)


def subject_id(group: str, num_features: int, index: int) -> str:
    """Id of reward draw ``index`` (1-based) of ``group`` at ``num_features`` features."""
    return f"{group}-k{num_features:02d}-s{index:04d}"


def trial_id(
    block: str, subject: str, policy: str, rationality: float, eta: float | None, robot: str
) -> str:
    """Stable id of a trial, spelling out its whole identity."""
    eta_part = "" if eta is None else f":eta={float(eta)!r}"
    return f"{block}:{subject}:{policy}:lambda={float(rationality)!r}{eta_part}:robot={robot}"


def trial_seed(root_seed: int, trial: str) -> int:
    """The ``seed`` of trial ``trial``: 53 bits of its own stream."""
    return int(random_stream(root_seed, f"trial:{trial}").generate_state(1, np.uint64)[0] >> 11)


@dataclass(frozen=True)
class Subject:
    """One reward draw: its RBF features and ``theta``."""

    id: str
    num_features: int
    features: RBFFeatures
    theta: tuple[float, ...]


def draw_subject(pipeline: Pipeline, group: str, num_features: int, index: int) -> Subject:
    """Draw subject ``index`` of ``group``: centres ``c_k`` then ``theta``, from its own stream."""
    ident = subject_id(group, num_features, index)
    game = pipeline.game
    rng = np.random.default_rng(random_stream(pipeline.seed, f"subject:{ident}"))
    centers = rng.uniform((0.0, 0.0), (game.width - 1, game.height - 1), size=(num_features, 2))
    theta = rng.uniform(-1.0, 1.0, size=num_features)
    features = RBFFeatures(
        centers=tuple((float(x), float(y)) for x, y in centers), sigma=game.sigma
    )
    return Subject(ident, num_features, features, tuple(float(t) for t in theta))


def _subjects(pipeline: Pipeline, group: str, num_features: int, count: int) -> list[Subject]:
    return [draw_subject(pipeline, group, num_features, i) for i in range(1, count + 1)]


def _trial(
    pipeline: Pipeline,
    block: str,
    subject: Subject,
    policy: str,
    rationality: float,
    eta: float | None,
    robot: str,
) -> TrialSpec:
    ident = trial_id(block, subject.id, policy, rationality, eta, robot)
    game = pipeline.game
    return TrialSpec(
        trial_id=ident,
        run_id=pipeline.run_id,
        block=block,
        subject=subject.id,
        policy=policy,
        num_features=subject.num_features,
        rationality=rationality,
        eta=eta,
        seed=trial_seed(pipeline.seed, ident),
        grid=Grid(width=game.width, height=game.height),
        start=game.start,
        learning_steps=game.learning_steps,
        deployment_steps=game.deployment_steps,
        features=subject.features,
        theta=subject.theta,
        robot=robot,
    )


def eta_cv_trials(pipeline: Pipeline) -> list[TrialSpec]:
    """Block ``eta_cv``: each policy with a trade-off at every eta of the grid, on ``cv`` draws,
    watched by the reference robot."""
    cv = pipeline.eta_cv
    robot = pipeline.main.reference_robot
    trials = []
    for k in pipeline.game.feature_levels:
        subjects = _subjects(pipeline, CV_GROUP, k, cv.subjects)
        trials += [
            _trial(pipeline, ETA_CV, subject, policy, cv.rationality, eta, robot)
            for policy in pipeline.policies_with_eta
            for eta in cv.etas
            for subject in subjects
        ]
    return trials


def study_trials(pipeline: Pipeline, etas: Mapping[tuple[str, int], float]) -> list[TrialSpec]:
    """Blocks ``main`` and ``lambda_sweep`` on the ``main`` draws, for every robot.

    A policy with a trade-off plays at feature level ``K`` with ``etas[policy, K]`` (the
    cross-validated choice, :func:`cirl_study.study.eta_cv.choose_etas`); the sweep plays the
    first ``lambda_sweep.subjects`` draws of the main block.
    """
    main, sweep = pipeline.main, pipeline.lambda_sweep
    levels = pipeline.game.feature_levels
    subjects = {k: _subjects(pipeline, TEST_GROUP, k, main.subjects) for k in levels}

    def eta_of(policy: str, k: int) -> float | None:
        return etas[policy, k] if policy in pipeline.policies_with_eta else None

    main_block = [
        _trial(pipeline, MAIN, subject, policy, main.rationality, eta_of(policy, k), robot)
        for k in levels
        for robot in main.robots
        for policy in main.policies
        for subject in subjects[k]
    ]
    sweep_block = [
        _trial(pipeline, LAMBDA_SWEEP, subject, policy, rationality, eta_of(policy, k), robot)
        for k in levels
        for rationality in sweep.rationalities
        for robot in main.robots
        for policy in main.policies
        for subject in subjects[k][: sweep.subjects]
    ]
    return main_block + sweep_block


def trial_counts(pipeline: Pipeline) -> dict[str, int]:
    """Number of trials of each block (known before eta is chosen)."""
    levels = len(pipeline.game.feature_levels)
    policies = len(pipeline.main.policies) * len(pipeline.main.robots)
    sweep = pipeline.lambda_sweep
    cv = pipeline.eta_cv
    return {
        ETA_CV: levels * cv.subjects * len(cv.etas) * len(pipeline.policies_with_eta),
        MAIN: levels * pipeline.main.subjects * policies,
        LAMBDA_SWEEP: levels * sweep.subjects * len(sweep.rationalities) * policies,
    }
