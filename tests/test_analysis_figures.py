"""The figures (cirl_study.analysis.report.figures): reward maps and deterministic PNG bytes."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import msgspec
import numpy as np
import pandas as pd
import pytest
from analysis_fixtures import synthetic_records
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from cirl_study.analysis.report import figures
from cirl_study.analysis.results.study import FIGURE1_DIFFERENCE, figure1_subject
from cirl_study.core.gridworld import feature_matrix
from cirl_study.record import TrialRecord, from_builtins, to_builtins

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def pair() -> tuple[TrialRecord, TrialRecord]:
    records = synthetic_records(subjects_per_level=1, lambdas=(), etas=(), cv_subjects=0)
    main = [r for r in records if r.block == "main" and r.num_features == 3]
    return main[0], main[1]


def test_reward_map_is_theta_dot_rbf_features_with_row_y_and_column_x(pair):
    record = pair[0]
    scene = figures.RewardScene.from_record(record)
    rewards = scene.reward_map(scene.theta)
    width, height = record.grid.width, record.grid.height
    assert rewards.shape == (height, width)
    sigma = record.features.sigma
    for x, y in [(0, 0), (width - 1, 0), (2, height - 1)]:
        expected = sum(
            weight * math.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * sigma**2))
            for weight, (cx, cy) in zip(record.theta, record.features.centers, strict=True)
        )
        assert rewards[y, x] == pytest.approx(expected)


def test_the_scene_is_the_records_own_data(pair):
    record = pair[1]
    scene = figures.RewardScene.from_record(record)
    np.testing.assert_array_equal(scene.features, feature_matrix(record))
    np.testing.assert_array_equal(scene.theta_hat, record.theta_hat)
    np.testing.assert_array_equal(scene.states, record.demonstration.states)
    np.testing.assert_array_equal(scene.centers, record.features.centers)


@pytest.fixture(scope="module")
def png(pair) -> bytes:
    return figures.reward_maps(*pair, "draw").png


def test_png_bytes_carry_no_software_or_time_metadata(png):
    assert png.startswith(PNG_SIGNATURE)
    assert b"Software" not in png and b"tIME" not in png


_RENDER = """
import sys
sys.path.insert(0, {tests!r})
from analysis_fixtures import synthetic_records
from cirl_study.analysis.report import figures
records = synthetic_records(subjects_per_level=1, lambdas=(), etas=(), cv_subjects=0)
main = [r for r in records if r.block == "main" and r.num_features == 3]
sys.stdout.buffer.write(figures.reward_maps(main[0], main[1], "draw").png)
"""


def test_png_bytes_are_the_same_in_a_fresh_process_with_another_hash_seed(png):
    script = _RENDER.format(tests=str(Path(__file__).parent))
    environment = {**os.environ, "PYTHONHASHSEED": "12345", "MPLBACKEND": "pdf"}
    fresh = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, check=True, env=environment
    ).stdout
    assert fresh == png


def test_a_record_without_a_drawable_reward_map_is_refused_before_it_becomes_a_record(pair):
    broken = to_builtins(pair[0])
    del broken["features"]["sigma"]
    with pytest.raises(msgspec.ValidationError, match="missing required field `sigma`"):
        from_builtins(broken)


def _identical_sweep() -> pd.DataFrame:
    """Both humans with the very same regret at every lambda: the case that hid one line."""
    rows = [
        {"measure": "regret", "rationality": lam, "human": human, "num_features": k,
         "mean": 1.0 + k / 10, "ci95_low": 0.9, "ci95_high": 1.1 + k / 10}
        for k in (3, 10) for lam in (1e-2, 1.0, 1e2) for human in ("expert", "best_response")
    ]  # fmt: skip
    return pd.DataFrame(rows)


def test_both_humans_are_visible_at_every_lambda_even_where_they_coincide():
    figure = figures.lambda_figure(_identical_sweep())
    panels = [axes for axes in figure.axes if axes.get_title()]
    assert [axes.get_title() for axes in panels] == ["3 features", "10 features"]
    for axes in panels:
        bars = {container.get_label(): container.lines[0] for container in axes.containers}
        lines = {line.get_label(): line for line in axes.get_lines()}
        expert, best = bars["expert"], bars["best response"]
        assert len(expert.get_xdata()) == len(best.get_xdata()) == 3
        # Distinct markers and colours, and never drawn on top of each other.
        assert expert.get_marker() != best.get_marker()
        assert expert.get_color() != best.get_color()
        assert all(a < b for a, b in zip(expert.get_xdata(), best.get_xdata(), strict=True))
        assert "lowest best-response regret" in lines
    assert figure.legends


def test_every_figure_also_renders_as_svg_deterministically():
    first = figures.lambda_curve(_identical_sweep())
    second = figures.lambda_curve(_identical_sweep())
    assert first.svg.startswith(b"<?xml") and b"<svg" in first.svg
    assert first.svg == second.svg and first.png == second.png


def test_figure1_draws_every_step_and_names_each_regret(pair):
    expert, best = pair
    stays = msgspec.structs.replace(
        expert,
        demonstration=msgspec.structs.replace(
            expert.demonstration,
            states=(expert.start,) * 3,
            actions=("stay", "stay"),
        ),
        learning_steps=2,
    )
    figure = figures.reward_figure(stays, best, "draw")
    true_map, stayed, moved = figure.axes[:3]
    assert stayed.get_title().startswith(f"expert: regret {stays.measures['regret']:.3g}")
    assert moved.get_title().startswith(f"best response: regret {best.measures['regret']:.3g}")
    assert all(axes.get_xlabel() == "x (cell)" for axes in (true_map, stayed, moved))
    # Two stays on the start cell: one ring; the step label covers both.
    rings = [line for line in stayed.get_lines() if line.get_markerfacecolor() == "none"]
    assert [ring.get_markersize() for ring in rings] == [figures.RING_SIZE]
    assert "0-2" in [text.get_text() for text in stayed.texts]
    # Every move of the best response is an arrow.
    arrows = [text for text in moved.texts if text.arrow_patch is not None]
    assert len(arrows) == sum(a != "stay" for a in best.demonstration.actions)
    assert figures._step_label([0, 2, 3, 5]) == "0,2-3,5"


def _star(axes) -> Line2D:
    (star,) = [line for line in axes.get_lines() if line.get_marker() == "*"]
    return star


def _sits_on(star: Line2D, axes, point: tuple[float, float]) -> bool:
    """The star is drawn at ``point`` in data coordinates, hence on the point's pixel."""
    drawn = star.get_transform().transform(star.get_xydata()[0])
    return tuple(star.get_xydata()[0]) == point and np.allclose(
        drawn, axes.transData.transform(point)
    )


