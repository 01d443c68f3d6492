"""One whole trial (docs/design.md §1-4 and §7), re-derived from its record by brute force."""

import dataclasses
import itertools
import json

import msgspec
import numpy as np
import path_enumeration as bf
import pytest

from cirl_study.core.estimate import Estimate
from cirl_study.core.maxent import Phase
from cirl_study.core.players import HUMANS, ROBOTS, Human, Robot, register_human, register_robot
from cirl_study.core.trial import (
    check_playable,
    demonstrations,
    first_move_paths,
    play_trials,
    play_watched,
)
from cirl_study.errors import PlayerFault
from cirl_study.features import RBFFeatures
from cirl_study.measure_registry import PAPER_MEASURES
from cirl_study.record import (
    MAP,
    Deployment,
    FitDiagnostics,
    Grid,
    TrialRecord,
    TrialSpec,
    decode,
    encode,
    to_builtins,
)

CENTERS = ((0.5, 2.0), (3.0, 1.0), (2.0, 3.5))
SIGMA = 1.5
GAME = {
    "grid": Grid(width=4, height=4),
    "start": (1, 2),
    "learning_steps": 4,
    "deployment_steps": 3,
    "features": RBFFeatures(centers=CENTERS, sigma=SIGMA),
}

TOP_LEVEL = {
    "trial_id",
    "run_id",
    "block",
    "subject",
    "human",
    "num_features",
    "rationality",
    "eta",
    "seed",
    "grid",
    "start",
    "learning_steps",
    "deployment_steps",
    "features",
    "theta",
    "robot",
    "theta_hat",
    "demonstration",
    "measures",
    "irl",
    "deployment",
}


def _spec(human, theta, *, eta=0.5, rationality=1.0, trial_id=None, game=None):
    return TrialSpec(
        trial_id=trial_id or f"t-{human}-{theta[0]:.3f}-{rationality:g}",
        run_id="run-test",
        block="main",
        subject="s-1",
        human=human,
        num_features=len(theta),
        rationality=rationality,
        eta=eta if human == "best_response" else None,
        seed=7,
        theta=tuple(float(v) for v in theta),
        **(game or GAME),
    )


def _specs():
    rng = np.random.default_rng(2016)
    specs = []
    for rationality in (1e-4, 1.0, 1e3):
        theta = rng.uniform(-1, 1, size=3)
        specs.append(_spec("expert", theta, rationality=rationality))
        specs.append(_spec("best_response", theta, eta=0.3, rationality=rationality))
    return specs


@pytest.fixture(scope="module")
def played():
    specs = _specs()
    return specs, play_trials(specs)


def _context(record):
    """Everything the brute-force reference needs, read back from the record alone."""
    width, height = record.grid.width, record.grid.height
    assert record.features.kind == "rbf"
    features = bf.rbf_features(width, height, record.features.centers, record.features.sigma)
    start = bf.cell(width, *record.start)
    return width, height, features, start


def _demo_states(record):
    return [bf.cell(record.grid.width, x, y) for x, y in record.demonstration.states]


def _assert_box_map(record):
    """``theta_hat`` is the box MAP of the record's demonstration, with its exact LL."""
    width, height, features, start = _context(record)
    horizon, rationality = record.learning_steps, record.rationality
    counts = bf.feature_counts(bf.enumerate_paths(width, height, start, horizon), features)
    demo = bf.feature_counts([_demo_states(record)], features)[0]
    theta_hat = np.array(record.theta_hat)
    assert np.all(np.abs(theta_hat) <= 1.0)
    slope = demo - bf.expected_features(counts, theta_hat, rationality)
    outward = ((theta_hat >= 1.0) & (slope > 0)) | ((theta_hat <= -1.0) & (slope < 0))
    assert np.abs(np.where(outward, 0.0, slope)).max() <= 1e-6
    assert record.irl.converged is True
    ll = bf.log_likelihood(demo, counts, theta_hat, rationality)
    assert record.irl.log_likelihood == pytest.approx(ll, rel=1e-10, abs=1e-10)


