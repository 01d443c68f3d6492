"""The robots study: robot as a within-subjects factor, from the plan to the report.

The split-plot ANOVA is checked against two independent references: ``pingouin.mixed_anova``
(one within factor), and, with two-level within factors, the exact equivalence of each
within effect with a one-way ANOVA of that effect's per-subject contrast
(``scipy.stats.f_oneway`` for the interaction with the between factor; the intercept test of
the same one-way model for the within effect itself).
"""

from __future__ import annotations

import itertools
from pathlib import Path

import msgspec
import numpy as np
import pandas as pd
import pingouin as pg
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats
from test_logs_helpers import run_records

from cirl_study.analysis.report.study import write_report
from cirl_study.analysis.statistics.anova import repeated_measures_anova
from cirl_study.analysis.statistics.procedures import paired_differences
from cirl_study.analysis.table import check_design
from cirl_study.logs.reader import read_run, read_trials
from cirl_study.record import ETA_CV, MAIN, MAP, POSTERIOR_MEAN
from cirl_study.study.engines import LocalEngine
from cirl_study.study.pipeline_file import load_pipeline, logged_pipeline
from cirl_study.study.plan import eta_cv_trials, study_trials, trial_counts
from cirl_study.study.runner import run_pipeline

SMOKE = Path(__file__).resolve().parent.parent / "pipelines" / "smoke.toml"
ROBOTS_PIPELINE = Path(__file__).resolve().parent.parent / "pipelines" / "robots.toml"


def _plain_report(*args, **kwargs) -> dict:
    """What :func:`write_report` returns, as ``results.json`` stores it."""
    return msgspec.to_builtins(write_report(*args, **kwargs))


def split_plot_data(seed: int, subjects: int, levels: int = 2) -> pd.DataFrame:
    """Random scores of ``subjects`` per group, 2 groups, within factors robot and human."""
    rng = np.random.default_rng(seed)
    rows = []
    for group in range(levels):
        for s in range(subjects):
            person = rng.normal()
            for robot, human in itertools.product(("map", "pm"), ("expert", "best")):
                effect = 0.4 * (robot == "pm") * (group == 0) + 0.7 * (human == "best")
                rows.append(
                    {
                        "subject": f"g{group}-s{s:03d}",
                        "num_features": 3 + 7 * group,
                        "robot": robot,
                        "human": human,
                        "y": person + effect + rng.normal(),
                    }
                )
    return pd.DataFrame(rows)


def anova_frame(data: pd.DataFrame, within: list[str]) -> pd.DataFrame:
    rows = repeated_measures_anova(data, "y", within, ["num_features"])
    return pd.DataFrame([msgspec.to_builtins(row) for row in rows]).set_index("effect")


def test_one_within_factor_matches_pingouin() -> None:
    data = split_plot_data(1, 9)
    one = data.groupby(["subject", "num_features", "human"], as_index=False)["y"].mean()
    ours = anova_frame(one, ["human"])
    arguments = dict(data=one, dv="y", within="human", between="num_features", subject="subject")
    partial = pg.mixed_anova(**arguments, effsize="np2").set_index("Source")
    general = pg.mixed_anova(**arguments, effsize="ng2").set_index("Source")
    names = {
        "num_features": "num_features",
        "human": "human",
        "human:num_features": "Interaction",
    }
    for effect, source in names.items():
        assert ours.at[effect, "SS"] == pytest.approx(partial.at[source, "SS"], rel=1e-12)
        assert ours.at[effect, "df1"] == partial.at[source, "DF1"]
        assert ours.at[effect, "df2"] == partial.at[source, "DF2"]
        assert ours.at[effect, "F"] == pytest.approx(partial.at[source, "F"], rel=1e-12)
        assert ours.at[effect, "p"] == pytest.approx(partial.at[source, "p_unc"], rel=1e-9)
        assert ours.at[effect, "np2"] == pytest.approx(partial.at[source, "np2"], rel=1e-12)
        assert ours.at[effect, "ges"] == pytest.approx(general.at[source, "ng2"], rel=1e-12)


