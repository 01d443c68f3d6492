"""Feature order agreement (cirl_study.core.order_agreement): closed-form cases, ties, where it
is undefined, its properties against a brute-force count, and its value in played records."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_logs_helpers import run_records

from cirl_study.core.order_agreement import agreement
from cirl_study.measure_registry import MEASURES, analysed_measures


def one(theta: list[float], theta_hat: list[float]) -> float | None:
    """The agreement of a single pair of weight vectors."""
    return agreement([theta], [theta_hat])[0]


def brute_force(theta: list[float], theta_hat: list[float]) -> Fraction | None:
    """The definition, pair by pair, in exact fractions."""
    pairs = [
        (i, j) for i in range(len(theta)) for j in range(i + 1, len(theta)) if theta[i] != theta[j]
    ]
    if not pairs:
        return None
    score = Fraction(0)
    for i, j in pairs:
        if theta_hat[i] == theta_hat[j]:
            score += Fraction(1, 2)
        elif (theta[i] < theta[j]) == (theta_hat[i] < theta_hat[j]):
            score += 1
    return score / len(pairs)


@pytest.mark.parametrize(
    ("theta", "theta_hat", "expected"),
    [
        ([0.1, 0.5, -0.3], [0.2, 0.1, 0.0], 2 / 3),  # one pair of three reversed
        ([0.1, 0.5, -0.3], [0.1, 0.5, -0.3], 1.0),  # the truth itself
        ([0.1, 0.5, -0.3], [-0.1, -0.5, 0.3], 0.0),  # every pair reversed
        ([0.1, 0.5, -0.3], [5.0, 7.0, -2.0], 1.0),  # another scale, the same order
        ([1.0, 0.0], [0.5, 0.5], 0.5),  # the estimate ties the one pair: a half
        ([0.2, 0.2, 0.7], [0.9, 0.1, 0.1], 0.25),  # theta's tie is no pair; one half, one wrong
        ([0.3, -0.3, 0.0, 0.9], [1.0, 1.0, 1.0, 1.0], 0.5),  # a constant estimate: all ties
        ([0.4, 0.4, -0.2, -0.2], [0.0, 1.0, -1.0, 0.5], 0.75),  # 4 pairs: 3 right, 1 wrong
    ],
)
def test_closed_form_cases(theta: list[float], theta_hat: list[float], expected: float) -> None:
    assert one(theta, theta_hat) == expected


@pytest.mark.parametrize("theta", [[0.5], [-1.0], [0.3, 0.3], [0.0, 0.0, 0.0]])
def test_it_is_undefined_where_theta_has_no_two_different_weights(theta: list[float]) -> None:
    assert one(theta, [0.1 * i for i in range(len(theta))]) is None


def test_a_batch_is_measured_row_by_row() -> None:
    theta = [[0.1, 0.5, -0.3], [0.3, 0.3, 0.3], [1.0, 0.0, 0.5]]
    theta_hat = [[0.2, 0.1, 0.0], [0.1, 0.2, 0.3], [1.0, 0.0, 0.5]]
    assert agreement(theta, theta_hat) == [2 / 3, None, 1.0]


WEIGHTS = st.one_of(
    st.sampled_from([-1.0, -0.5, 0.0, 0.25, 1.0]),  # ties are likely
    st.floats(-1.0, 1.0, allow_nan=False),
)
ESTIMATES = st.one_of(
    st.sampled_from([-1.0, 0.0, 1.0]),  # the box's bounds, where a MAP estimate often ties
    st.floats(-30.0, 30.0, allow_nan=False),  # gradient ascent's may leave the box
)


@st.composite
def weights_and_estimates(draw: st.DrawFn) -> tuple[list[float], list[float]]:
    k = draw(st.integers(1, 8))
    theta = draw(st.lists(WEIGHTS, min_size=k, max_size=k))
    return theta, draw(st.lists(ESTIMATES, min_size=k, max_size=k))


@st.composite
def increasing_transform(draw: st.DrawFn, values: list[float]) -> list[float]:
    """``values`` mapped by a strictly increasing function: each distinct value to one of
    as many new distinct values, in the same order (ties stay ties)."""
    distinct = sorted(set(values))
    images = draw(
        st.lists(
            st.floats(-1e9, 1e9, allow_nan=False),
            min_size=len(distinct),
            max_size=len(distinct),
            unique=True,
        )
    )
    new = dict(zip(distinct, sorted(images), strict=True))
    return [new[value] for value in values]


@settings(max_examples=300, deadline=None)
@given(data=st.data(), drawn=weights_and_estimates())
def test_it_is_a_fraction_of_pairs_blind_to_any_increasing_transform_of_the_estimate(
    data: st.DataObject, drawn: tuple[list[float], list[float]]
) -> None:
    theta, theta_hat = drawn
    value = one(theta, theta_hat)
    expected = brute_force(theta, theta_hat)
    if expected is None:
        assert value is None and len(set(theta)) == 1
        return
    assert value == float(expected)  # exactly: an integer count of halves over 2 |P|
    assert 0.0 <= value <= 1.0
    assert one(theta, theta) == 1.0
    assert one(theta, data.draw(increasing_transform(theta_hat))) == value
    assert one(theta, [-v for v in theta_hat]) == pytest.approx(1.0 - value, abs=1e-15)


def test_it_is_registered_as_a_score_the_analysis_tests() -> None:
    measure = MEASURES["order_agreement"]
    assert not measure.lower_is_better and (measure.minimum, measure.maximum) == (0.0, 1.0)
    assert measure.unit == "fraction" and measure.label == "feature order agreement"
    assert "order_agreement" in analysed_measures()


def test_every_played_record_logs_it(smoke_run: Path) -> None:
    records = run_records(smoke_run)
    assert records
    for record in records:
        expected = one(list(record.theta), list(record.theta_hat))
        assert expected is not None  # K = 3 and 10: theta has two different weights
        assert record.measures["order_agreement"] == expected


def test_a_run_with_one_feature_leaves_that_level_out_of_its_statistics(tmp_path: Path) -> None:
    """At K = 1 theta has no pair of weights: the records log null, and the analysis tests
    the agreement on the K = 3 draws alone, saying so, while the paper's three measures keep
    both levels."""
    import cirl_study

    smoke = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"
    pipeline = tmp_path / "one-feature.toml"
    pipeline.write_text(
        smoke.read_text()
        .replace("feature_levels = [3, 10]", "feature_levels = [1, 3]")
        .replace('name = "smoke"', 'name = "one-feature"')
    )
    run = cirl_study.run(pipeline, tmp_path / "run")
    records = run_records(run)
    assert {r.measures["order_agreement"] is None for r in records if r.num_features == 1} == {True}
    assert all(r.measures["order_agreement"] is not None for r in records if r.num_features == 3)
    results = cirl_study.analyze(run)
    (undefined,) = results.undefined
    at_one = [r for r in records if r.num_features == 1]
    assert (undefined.measure, undefined.trials) == ("order_agreement", len(at_one))
    assert undefined.subjects == len({r.subject for r in at_one})
    for name in ("regret", "order_agreement"):
        levels = {row.num_features for row in results.cells if row.measure == name}
        effects = {row.effect for row in results.anova if row.measure == name}
        assert levels == ({3} if name == "order_agreement" else {1, 3})
        assert ("num_features" in effects) == (name == "regret")