def test_record_has_every_field_of_the_contract_and_is_plain_json(played):
    specs, records = played
    assert len(records) == len(specs)
    for spec, record in zip(specs, records, strict=True):
        assert isinstance(record, TrialRecord)
        data = json.loads(encode(record))  # what a reader of the log sees
        assert set(data) >= TOP_LEVEL
        assert json.loads(json.dumps(data, allow_nan=False)) == data
        assert json.loads(json.dumps(to_builtins(record), allow_nan=False)) == data
        assert decode(encode(record)) == record  # valid against the record's schema
        assert record.spec() == spec
        assert record.trial_id == spec.trial_id and record.human == spec.human
        assert record.run_id == spec.run_id and record.subject == spec.subject
        assert record.block == spec.block and record.seed == spec.seed
        assert record.num_features == 3 == len(record.theta) == len(record.theta_hat)
        assert record.rationality == spec.rationality
        assert record.eta == (spec.eta if spec.human == "best_response" else None)
        assert record.robot == MAP
        assert record.grid == Grid(width=4, height=4)
        assert data["grid"] == {"width": 4, "height": 4}
        assert record.start == (1, 2) and data["start"] == [1, 2]
        assert (record.learning_steps, record.deployment_steps) == (4, 3)
        assert record.features.centers == CENTERS
        assert data["features"]["centers"] == [list(c) for c in CENTERS]
        assert record.features.sigma == SIGMA
        assert record.theta == spec.theta
        assert isinstance(record.measures, dict)
        assert set(data["measures"]) >= set(PAPER_MEASURES) == {"regret", "kl", "reward_l2"}
        assert isinstance(record.irl, FitDiagnostics)
        assert set(data["irl"]) >= {"log_likelihood", "iterations", "converged"}
        assert isinstance(record.deployment, Deployment)
        assert set(data["deployment"]) >= {"starts", "paths"}


def test_demonstration_is_the_policy_s_optimal_path(played):
    _, records = played
    for record in records:
        width, height, features, start = _context(record)
        horizon = record.learning_steps
        demo = record.demonstration
        states = _demo_states(record)
        assert bf.is_path(width, height, states, start, horizon)
        assert len(demo.actions) == horizon
        for here, there, name in zip(states[:-1], states[1:], demo.actions, strict=True):
            assert bf.move(width, height, here, name) == there
        counts = bf.feature_counts(bf.enumerate_paths(width, height, start, horizon), features)
        got = bf.feature_counts([states], features)
        theta = np.array(record.theta)
        if record.human == "expert":
            _, best = bf.expert(counts, theta)
            assert got[0] @ theta == pytest.approx(best, rel=1e-12, abs=1e-12)
        else:
            eta, rationality = record.eta, record.rationality
            _, best = bf.best_response(counts, theta, eta, rationality)
            phi_theta = bf.expected_features(counts, theta, rationality)
            value = bf.best_response_objective(got, theta, eta, phi_theta)[0]
            assert value == pytest.approx(best, abs=1e-9 * max(1.0, abs(best)))


def test_theta_hat_is_the_box_map_of_the_demonstration(played):
    _, records = played
    for record in records:
        _assert_box_map(record)


def test_measures_equal_the_brute_force_measures_of_the_record(played):
    _, records = played
    for record in records:
        width, height, features, _ = _context(record)
        theta, theta_hat = record.theta, record.theta_hat
        horizon, rationality = record.deployment_steps, record.rationality
        measures = record.measures
        want_regret = bf.regret(width, height, features, theta, theta_hat, horizon)
        want_kl = bf.kl(width, height, features, theta, theta_hat, horizon, rationality)
        assert measures["regret"] == pytest.approx(want_regret, abs=1e-12)
        assert measures["kl"] == pytest.approx(want_kl, rel=1e-8, abs=1e-12)
        assert measures["reward_l2"] == pytest.approx(
            bf.reward_l2(features, theta, theta_hat), rel=1e-12
        )
        assert measures["regret"] >= -1e-12 and measures["kl"] >= 0.0