def test_every_lambda_panel_labels_its_regret_and_the_star_sits_on_its_point():
    """The star marks the best response's lowest mean regret on that very point, beneath every
    marker and line, so it neither floats away from its point nor hides another."""
    sweep = _identical_sweep()
    at_one = (sweep["human"] == "best_response") & (sweep["rationality"] == 1.0)
    sweep.loc[at_one, ["mean", "ci95_low", "ci95_high"]] -= 0.5
    figure = figures.lambda_figure(sweep)
    FigureCanvasAgg(figure).draw()
    for axes in [axes for axes in figure.axes if axes.get_title()]:
        assert axes.get_ylabel() == "mean regret (95% CI)"
        bars = {container.get_label(): container for container in axes.containers}
        points = bars["best response"].lines[0].get_xydata()
        lowest = tuple(points[np.argmin(points[:, 1])])
        assert lowest[0] == pytest.approx(1.0 * figures.DODGE["best_response"])
        star = _star(axes)
        assert _sits_on(star, axes, lowest)
        assert star.get_zorder() < min(
            line.get_zorder() for line in axes.get_lines() if line is not star
        )


def test_the_eta_star_sits_on_the_chosen_etas_point(monkeypatch):
    """The smoke run's 10-feature panel drew its star at 1.33 for a point at 0.32."""
    means = pd.DataFrame(
        [
            {"num_features": k, "eta": eta, "mean": mean, "ci95_low": mean - 0.9,
             "ci95_high": mean + 0.9}
            for k in (3, 10) for eta, mean in ((0.1, 0.32), (1.0, 0.38), (10.0, 0.67))
        ]
    )  # fmt: skip
    choice = pd.DataFrame(
        [{"num_features": k, "eta": 0.1, "mean": 0.32, "se": 0.2} for k in (3, 10)]
    )
    captured = []
    render = figures.render
    monkeypatch.setattr(figures, "render", lambda figure: captured.append(figure) or render(figure))
    assert figures.eta_curve(means, choice).png.startswith(PNG_SIGNATURE)
    (figure,) = captured
    for axes in [axes for axes in figure.axes if axes.get_title()]:
        assert _sits_on(_star(axes), axes, (0.1, 0.32))