def contrast_f(data: pd.DataFrame, weights: dict[tuple[str, str], float]) -> tuple[float, float]:
    """F of a within contrast's mean (pooled within-group error) and of its group effect."""
    wide = data.pivot_table(
        index=["num_features", "subject"], columns=["robot", "human"], values="y"
    )
    contrast = sum(weight * wide[cell] for cell, weight in weights.items())
    groups = [values.to_numpy() for _, values in contrast.groupby(level="num_features")]
    within = sum(((g - g.mean()) ** 2).sum() for g in groups) / (len(contrast) - len(groups))
    intercept = len(contrast) * contrast.mean() ** 2 / within
    return float(intercept), float(stats.f_oneway(*groups).statistic)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), subjects=st.integers(3, 12))
def test_two_within_factors_match_the_contrast_tests(seed: int, subjects: int) -> None:
    data = split_plot_data(seed, subjects)
    ours = anova_frame(data, ["robot", "human"])
    robot = {("pm", "expert"): 1, ("pm", "best"): 1, ("map", "expert"): -1, ("map", "best"): -1}
    human = {("pm", "best"): 1, ("map", "best"): 1, ("pm", "expert"): -1, ("map", "expert"): -1}
    both = {("pm", "best"): 1, ("map", "expert"): 1, ("pm", "expert"): -1, ("map", "best"): -1}
    for name, weights in (("robot", robot), ("human", human), ("robot:human", both)):
        main_f, group_f = contrast_f(data, weights)
        assert ours.at[name, "F"] == pytest.approx(main_f, rel=1e-9)
        assert ours.at[f"{name}:num_features", "F"] == pytest.approx(group_f, rel=1e-9)
    # The effects and the four error terms (one per within subset) partition the total SS.
    error_ss = sum(
        ours.at[e, "MS"] / ours.at[e, "F"] * ours.at[e, "df2"]
        for e in ("num_features", "robot", "human", "robot:human")
    )
    total = ((data["y"] - data["y"].mean()) ** 2).sum()
    assert ours["SS"].sum() + error_ss == pytest.approx(total, rel=1e-9)


def test_the_anova_refuses_an_incomplete_subject() -> None:
    data = split_plot_data(3, 5)
    with pytest.raises(ValueError, match="exactly one observation in every within cell"):
        repeated_measures_anova(data.iloc[1:], "y", ["robot", "human"], ["num_features"])


def test_paired_differences_are_paired_t_tests_with_holm() -> None:
    data = split_plot_data(4, 10)
    rows = paired_differences(data, "y", "robot", "map", ["num_features", "human"]).to_frame()
    assert len(rows) == 4 and set(rows["level"]) == {"pm"}
    raw = []
    for row in rows.itertuples():
        cell = data[(data["num_features"] == row.num_features) & (data["human"] == row.human)]
        wide = cell.pivot(index="subject", columns="robot", values="y")
        test = stats.ttest_rel(wide["pm"], wide["map"])
        assert row.t == pytest.approx(test.statistic, rel=1e-12)
        assert row.mean_diff == pytest.approx((wide["pm"] - wide["map"]).mean(), rel=1e-12)
        raw.append(test.pvalue)
    order = np.argsort(raw)
    adjusted = np.maximum.accumulate([min(1, (4 - i) * raw[j]) for i, j in enumerate(order)])
    np.testing.assert_allclose(rows["p_holm"].to_numpy()[order], adjusted, rtol=1e-12)


def robots_smoke(tmp_path: Path, robots: str) -> Path:
    path = tmp_path / f"smoke-{len(robots)}.toml"
    path.write_text(SMOKE.read_text().replace('robots = ["map"]', f"robots = {robots}"))
    return path


def test_the_plan_puts_every_robot_on_the_same_demonstrations(tmp_path: Path) -> None:
    pipeline = load_pipeline(robots_smoke(tmp_path, '["posterior_mean", "map"]'))
    assert pipeline.main.reference_robot == MAP
    assert {t.robot for t in eta_cv_trials(pipeline)} == {MAP}
    study = study_trials(
        pipeline, {(None, "best_response", 3): 1.0, (None, "best_response", 10): 1.0}
    )
    cells: dict[tuple, set[str]] = {}
    for t in study:
        cells.setdefault((t.block, t.subject, t.human, t.rationality, t.eta), set()).add(t.robot)
    assert set(map(frozenset, cells.values())) == {frozenset({MAP, POSTERIOR_MEAN})}
    counts = trial_counts(pipeline)
    assert counts == {"eta_cv": 18, "main": 32, "lambda_sweep": 96}
    assert sum(t.block == MAIN for t in study) == counts[MAIN]