def test_deployment_paths_are_optimal_for_theta_hat(played):
    _, records = played
    for record in records:
        width, height, features, _ = _context(record)
        horizon = record.deployment_steps
        best = bf.optimal_values(width, height, features, record.theta_hat, horizon)
        deployment = record.deployment
        assert len(deployment.starts) == len(deployment.paths) >= 1
        for start_xy, path in zip(deployment.starts, deployment.paths, strict=True):
            start = bf.cell(width, *start_xy)
            states = [bf.cell(width, x, y) for x, y in path]
            assert bf.is_path(width, height, states, start, horizon)
            value = bf.feature_counts([states], features)[0] @ np.array(record.theta_hat)
            assert value == pytest.approx(best[start], abs=1e-12)


def test_a_record_depends_only_on_its_spec(played):
    specs, records = played
    # alone, in another order, and in a batch with other grids and horizons
    other = {
        "grid": Grid(width=3, height=5),
        "start": (1, 1),
        "learning_steps": 3,
        "deployment_steps": 2,
        "features": RBFFeatures(centers=((0.0, 0.0), (2.0, 4.0)), sigma=1.0),
    }
    stranger = _spec("best_response", (0.2, -0.9), eta=2.0, trial_id="stranger", game=other)
    assert play_trials([specs[3]]) == [records[3]]
    shuffled = play_trials([specs[5], stranger, specs[1], specs[3]])
    assert shuffled[0] == records[5]
    assert shuffled[2] == records[1]
    assert shuffled[3] == records[3]
    assert shuffled[1].trial_id == "stranger" and shuffled[1].grid.height == 5


def test_the_true_reward_is_not_recovered_by_a_broken_demonstration(played):
    # A check that can fail: the measures of the record disagree with those of a wrong theta_hat.
    _, records = played
    record = records[1]
    width, height, features, _ = _context(record)
    wrong = [-v for v in record.theta_hat]
    assert record.measures["reward_l2"] != pytest.approx(
        bf.reward_l2(features, record.theta, wrong), rel=1e-6
    )


# ---- what play_trials refuses ---------------------------------------------------------------


def _expert():
    return _spec("expert", (0.4, -0.7, 0.1), trial_id="expert")


def _best_response():
    return _spec("best_response", (0.4, -0.7, 0.1), eta=0.3, trial_id="best-response")


UNPLAYABLE = {
    "unknown human": (
        lambda: _spec("novice", (0.4, -0.7, 0.1)),
        "human 'novice' is not a known human",
    ),
    "unknown robot": (
        lambda: msgspec.structs.replace(_expert(), robot="bayes"),
        "robot 'bayes' is not a known robot",
    ),
    "eta given to the expert": (lambda: msgspec.structs.replace(_expert(), eta=0.5), "eta"),
    "eta missing for the best response": (
        lambda: msgspec.structs.replace(_best_response(), eta=None),
        "eta",
    ),
    "theta too short": (
        lambda: msgspec.structs.replace(_expert(), theta=(0.4, -0.7)),
        "num_features",
    ),
    "num_features wrong": (
        lambda: msgspec.structs.replace(_best_response(), num_features=2),
        "num_features",
    ),
    "a center too many": (
        lambda: msgspec.structs.replace(
            _expert(), features=RBFFeatures(centers=(*CENTERS, (1.0, 1.0)), sigma=SIGMA)
        ),
        "num_features",
    ),
    "start off the grid": (lambda: msgspec.structs.replace(_expert(), start=(4, 0)), "outside"),
}


def test_watching_the_humans_demonstrations_is_playing_the_trials(played):
    specs, records = played
    watched = play_watched(specs, demonstrations(specs))
    assert [encode(record) for record in watched] == [encode(record) for record in records]