def _sweep_of(humans: list[str], robots: list[str]) -> pd.DataFrame:
    rows = [
        {"measure": measure, "rationality": lam, "human": human, "robot": robot,
         "num_features": k, "mean": 1.0 + i / 10 + j / 20 + lam / 1000, "ci95_low": 0.5,
         "ci95_high": 2.0}
        for measure in ("regret", "kl") for k in (3, 10) for lam in (0.1, 1.0, 10.0)
        for i, human in enumerate(humans) for j, robot in enumerate(robots)
    ]  # fmt: skip
    return pd.DataFrame(rows)


HUMANS5 = ["expert", "best_response", "literal", "pedagogic", "regret_optimal"]


def test_the_lambda_figure_draws_one_line_per_human_and_robot_in_every_panel():
    """Every human of the sweep with every robot, not only the expert and the best response
    of the reference robot: a panel per robot and feature level, a line per human in it."""
    robots = ["map", "posterior_mean"]
    figure = figures.lambda_figure(_sweep_of(HUMANS5, robots), HUMANS5, robots)
    panels = [axes for axes in figure.axes if axes.get_title()]
    titles = [f"robot {robot}, {k} features" for robot in robots for k in (3, 10)]
    assert [axes.get_title() for axes in panels] == titles
    drawn = set()
    for axes in panels:
        robot, level = axes.get_title().removeprefix("robot ").split(", ")
        labels = [container.get_label() for container in axes.containers]
        assert labels == [figures.human_label(human) for human in HUMANS5]
        for container in axes.containers:
            assert len(container.lines[0].get_xdata()) == 3  # every lambda
            drawn.add((container.get_label(), robot, level))
        styles = {
            (container.lines[0].get_color(), container.lines[0].get_marker())
            for container in axes.containers
        }
        assert len({colour for colour, _ in styles}) == len({m for _, m in styles}) == 5
    assert len(drawn) == 5 * 2 * 2


@pytest.mark.parametrize(("humans", "robots"), [(2, 1), (8, 4)])
def test_the_lambda_figures_legend_names_every_human_outside_the_panels(humans, robots):
    names = [*HUMANS5, "human_six", "human_seven", "human_eight"][:humans]
    robot_names = ["map", "posterior_mean", "gradient_ascent", "pragmatic"][:robots]
    figure = figures.lambda_figure(_sweep_of(names, robot_names), names, robot_names)
    renderer = FigureCanvasAgg(figure).get_renderer()
    (legend,) = figure.legends
    labels = [text.get_text() for text in legend.get_texts()]
    assert labels == [*(figures.human_label(h) for h in names), figures.LOWEST_REGRET]
    box = legend.get_window_extent(renderer)
    panels = [axes for axes in figure.axes if axes.get_title()]
    assert len(panels) == 2 * robots
    assert box.x0 >= max(axes.get_window_extent(renderer).x1 for axes in panels)
    assert box.x1 <= figure.bbox.x1
    # Colour-blind-safe and distinct: no two humans share a colour or a marker.
    styles = figures.human_styles(names)
    assert len({style["color"] for style in styles.values()}) == humans
    assert len({style["marker"] for style in styles.values()}) == humans


def test_figure1_explains_its_step_labels_and_shading(pair):
    figure = figures.reward_figure(*pair, "draw")
    (key,) = [text.get_text() for text in figure.texts if "steps" in text.get_text()]
    assert "3-4: steps 3 to 4" in key and "2,5: steps 2 and 5" in key and "light" in key


@pytest.mark.parametrize("humans", [5, 8])
def test_the_cell_figure_labels_its_axes_and_its_human_names_do_not_collide(humans):
    names = [f"human_number_{i}" for i in range(humans)]
    robots = ["map", "literal_observer", "pragmatic"]
    cells = pd.DataFrame(
        [
            {"measure": m, "num_features": k, "human": h, "robot": r, "mean": 1.0,
             "ci95_low": 0.5, "ci95_high": 1.5}
            for m in ("regret", "kl", "reward_l2") for k in (3, 10) for h in names for r in robots
        ]
    )  # fmt: skip
    figure = figures.cell_figure(cells, names, robots)
    renderer = FigureCanvasAgg(figure).get_renderer()
    panels = [axes for axes in figure.axes if axes.get_title()]
    assert all(axes.get_ylabel().startswith("mean ") for axes in panels)
    assert any(axes.get_xlabel() == "human" for axes in panels)
    for axes in panels:
        boxes = [label.get_window_extent(renderer) for label in axes.get_xticklabels()]
        assert all(a.x1 <= b.x0 for a, b in zip(boxes, boxes[1:], strict=False)), axes.get_title()