def test_the_shipped_robots_pipeline_compares_both_robots() -> None:
    pipeline = load_pipeline(ROBOTS_PIPELINE)
    assert pipeline.main.robots == (MAP, POSTERIOR_MEAN)
    assert sum(trial_counts(pipeline).values()) == 9800


@pytest.fixture(scope="module")
def two_robot_runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    base = tmp_path_factory.mktemp("robots")
    one, two = base / "one", base / "two"
    run_pipeline(load_pipeline(robots_smoke(base, '["map"]')), one, LocalEngine(2))
    run_pipeline(
        load_pipeline(robots_smoke(base, '["map", "posterior_mean"]')), two, LocalEngine(2)
    )
    return one, two


def test_the_map_trials_of_a_two_robot_run_are_those_of_the_map_run(
    two_robot_runs: tuple[Path, Path],
) -> None:
    one, two = (run_records(run) for run in two_robot_runs)
    assert {r.robot for r in two if r.block == ETA_CV} == {MAP}

    def key(record):
        return (record.block, record.subject, record.human, record.rationality, record.eta)

    alone = {key(r): r for r in one}
    beside = {key(r): r for r in two if r.robot == MAP}
    assert alone.keys() == beside.keys()
    for k, record in alone.items():
        assert beside[k].theta_hat == record.theta_hat
        assert beside[k].measures == record.measures
        assert beside[k].demonstration == record.demonstration


def test_the_report_compares_the_robots_and_keeps_the_paper_analysis(
    two_robot_runs: tuple[Path, Path], tmp_path: Path
) -> None:
    reports = []
    for run, name in zip(two_robot_runs, ("one", "two"), strict=True):
        contents = read_run(run, logged_pipeline)
        reports.append(
            _plain_report(
                contents.rows,
                tmp_path / name,
                logged_pipeline(contents.identity),
                records_of=lambda wanted, run=run, contents=contents: read_trials(
                    run, contents.identity, logged_pipeline, wanted
                ),
            )
        )
    alone, both = reports
    two = read_run(two_robot_runs[1], logged_pipeline).rows
    assert alone["robots"] is None and not (tmp_path / "one" / "robots_lambda.png").exists()
    assert both["paper"] == alone["paper"]  # the paper's analysis: the reference robot's trials
    assert alone["anova"] == alone["paper"]["anova"]
    with_map = [row for row in both["cells"] if row["robot"] == MAP]
    assert with_map == alone["cells"]
    robots = both["robots"]
    assert (robots["reference"], robots["others"]) == (MAP, [POSTERIOR_MEAN])
    assert {row["effect"] for row in both["anova"]} == {
        "num_features", "human", "human:num_features", "robot", "robot:num_features",
        "human:robot", "human:robot:num_features",
    }  # fmt: skip
    regret = [r for r in robots["main"] if r["measure"] == "regret"]
    by_cell = {(r.subject, r.human, r.robot): r.measure("regret") for r in two if r.block == MAIN}
    for row in regret:
        differences = [
            by_cell[s, row["human"], POSTERIOR_MEAN] - by_cell[s, row["human"], MAP]
            for (s, human, robot) in by_cell
            if robot == MAP and human == row["human"] and f"-k{row['num_features']:02d}-" in s
        ]
        assert row["mean_diff"] == pytest.approx(np.mean(differences), rel=1e-12)
    text = (tmp_path / "two" / "report.md").read_text()
    assert "## Robots" in text and "### Repeated-measures ANOVA" in text
    assert (tmp_path / "two" / "robots_lambda.png").exists()
    assert (tmp_path / "two" / "cell_means.png").exists()
    assert not (tmp_path / "one" / "cell_means.png").exists()


def test_three_robots_are_compared_with_the_reference(two_robot_runs: tuple[Path, Path]) -> None:
    records = read_run(two_robot_runs[1], logged_pipeline).rows
    third = [
        msgspec.structs.replace(r, robot="third", trial_id=r.trial_id + "3")
        for r in records
        if r.block == MAIN and r.robot == MAP
    ]
    check_design([*records, *third])