@pytest.mark.parametrize("stays", [True, False])
def test_first_move_paths_are_paths_of_the_learning_phase(stays):
    specs = [msgspec.structs.replace(spec, demonstrator_stays=stays) for spec in _specs()]
    paths = first_move_paths(specs)
    assert paths.shape == (len(specs), GAME["learning_steps"] + 1)
    for spec, path in zip(specs, paths, strict=True):
        states = [bf.xy(spec.grid.width, int(cell)) for cell in path]
        assert states[0] == spec.start
        steps = [(b[0] - a[0], b[1] - a[1]) for a, b in zip(states, states[1:], strict=False)]
        allowed = {(1, 0), (-1, 0), (0, 1), (0, -1)} | ({(0, 0)} if stays else set())
        assert set(steps) <= allowed
    watched = play_watched(specs, paths)
    assert [r.demonstration.states for r in watched] == [
        tuple(bf.xy(GAME["grid"].width, int(cell)) for cell in path) for path in paths
    ]


def test_playable_specs_pass_the_check():
    for spec in [*_specs(), _expert(), _best_response()]:
        assert check_playable(spec) is None


@pytest.mark.parametrize("case", UNPLAYABLE)
def test_an_unplayable_spec_is_refused(case):
    make, message = UNPLAYABLE[case]
    spec = make()
    with pytest.raises(ValueError, match=message):
        check_playable(spec)
    # One bad spec refuses the whole batch, wherever it is.
    with pytest.raises(ValueError, match=message):
        play_trials([_expert(), spec, _best_response()])


# ---- a human added by registration ----------------------------------------------------------

LAST_PATH, STAY_PUT = "test-last-path", "test-stay-put"


def _last_path(game, theta, eta, seeds):
    """At every step the highest-index available action: the lexicographically last path."""
    assert eta is None
    phase = game.learning.phase
    rows = np.arange(len(theta))
    paths = np.empty((len(theta), phase.horizon + 1), dtype=np.int64)
    paths[:, 0] = phase.start_cell
    for t in range(phase.horizon):
        moves = phase.successors[paths[:, t]]  # (B, A)
        last = moves.shape[1] - 1 - np.argmax((moves >= 0)[:, ::-1], axis=1)
        paths[:, t + 1] = moves[rows, last]
    return paths


@pytest.fixture
def toy_humans():
    """Register two toy humans for one test; yields the etas the one with a trade-off got."""
    received = []

    def stay_put(game, theta, eta, seeds):
        received.append(np.array(eta))
        phase = game.learning.phase
        return np.full((len(theta), phase.horizon + 1), phase.start_cell)

    try:
        register_human(LAST_PATH, Human(_last_path, takes_eta=False))
        register_human(STAY_PUT, Human(stay_put, takes_eta=True))
        yield received
    finally:
        HUMANS.pop(LAST_PATH, None)
        HUMANS.pop(STAY_PUT, None)


def test_a_registered_human_is_played_by_name(toy_humans):
    theta = (0.4, -0.7, 0.1)
    specs = [
        _spec(LAST_PATH, theta, trial_id="last"),
        _spec(STAY_PUT, theta, trial_id="stay-1"),
        _spec(STAY_PUT, (-0.2, 0.5, 0.9), trial_id="stay-2"),
    ]
    specs[1] = msgspec.structs.replace(specs[1], eta=0.3)
    specs[2] = msgspec.structs.replace(specs[2], eta=2.0)
    last, stay_1, stay_2 = play_trials(specs)

    width, height, _, start = _context(last)
    want = bf.enumerate_paths(width, height, start, last.learning_steps)[-1]
    assert last.human == LAST_PATH and last.eta is None
    assert last.demonstration.states == tuple(bf.xy(width, s) for s in want)
    assert want != (start,) * (last.learning_steps + 1)  # it is not the trivial path
    for here, there, name in zip(want[:-1], want[1:], last.demonstration.actions, strict=True):
        assert bf.move(width, height, here, name) == there

    for record in (stay_1, stay_2):
        assert record.human == STAY_PUT
        assert record.demonstration.states == (record.start,) * (record.learning_steps + 1)
        assert record.demonstration.actions == ("stay",) * record.learning_steps
    assert (stay_1.eta, stay_2.eta) == (0.3, 2.0)
    # one batch, the trials' own etas in order
    assert len(toy_humans) == 1
    np.testing.assert_array_equal(toy_humans[0], [0.3, 2.0])

    for record in (last, stay_1, stay_2):  # the rest of the trial is played on that demonstration
        _assert_box_map(record)
        assert decode(encode(record)) == record