def _paper_main(regrets: dict[str, tuple[float, float]]) -> pd.DataFrame:
    """Main-block rows of the paper's humans: subject -> (expert's, best response's) regret,
    at 3 features, and a subject at 10 features that never counts."""
    rows = [
        {"subject": subject, "num_features": 3, "human": human, "regret": regret}
        for subject, pair in regrets.items()
        for human, regret in zip(("expert", "best_response"), pair, strict=True)
    ]
    rows += [
        {"subject": "k10", "num_features": 10, "human": human, "regret": 1.0 + i}
        for i, human in enumerate(("expert", "best_response"))
    ]
    return pd.DataFrame(rows)


def test_figure1_shows_a_draw_whose_two_regrets_differ():
    """The median improvement of all subjects is a draw with two equal regrets (s2, improvement
    0); Figure 1 takes the median of the draws whose regrets differ by more than 5%."""
    paper_main = _paper_main(
        {
            "s1": (0.5, 0.5),
            "s2": (0.3, 0.3),
            "s3": (0.05739, 0.05739),
            "s4": (0.6, 0.2),
            "s5": (0.4, 0.1),
            "s6": (0.2, 0.25),
            "s7": (0.05739, 0.0574),  # differ, but by far less than 5%
        }
    )
    chosen = figure1_subject(paper_main, "map")
    assert (chosen.subject, chosen.num_features, chosen.robot) == ("s5", 3, "map")
    assert (chosen.regret_expert, chosen.regret_best_response) == (0.4, 0.1)
    assert f"differ by more than {FIGURE1_DIFFERENCE:.0%}" in chosen.rule
    assert "no subject" not in chosen.rule


def test_figure1_falls_back_to_the_median_with_a_note_when_no_draws_regrets_differ():
    paper_main = _paper_main({"s1": (0.5, 0.5), "s2": (0.0, 0.0), "s3": (0.2, 0.2001)})
    chosen = figure1_subject(paper_main, "map")
    assert chosen.subject == "s1"  # improvements -1e-4, 0, 0: the lower median, by subject id
    assert "median of its feature level" in chosen.rule
    assert f"no subject's two regrets differ by more than {FIGURE1_DIFFERENCE:.0%}" in chosen.rule


def test_repeated_stays_draw_one_ring_per_cell_with_its_steps_beside_it():
    """Three stays on a cell, a move, two stays, and a return with one more stay: a ring per
    stayed cell, not one per stay, and each cell's combined step label clear of its ring."""
    states = np.array(
        [[2, 2], [2, 2], [2, 2], [2, 2], [3, 2], [3, 2], [3, 2], [2, 2], [2, 2]], dtype=float
    )
    figure = Figure(figsize=(3, 3), dpi=figures.DPI)
    axes = figure.add_subplot()
    axes.set_xlim(-0.5, 4.5)
    axes.set_ylim(-0.5, 4.5)
    figures._draw_path(axes, states)
    renderer = FigureCanvasAgg(figure).get_renderer()
    rings = [line for line in axes.get_lines() if line.get_markerfacecolor() == "none"]
    assert sorted(tuple(ring.get_xydata()[0]) for ring in rings) == [(2.0, 2.0), (3.0, 2.0)]
    labels = {text.get_text(): text for text in axes.texts if text.arrow_patch is None}
    assert {"0-3,7-8", "4-6"} <= set(labels)
    for ring in rings:
        (label,) = [t for t in labels.values() if tuple(t.xy) == tuple(ring.get_xydata()[0])]
        centre = axes.transData.transform(ring.get_xydata()[0])
        radius = (ring.get_markersize() + ring.get_markeredgewidth()) / 2 * figure.dpi / 72
        box = label.get_window_extent(renderer)
        nearest = np.clip(centre, [box.x0, box.y0], [box.x1, box.y1])
        assert np.hypot(*(nearest - centre)) > radius, label.get_text()
