"""One whole trial (DESIGN sections 1-4 and 7), re-derived from its record by brute force."""

import json

import brute_force as bf
import numpy as np
import pytest

from cirl_study.trial import GameSetting, TrialSpec, play_trials

SETTING = GameSetting(
    width=4,
    height=4,
    start=(1, 2),
    learning_steps=4,
    deployment_steps=3,
    centers=((0.5, 2.0), (3.0, 1.0), (2.0, 3.5)),
    sigma=1.5,
)

TOP_LEVEL = {
    "trial_id",
    "run_id",
    "block",
    "subject",
    "policy",
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
    "theta_hat",
    "demonstration",
    "measures",
    "irl",
    "deployment",
}


def _spec(policy, theta, *, eta=0.5, rationality=1.0, trial_id=None, setting=SETTING):
    return TrialSpec(
        trial_id=trial_id or f"t-{policy}-{theta[0]:.3f}-{rationality:g}",
        run_id="run-test",
        block="main",
        subject="s-1",
        policy=policy,
        num_features=len(theta),
        rationality=rationality,
        eta=eta if policy == "best_response" else None,
        seed=7,
        theta=tuple(float(v) for v in theta),
        setting=setting,
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
    width, height = record["grid"]["width"], record["grid"]["height"]
    feats = record["features"]
    assert feats["kind"] == "rbf"
    features = bf.rbf_features(width, height, feats["centers"], feats["sigma"])
    start = bf.cell(width, *record["start"])
    return width, height, features, start


def test_record_has_every_field_of_the_contract_and_is_plain_json(played):
    specs, records = played
    assert len(records) == len(specs)
    for spec, record in zip(specs, records, strict=True):
        assert set(record) >= TOP_LEVEL
        assert json.loads(json.dumps(record, allow_nan=False)) == record
        assert record["trial_id"] == spec.trial_id and record["policy"] == spec.policy
        assert record["run_id"] == spec.run_id and record["subject"] == spec.subject
        assert record["block"] == spec.block and record["seed"] == spec.seed
        assert record["num_features"] == 3 == len(record["theta"]) == len(record["theta_hat"])
        assert record["rationality"] == spec.rationality
        assert record["eta"] == (spec.eta if spec.policy == "best_response" else None)
        assert record["grid"] == {"width": 4, "height": 4}
        assert record["start"] == [1, 2]
        assert (record["learning_steps"], record["deployment_steps"]) == (4, 3)
        assert record["features"]["centers"] == [list(c) for c in SETTING.centers]
        assert record["features"]["sigma"] == SETTING.sigma
        assert record["theta"] == list(spec.theta)
        assert set(record["measures"]) >= {"regret", "kl", "reward_l2"}
        assert set(record["irl"]) >= {"log_likelihood", "iterations", "converged"}
        assert set(record["deployment"]) >= {"starts", "paths"}


def test_demonstration_is_the_policy_s_optimal_path(played):
    _, records = played
    for record in records:
        width, height, features, start = _context(record)
        horizon = record["learning_steps"]
        demo = record["demonstration"]
        states = [bf.cell(width, x, y) for x, y in demo["states"]]
        assert bf.is_path(width, height, states, start, horizon)
        assert len(demo["actions"]) == horizon
        for here, there, name in zip(states[:-1], states[1:], demo["actions"], strict=True):
            assert bf.move(width, height, here, name) == there
        counts = bf.feature_counts(bf.enumerate_paths(width, height, start, horizon), features)
        got = bf.feature_counts([states], features)
        theta = np.array(record["theta"])
        if record["policy"] == "expert":
            _, best = bf.expert(counts, theta)
            assert got[0] @ theta == pytest.approx(best, rel=1e-12, abs=1e-12)
        else:
            eta, rationality = record["eta"], record["rationality"]
            _, best = bf.best_response(counts, theta, eta, rationality)
            phi_theta = bf.expected_features(counts, theta, rationality)
            value = bf.best_response_objective(got, theta, eta, phi_theta)[0]
            assert value == pytest.approx(best, abs=1e-9 * max(1.0, abs(best)))


def test_theta_hat_is_the_box_map_of_the_demonstration(played):
    _, records = played
    for record in records:
        width, height, features, start = _context(record)
        horizon, rationality = record["learning_steps"], record["rationality"]
        counts = bf.feature_counts(bf.enumerate_paths(width, height, start, horizon), features)
        states = [bf.cell(width, x, y) for x, y in record["demonstration"]["states"]]
        demo = bf.feature_counts([states], features)[0]
        theta_hat = np.array(record["theta_hat"])
        assert np.all(np.abs(theta_hat) <= 1.0)
        slope = demo - bf.expected_features(counts, theta_hat, rationality)
        outward = ((theta_hat >= 1.0) & (slope > 0)) | ((theta_hat <= -1.0) & (slope < 0))
        assert np.abs(np.where(outward, 0.0, slope)).max() <= 1e-6
        assert record["irl"]["converged"] is True
        ll = bf.log_likelihood(demo, counts, theta_hat, rationality)
        assert record["irl"]["log_likelihood"] == pytest.approx(ll, rel=1e-10, abs=1e-10)


def test_measures_equal_the_brute_force_measures_of_the_record(played):
    _, records = played
    for record in records:
        width, height, features, _ = _context(record)
        theta, theta_hat = record["theta"], record["theta_hat"]
        horizon, rationality = record["deployment_steps"], record["rationality"]
        measures = record["measures"]
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
        horizon = record["deployment_steps"]
        best = bf.optimal_values(width, height, features, record["theta_hat"], horizon)
        deployment = record["deployment"]
        assert len(deployment["starts"]) == len(deployment["paths"]) >= 1
        for start_xy, path in zip(deployment["starts"], deployment["paths"], strict=True):
            start = bf.cell(width, *start_xy)
            states = [bf.cell(width, x, y) for x, y in path]
            assert bf.is_path(width, height, states, start, horizon)
            value = bf.feature_counts([states], features)[0] @ np.array(record["theta_hat"])
            assert value == pytest.approx(best[start], abs=1e-12)


def test_a_record_depends_only_on_its_spec(played):
    specs, records = played
    # alone, in another order, and in a batch with other grids and horizons
    other = GameSetting(
        width=3,
        height=5,
        start=(1, 1),
        learning_steps=3,
        deployment_steps=2,
        centers=((0.0, 0.0), (2.0, 4.0)),
        sigma=1.0,
    )
    stranger = _spec("best_response", (0.2, -0.9), eta=2.0, trial_id="stranger", setting=other)
    assert play_trials([specs[3]]) == [records[3]]
    shuffled = play_trials([specs[5], stranger, specs[1], specs[3]])
    assert shuffled[0] == records[5]
    assert shuffled[2] == records[1]
    assert shuffled[3] == records[3]
    assert shuffled[1]["trial_id"] == "stranger" and shuffled[1]["grid"]["height"] == 5


def test_the_true_reward_is_not_recovered_by_a_broken_demonstration(played):
    # A check that can fail: the measures of the record disagree with those of a wrong theta_hat.
    _, records = played
    record = records[1]
    width, height, features, _ = _context(record)
    wrong = [-v for v in record["theta_hat"]]
    assert record["measures"]["reward_l2"] != pytest.approx(
        bf.reward_l2(features, record["theta"], wrong), rel=1e-6
    )