def test_a_registered_human_is_checked_like_the_paper_s(toy_humans):
    theta = (0.4, -0.7, 0.1)
    with pytest.raises(ValueError, match="eta"):
        check_playable(msgspec.structs.replace(_spec(LAST_PATH, theta), eta=0.3))
    with pytest.raises(ValueError, match="eta"):
        check_playable(_spec(STAY_PUT, theta))  # eta is None for a human that needs it
    with pytest.raises(ValueError):
        register_human(LAST_PATH, Human(_last_path, takes_eta=False))


def test_each_demonstration_is_played_once_for_every_robot_that_watches_it(toy_humans):
    # Three robots watch two demonstrations (seeds 7 and 8) of the same human: the human is
    # asked once, for the two distinct ones, and every robot's record holds its demonstration.
    theta = (0.4, -0.7, 0.1)
    shown = [
        msgspec.structs.replace(
            _spec(STAY_PUT, theta, trial_id=f"stay-{seed}-{robot}"),
            eta=float(seed),
            seed=seed,
            robot=robot,
        )
        for seed in (7, 8)
        for robot in ("map", "prior_mean-test", "map-again-test")
    ]
    prior_mean = Robot(
        lambda game, demos, seeds: Estimate(
            theta_hat=np.zeros((len(demos), game.learning.features.shape[2])),
            log_likelihood=np.zeros(len(demos)),
            iterations=np.zeros(len(demos), dtype=np.int64),
            converged=np.ones(len(demos), dtype=bool),
        )
    )
    register_robot("prior_mean-test", prior_mean)
    register_robot("map-again-test", ROBOTS["map"])
    try:
        records = play_trials(shown)
    finally:
        del ROBOTS["prior_mean-test"], ROBOTS["map-again-test"]
    assert len(toy_humans) == 1
    np.testing.assert_array_equal(toy_humans[0], [7.0, 8.0])  # one row per demonstration
    for record, spec in zip(records, shown, strict=True):
        assert record.trial_id == spec.trial_id and record.robot == spec.robot
        assert record.demonstration.states == (record.start,) * (record.learning_steps + 1)
    by_robot = {r.robot: r for r in records if r.seed == 7}
    assert by_robot["prior_mean-test"].theta_hat == (0.0, 0.0, 0.0)
    assert by_robot["map"].theta_hat == by_robot["map-again-test"].theta_hat
    assert by_robot["map"].theta_hat != (0.0, 0.0, 0.0)


# ---- a player's output is checked where it enters ---------------------------------------------


@pytest.fixture
def faulty_players():
    """Register, for one test, humans and robots that break their contracts."""

    def jumps(game, theta, eta, seeds):
        paths = np.full((len(theta), game.learning.phase.horizon + 1), game.learning.phase.start)
        paths[:, 2] = 15  # two moves or more from the start
        return paths

    def short(game, theta, eta, seeds):
        return np.zeros((len(theta), 2), dtype=np.int64)

    def not_finite(game, demos, seeds):
        estimate = ROBOTS["map"].estimate(game, demos, seeds)
        theta_hat = estimate.theta_hat.copy()
        theta_hat[-1, 0] = np.nan
        return dataclasses.replace(estimate, theta_hat=theta_hat)

    def one_short(game, demos, seeds):
        estimate = ROBOTS["map"].estimate(game, demos, seeds)
        return dataclasses.replace(estimate, theta_hat=estimate.theta_hat[:, 1:])

    humans = {"jumps": Human(jumps, takes_eta=False), "short": Human(short, takes_eta=False)}
    robots = {"not_finite": Robot(not_finite), "one_short": Robot(one_short)}
    try:
        for name, human in humans.items():
            register_human(name, human)
        for name, robot in robots.items():
            register_robot(name, robot)
        yield
    finally:
        for name in humans:
            HUMANS.pop(name, None)
        for name in robots:
            ROBOTS.pop(name, None)


@pytest.mark.parametrize(
    ("human", "robot", "message"),
    [
        (
            "jumps",
            "map",
            "human 'jumps' (registered in this process) showed a demonstration that is not a "
            "path of the game in trial first: path 0 goes from cell 9 to cell 15 at step 2: "
            "not one available move",
        ),
        (
            "short",
            "map",
            "human 'short' (registered in this process) showed a demonstration that is not a "
            "path of the game in trial first: not an integer array of shape (B, 5): shape "
            "(1, 2), dtype int64",
        ),
        (
            "expert",
            "not_finite",
            "robot 'not_finite' (registered in this process) returned a theta_hat that is not "
            "finite in trial second: [nan, ",
        ),
        (
            "expert",
            "one_short",
            "robot 'one_short' (registered in this process) returned theta_hat of shape (2, 2) "
            "and dtype float64, where (2, 3) values of kind 'fiu' were due, in trial first",
        ),
    ],
)
def test_a_player_breaking_its_contract_is_named_with_its_trial(
    faulty_players, human, robot, message
):
    specs = [
        msgspec.structs.replace(_spec(human, theta, trial_id=trial_id), robot=robot, eta=None)
        for trial_id, theta in (("first", (0.4, -0.7, 0.1)), ("second", (-0.2, 0.3, 0.9)))
    ]
    with pytest.raises(PlayerFault) as error:
        play_trials(specs)
    assert str(error.value).startswith(message)
    assert "\n" not in str(error.value)


def test_path_faults_accept_exactly_the_paths_of_a_phase():
    """Every sequence of cells of a small goal phase, against a brute-force walk: a sequence
    is accepted iff it starts at the start, makes available moves, and enters the goal in
    time (then the sink)."""
    successors = np.array([[1, 3, -1], [0, 2, -1], [1, 3, 2], [0, 2, -1]])
    phase = Phase(successors, start=0, horizon=3, goals=(2,))
    sink = 4
    for cells in itertools.product(range(5), repeat=4):
        path = np.array([cells])
        legal = cells[0] == 0 and all(
            nxt in phase.successors[cell] for cell, nxt in itertools.pairwise(cells)
        )
        finished = 2 in cells or sink in cells
        assert (phase.path_faults(path) == []) == (legal and finished), cells


def _estimate(**changed):
    fields = {
        "theta_hat": np.array([[0.5, -0.5], [1.0, -1.0]]),
        "log_likelihood": np.array([-1.0, -2.0]),
        "iterations": np.array([3, 0]),
        "converged": np.array([True, False]),
    }
    return Estimate(**{**fields, **changed})


@pytest.mark.parametrize(
    ("changed", "leaves_box", "fault"),
    [
        ({}, False, None),
        ({"theta_hat": np.array([[0.5, -0.5], [1.5, 0.0]])}, True, None),
        ({"theta_hat": np.array([[0.5, -0.5], [1.5, 0.0]])}, False, (1, "outside [-1, 1]^K")),
        ({"log_likelihood": np.array([-1.0, np.nan])}, False, (1, "log_likelihood that is not")),
        ({"log_likelihood": np.array([-1.0])}, False, (0, "log_likelihood of shape (1,)")),
        ({"iterations": np.array([-1, 0])}, False, (0, "iterations that is not a finite")),
        ({"iterations": np.array([1.0, 2.0])}, False, (0, "iterations of shape (2,) and dtype")),
        ({"converged": np.array([1, 0])}, False, (0, "converged of shape (2,) and dtype int")),
        ({"theta_hat_se": np.array([[0.1, 0.1], [0.1, -0.1]])}, False, (1, "theta_hat_se that")),
        ({"effective_sample_size": np.array([np.inf, 2.0])}, False, (0, "effective_sample_size")),
    ],
)
def test_every_field_of_an_estimate_is_held_to_what_its_record_can_hold(changed, leaves_box, fault):
    from cirl_study.core.trial import estimate_faults

    faults = estimate_faults(_estimate(**changed), (2, 2), leaves_box)
    if fault is None:
        assert faults == []
    else:
        (row, what, _), *_ = faults
        assert row == fault[0] and fault[1] in what, faults
