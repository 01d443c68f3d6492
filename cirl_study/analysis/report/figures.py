"""The report's figures, rendered with matplotlib's Agg backend to deterministic PNG and SVG.

Identical input gives identical bytes: each figure is drawn on its own
:class:`~matplotlib.figure.Figure` (no pyplot state) under matplotlib's default style
plus :data:`STYLE`, at a fixed size and :data:`DPI`, and saved as PNG without the
``Software`` metadata entry (PNG files carry no timestamp) and as SVG without a date.

- Figure 1 (:func:`reward_maps`): for one reward draw, the true reward map, and each
  human's demonstration over the MAP reward map the robot inferred from it.
- Figure 2 (:func:`measure_bars`, :func:`lambda_curve`): the paper's three measures by human
  and feature level (and the other measures the analysis tests, in a figure of their own); the
  regret of every human of the sweep with every robot against the robot's rationality lambda.
- :func:`eta_curve`: the cross-validation of the best response's eta.
- :func:`robot_difference_curve`: a run with two robots, the paired regret difference of
  the other robot to the reference against lambda.
- :func:`cell_bars`: a study's measures by human, robot and feature level.
"""

from __future__ import annotations

import contextlib
import io
import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import matplotlib.style
import numpy as np
import pandas as pd
from matplotlib import rc_context, ticker
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.font_manager import FontProperties
from matplotlib.lines import Line2D
from matplotlib.textpath import TextPath
from numpy.typing import NDArray
from scipy import stats

from cirl_study.analysis.report.markdown import HIGHER_IS_BETTER, svg_name
from cirl_study.core.gridworld import feature_matrix
from cirl_study.features import RBFFeatures, TileFeatures
from cirl_study.measure_registry import MEASURES, analysed_measures
from cirl_study.record import BEST_RESPONSE, PAPER_HUMANS, TrialRecord
from cirl_study.workers import Call, call, started

DPI = 120
"""Resolution of every figure, in dots per inch."""

STYLE: dict[str, Any] = {
    "font.family": "DejaVu Sans",
    "font.size": 9,
    "axes.titlesize": 10,
    "figure.dpi": DPI,
    "savefig.dpi": DPI,
    "svg.hashsalt": "cirl-study",
    "svg.fonttype": "none",
}
"""Settings applied over matplotlib's default style. SVG text stays text (``svg.fonttype``
``none``): selectable and searchable, half the file, and a seventh of a figure's drawing
time less than tracing every glyph as a path; a viewer without DejaVu Sans shows it in its
own sans-serif."""

HUMAN_LABELS = {"expert": "expert", "best_response": "best response"}
HUMAN_COLOURS = {"expert": "#9e9e9e", "best_response": "#1f77b4"}
MEASURE_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b")
"""Colours of the measures in the order of the registry (the calibration figure)."""
LEVEL_MARKERS = ("o", "s", "^", "D", "v")
HUMAN_MARKERS = {"expert": "o", "best_response": "s"}
DODGE = {"expert": 1 / 1.08, "best_response": 1.08}
"""Factors that shift each human's points sideways on a log x axis."""


@dataclass(frozen=True)
class Rendered:
    """One figure as a 120-dpi PNG and as an SVG (vector) file."""

    png: bytes
    svg: bytes


def render(figure: Figure) -> Rendered:
    """``figure`` as PNG and SVG bytes, without metadata that could vary between runs.

    The SVG's element ids are salted with a fixed string (``svg.hashsalt`` in :data:`STYLE`)
    and it carries no date, so identical input gives identical bytes in both formats.
    """
    canvas = FigureCanvasAgg(figure)
    png, svg = io.BytesIO(), io.BytesIO()
    canvas.print_png(png, metadata={"Software": None})
    figure.savefig(svg, format="svg", metadata={"Date": None, "Creator": None})
    return Rendered(png.getvalue(), svg.getvalue())


def draw_all(drawings: Mapping[str, Call]) -> dict[str, bytes]:
    """The files (:func:`_figure_files`) of every figure of ``drawings`` (a drawing function of
    this module and its arguments, by PNG name), drawn on every core."""
    with drawing(drawings) as files:
        return files()


@contextlib.contextmanager
def drawing(drawings: Mapping[str, Call]) -> Iterator[Callable[[], dict[str, bytes]]]:
    """:func:`draw_all` begun: the figures are drawn in worker processes while this one goes
    on with its own work, until it calls the function given, which returns the files.

    A figure is drawn whole in one worker (:func:`~cirl_study.workers.started`), so a report's
    figures take about as long as its slowest, not their sum, on enough cores; each is the
    same, byte for byte, wherever it is drawn.
    """
    with started(call, list(drawings.values())) as rendered:
        yield lambda: _figure_files(dict(zip(drawings, rendered, strict=True)))


def _figure_files(rendered: Mapping[str, Rendered]) -> dict[str, bytes]:
    """The files of figures rendered under their PNG names: each PNG and its SVG twin."""
    files = {}
    for name, figure in rendered.items():
        files[name] = figure.png
        files[svg_name(name)] = figure.svg
    return files


def _new_figure(width: float, height: float) -> Figure:
    return Figure(figsize=(width, height), dpi=DPI)


@dataclass(frozen=True)
class Margins:
    """The space around a figure's grid of panels and between them, in inches.

    Fixed, and sized for the labels the figures draw (tick labels of a few digits, one-line
    axis labels, a title over the panels and one over the figure), rather than solved by
    matplotlib's constrained layout, which measures every label of the figure twice before
    drawing it: that was a third to a half of a figure's drawing time.
    """

    left: float = 0.75
    right: float = 0.15
    bottom: float = 0.55
    top: float = 0.6
    across: float = 0.6
    down: float = 0.75


def _panels(
    figure: Figure, rows: int, columns: int, margins: Margins = Margins(), **options: Any
) -> np.ndarray:
    """``rows x columns`` axes on ``figure`` within ``margins`` (an array, even of one)."""
    width, height = figure.get_size_inches()
    panel_width = (width - margins.left - margins.right - (columns - 1) * margins.across) / columns
    panel_height = (height - margins.top - margins.bottom - (rows - 1) * margins.down) / rows
    spacing = {
        "left": margins.left / width,
        "right": 1 - margins.right / width,
        "bottom": margins.bottom / height,
        "top": 1 - margins.top / height,
        "wspace": margins.across / panel_width,
        "hspace": margins.down / panel_height,
    }
    return figure.subplots(rows, columns, squeeze=False, gridspec_kw=spacing, **options)


def _figure_legend(figure: Figure, axes: Axes, columns: int) -> None:
    """The legend of ``axes``'s series, in one row under the panels (in the bottom margin)."""
    figure.legend(
        *axes.get_legend_handles_labels(),
        loc="lower center",
        bbox_to_anchor=(0.5, 0.0),
        ncols=columns,
        frameon=False,
    )


@dataclass(frozen=True)
class RewardScene:
    """What Figure 1 needs of one trial record, of any feature kind.

    ``features`` is the record's ``(width * height, K)`` matrix ``Phi``
    (:func:`~cirl_study.core.gridworld.feature_matrix`) and ``states`` the ``(T + 1, 2)``
    cells of the demonstration. What marks the features on the map: ``centers``, the
    ``(K, 2)`` centers of RBF features (``None`` for another kind), or ``tiles``, the rows of
    a tile layout, top row first, its ``legend`` (``None`` for another kind) and the
    ``goals``' cells.
    """

    width: int
    height: int
    centers: NDArray[np.float64] | None
    features: NDArray[np.float64]
    theta: NDArray[np.float64]
    theta_hat: NDArray[np.float64]
    states: NDArray[np.float64]
    tiles: tuple[str, ...] | None = None
    legend: tuple[tuple[str, str | None], ...] | None = None
    goals: tuple[tuple[int, int], ...] = ()

    @classmethod
    def from_record(cls, record: TrialRecord) -> RewardScene:
        """The grid, features, parameters and demonstration of a trial record.

        The record is taken as consistent (``theta``, ``theta_hat`` and its features of one
        length), as :func:`cirl_study.logs.record_checks.record_faults` checks when logs are
        read.
        """
        kind = record.features
        rbf = isinstance(kind, RBFFeatures)
        return cls(
            width=record.grid.width,
            height=record.grid.height,
            centers=np.asarray(kind.centers, dtype=np.float64) if rbf else None,
            features=feature_matrix(record),
            theta=np.asarray(record.theta, dtype=np.float64),
            theta_hat=np.asarray(record.theta_hat, dtype=np.float64),
            states=np.asarray(record.demonstration.states, dtype=np.float64),
            tiles=kind.layout if isinstance(kind, TileFeatures) else None,
            legend=kind.legend if isinstance(kind, TileFeatures) else None,
            goals=tuple(record.goals),
        )

    def reward_map(self, weights: NDArray[np.float64]) -> NDArray[np.float64]:
        """``(height, width)`` array of ``weights . phi([x, y])``, row ``y``, column ``x``."""
        return (self.features @ weights).reshape(self.height, self.width)

    def mark_features(self, axes: Axes) -> None:
        """Where the features lie: a cross on each RBF center, or each tile's character in
        the lower left of its cell."""
        if self.centers is not None:
            axes.plot(
                self.centers[:, 0],
                self.centers[:, 1],
                marker="x",
                color="black",
                linestyle="none",
                markersize=6,
            )
        for row, text in enumerate(self.tiles or ()):
            for x, char in enumerate(text):
                axes.text(x - 0.42, self.height - 1 - row - 0.42, char, ha="left",
                          va="bottom", fontsize=6, color="#333333")  # fmt: skip

    @property
    def key(self) -> str:
        """The line under Figure 1 that says how to read its panels (:data:`FIGURE1_KEY`)."""
        if self.legend is None or self.tiles is None:
            return FIGURE1_KEY
        goals = {self.tiles[self.height - 1 - y][x] for x, y in self.goals}
        tiles = ", ".join(
            f"{char} {name or ('goal' if char in goals else 'no feature')}"
            for char, name in self.legend
        )
        return FIGURE1_KEY.replace("Crosses: RBF centers.", f"Letters: the tiles ({tiles}).")


def _draw_map(axes: Axes, values: NDArray[np.float64], limit: float, title: str):
    height, width = values.shape
    image = axes.imshow(
        values,
        origin="lower",
        extent=(-0.5, width - 0.5, -0.5, height - 0.5),
        cmap="RdBu_r",
        vmin=-limit,
        vmax=limit,
        interpolation="nearest",
    )
    axes.set_title(title)
    axes.set_xticks(range(width))
    axes.set_yticks(range(height))
    axes.tick_params(labelsize=7)
    return image


def _draw_path(axes: Axes, states: NDArray[np.float64]) -> None:
    """The demonstration, step by step: each move an arrow coloured by its time step (light to
    dark), each cell numbered by the steps it is occupied at (:func:`_step_label`); back-and-forth
    moves are offset sideways so both directions show.

    A cell the demonstration stays on gets one ring, however many steps it stays there and
    however often it comes back (shaded as its last stay): its number says when (``3-5``: steps
    3 to 5), and it is set just outside the ring (:data:`RING_SIZE`), so neither hides the
    other.
    """
    steps = len(states) - 1
    colours = matplotlib.colormaps["Greys"](np.linspace(0.35, 1.0, max(steps, 1)))
    seen: dict[frozenset[tuple[float, float]], int] = {}
    stays: dict[tuple[float, float], int] = {}
    for t in range(steps):
        start, end = states[t], states[t + 1]
        edge = frozenset({(float(start[0]), float(start[1])), (float(end[0]), float(end[1]))})
        if len(edge) == 1:  # a stay: its cell's ring, drawn below once every stay is known
            stays[next(iter(edge))] = t
            continue
        repeat = seen.get(edge, 0)
        seen[edge] = repeat + 1
        shift = 0.12 * repeat
        normal = np.array([-(end - start)[1], (end - start)[0]]) * shift
        arrow = {"arrowstyle": "-|>", "color": colours[t], "linewidth": 1.8}
        axes.annotate("", xy=end + normal, xytext=start + normal, arrowprops=arrow)
    for cell, last in stays.items():
        axes.plot(*cell, marker="o", markersize=RING_SIZE, linestyle="none",
                  markerfacecolor="none", markeredgecolor=colours[last],
                  markeredgewidth=1.5)  # fmt: skip
    visits: dict[tuple[float, float], list[int]] = {}
    for t, cell in enumerate(states):
        visits.setdefault((float(cell[0]), float(cell[1])), []).append(t)
    for cell, times in visits.items():
        offset = RING_SIZE / 2 + 1 if cell in stays else 4
        axes.annotate(_step_label(times), cell, xytext=(offset, offset),
                      textcoords="offset points", fontsize=6)  # fmt: skip
    for index, marker in ((0, "o"), (-1, "s")):
        axes.plot(
            states[index, 0],
            states[index, 1],
            marker=marker,
            markersize=6,
            markerfacecolor="white",
            markeredgecolor="black",
            linestyle="none",
            zorder=3,
        )


RING_SIZE = 12.0
"""Diameter of the ring on a cell the demonstration stays on, in points; the cell's step
label starts just beyond its radius, up and to the right."""


def _step_label(times: list[int]) -> str:
    """The steps at which a cell is occupied, runs shortened: ``[4, 5, 6, 9]`` -> ``4-6,9``."""
    runs: list[list[int]] = []
    for t in times:
        if runs and t == runs[-1][-1] + 1:
            runs[-1].append(t)
        else:
            runs.append([t])
    return ",".join(f"{run[0]}-{run[-1]}" if len(run) > 1 else str(run[0]) for run in runs)


MAP_SIZE = 2.5
"""Side of each square reward map of Figure 1, in inches."""

FIGURE1_KEY = (
    "Demonstration: white dot = start, white square = end; arrows shade from light (first "
    "step) to dark (last); a ring: it stays on the cell.\nNumbers: the steps at which the "
    "demonstration is on the cell (3-4: steps 3 to 4; 2,5: steps 2 and 5). Crosses: RBF centers."
)
"""The key printed under Figure 1's panels."""


def reward_maps(expert: TrialRecord, best_response: TrialRecord, title: str) -> Rendered:
    """Figure 1, rendered: see :func:`reward_figure`."""
    with matplotlib.style.context("default"), rc_context(STYLE):
        return render(reward_figure(expert, best_response, title))


def reward_figure(expert: TrialRecord, best_response: TrialRecord, title: str) -> Figure:
    """Figure 1: true reward; each demonstration over the MAP reward inferred from it.

    The reward of cell ``s`` is ``theta . phi(s)``, with ``phi_k(s) = exp(-||s - c_k||^2 /
    (2 sigma^2))`` for RBF features or the one-hot colours (and the step) of a tile layout;
    the three panels share one symmetric colour scale. The demonstration runs from the white
    dot (step 0) to the white square, every step drawn and numbered, in shades from light
    (first) to dark (last), one ring on each cell it stays on (:func:`_draw_path`); crosses
    mark the RBF centers, or each cell's letter its tile (:meth:`RewardScene.mark_features`).
    The number beside a cell lists the steps at which the demonstration is there (``3-4``:
    steps 3 to 4; ``2,5``: steps 2 and 5). Each demonstration panel names its regret, and a
    legend line under the panels says how to read them.

    Args:
        expert: the expert's trial record of the reward draw.
        best_response: the best response's trial record of the same draw.
        title: the figure's title.
    """
    scenes = RewardScene.from_record(expert), RewardScene.from_record(best_response)
    maps = [
        scenes[0].reward_map(scenes[0].theta),
        scenes[0].reward_map(scenes[0].theta_hat),
        scenes[1].reward_map(scenes[1].theta_hat),
    ]
    limit = max(float(np.abs(values).max()) for values in maps) or 1.0
    titles = (
        "true reward",
        f"expert: regret {expert.measures['regret']:.3g}\n(over its MAP reward)",
        f"best response: regret {best_response.measures['regret']:.3g}\n(over its MAP reward)",
    )
    with matplotlib.style.context("default"), rc_context(STYLE):
        # Square maps of MAP_SIZE inches; the colour bar to the right of the last one.
        margins = Margins(left=0.55, right=1.2, bottom=0.95, top=0.85, across=0.5)
        figure = _new_figure(
            margins.left + 3 * MAP_SIZE + 2 * margins.across + margins.right,
            margins.bottom + MAP_SIZE + margins.top,
        )
        axes = _panels(figure, 1, 3, margins)[0]
        for panel, (values, name) in enumerate(zip(maps, titles, strict=True)):
            image = _draw_map(axes[panel], values, limit, name)
            scenes[0].mark_features(axes[panel])
            if panel:
                _draw_path(axes[panel], scenes[panel - 1].states)
            axes[panel].set_xlim(-0.5, scenes[0].width - 0.5)
            axes[panel].set_ylim(-0.5, scenes[0].height - 0.5)
            axes[panel].set_xlabel("x (cell)")
            axes[panel].set_ylabel("y (cell)")
        width, height = figure.get_size_inches()
        bar = figure.add_axes(
            (
                (width - margins.right + 0.3) / width,
                (margins.bottom + 0.1 * MAP_SIZE) / height,
                0.15 / width,
                0.8 * MAP_SIZE / height,
            )
        )
        figure.colorbar(image, cax=bar, label="reward of the cell")
        figure.text(0.5, 0.12 / height, scenes[0].key, ha="center", va="bottom", fontsize=7)
        figure.suptitle(title)
        return figure


def measure_label(measure: str) -> str:
    """A registered measure as the figures name it
    (:attr:`~cirl_study.measure_registry.Measure.label`)."""
    return MEASURES[measure].label


def _titled(measure: str) -> str:
    """A panel's title: the measure's label, marked with
    :data:`~cirl_study.analysis.report.markdown.HIGHER_IS_BETTER` where a higher value is better."""
    higher = "" if MEASURES[measure].lower_is_better else f" {HIGHER_IS_BETTER}"
    return measure_label(measure) + higher


def better(measures: Sequence[str]) -> str:
    """Which way is better, for a figure of ``measures``: lower, higher, or lower but where a
    panel is marked as a score (:func:`_titled`)."""
    lower = {MEASURES[measure].lower_is_better for measure in measures}
    if lower == {True}:
        return "Lower is better"
    if lower == {False}:
        return "Higher is better"
    return f"Lower is better, higher where marked {HIGHER_IS_BETTER}"


def measure_bars(cells: pd.DataFrame, measures: Sequence[str], title: str) -> Rendered:
    """Figure 2 (left, middle) of ``measures``: each one's mean with its 95% CI by human and
    level, one panel each (a level without a cell of a measure has no bar there).

    Args:
        cells: rows ``measure, num_features, human, mean, ci95_low, ci95_high``.
        measures: the measures drawn, in order.
        title: the figure's title.
    """
    levels = sorted(cells["num_features"].unique())
    positions = np.arange(len(levels), dtype=np.float64)
    width = 0.38
    with matplotlib.style.context("default"), rc_context(STYLE):
        figure = _new_figure(max(6.0, 10.0 * len(measures) / 3), 3.4)
        axes = _panels(figure, 1, len(measures), Margins(bottom=0.75, across=0.7))[0]
        for panel, measure in zip(axes, measures, strict=True):
            for offset, human in zip((-width / 2, width / 2), PAPER_HUMANS, strict=True):
                rows = (
                    cells[(cells["measure"] == measure) & (cells["human"] == human)]
                    .set_index("num_features")
                    .reindex(levels)
                )
                errors = np.vstack(
                    [rows["mean"] - rows["ci95_low"], rows["ci95_high"] - rows["mean"]]
                )
                panel.bar(
                    positions + offset,
                    rows["mean"],
                    width,
                    yerr=errors,
                    capsize=4,
                    color=HUMAN_COLOURS[human],
                    label=HUMAN_LABELS[human],
                )
            panel.set_xticks(positions, [f"{level} features" for level in levels])
            panel.set_title(_titled(measure))
            panel.set_ylabel(f"mean {measure_label(measure)} (95% CI)")
        _figure_legend(figure, axes[0], columns=2)
        figure.suptitle(title)
        return render(figure)


ROBOT_COLOURS = ("#4c72b0", "#dd8452", "#55a868", "#c44e52", "#8172b3")
"""Colours of a study's robots, in the pipeline's order (up to five distinct)."""


def participant_points(
    means: pd.DataFrame, conditions: Sequence[str], robots: Sequence[str]
) -> Rendered:
    """Each participant beside the means: one panel per measure, a group per condition, a
    column per robot, each participant's mean over her tasks as a point (spread sideways by
    a fixed pattern, so the figure is the same on every run) and the column's mean with its
    t-based 95% CI as a bar.

    Args:
        means: rows ``measure, subject, condition, robot, mean`` (one per participant, robot
            and measure).
        conditions: the conditions, in order (baseline first).
        robots: the robots, in order.
    """
    measures = list(dict.fromkeys(means["measure"]))
    width = 0.8 / max(1, len(robots))
    with matplotlib.style.context("default"), rc_context(STYLE):
        figure = _new_figure(max(6.0, 3.6 * len(measures)), 3.6)
        axes = _panels(figure, 1, len(measures), Margins(bottom=0.75, across=0.7))[0]
        for panel, measure in zip(axes, measures, strict=True):
            for r, robot in enumerate(robots):
                colour = ROBOT_COLOURS[r % len(ROBOT_COLOURS)]
                for c, condition in enumerate(conditions):
                    values = means.loc[
                        (means["measure"] == measure)
                        & (means["robot"] == robot)
                        & (means["condition"] == condition),
                        "mean",
                    ].to_numpy(dtype=np.float64)
                    if not len(values):
                        continue
                    x = c + (r - (len(robots) - 1) / 2) * width
                    spread = (np.arange(len(values)) % 7 - 3) * width / 18
                    panel.scatter(x + spread, values, s=9, color=colour, alpha=0.55, lw=0)
                    mean = float(values.mean())
                    half = (
                        float(stats.t.ppf(0.975, len(values) - 1) * values.std(ddof=1))
                        / math.sqrt(len(values))
                        if len(values) > 1
                        else 0.0
                    )
                    panel.errorbar(
                        x, mean, yerr=half, fmt="_", markersize=14, capsize=5, color="black",
                        label=None,
                    )  # fmt: skip
                panel.scatter([], [], s=16, color=colour, label=robot.replace("_", " "))
            panel.set_xticks(range(len(conditions)), list(conditions))
            panel.set_title(_titled(measure))
            panel.set_ylabel(f"{measure_label(measure)} (participant means)")
        _figure_legend(figure, axes[0], columns=min(4, len(robots)))
        figure.suptitle("Each participant's mean over her tasks; bars: mean with 95% CI")
        return render(figure)


WIDE_CELLS = 16
"""Bars per panel (humans x robots) above which :func:`cell_bars` gives each measure a row of
its own, so every panel spans the figure's width."""


def cell_bars(cells: pd.DataFrame, humans: Sequence[str], robots: Sequence[str]) -> Rendered:
    """The cell means, rendered: see :func:`cell_figure`."""
    with matplotlib.style.context("default"), rc_context(STYLE):
        return render(cell_figure(cells, humans, robots))


def cell_figure(cells: pd.DataFrame, humans: Sequence[str], robots: Sequence[str]) -> Figure:
    """Every measure's mean with its 95% CI by human (groups) and robot (bars), of each measure
    the analysis tests (:func:`~cirl_study.measure_registry.analysed_measures`) that has a
    cell: a row of panels per feature level, the measures across; or, with more than
    :data:`WIDE_CELLS` bars a panel (up to 8 humans and 4 robots), a row per measure, the
    feature levels across. The figure is 11 inches wide, wider beyond three panels across so
    that each stays readable. Each panel labels its measure; a human's name is broken at its
    underscores, so the names of 8 humans fit under a panel side by side.

    Args:
        cells: rows ``measure, num_features, human, robot, mean, ci95_low, ci95_high``.
        humans: the humans, in the order drawn.
        robots: the robots, in the order drawn.
    """
    levels = sorted(cells["num_features"].unique())
    measures = [m for m in analysed_measures() if m in set(cells["measure"])]
    positions = np.arange(len(humans), dtype=np.float64)
    width = 0.8 / len(robots)
    panels = [[(level, measure) for measure in measures] for level in levels]
    if len(humans) * len(robots) > WIDE_CELLS:
        panels = [[(level, measure) for level in levels] for measure in measures]
    with matplotlib.style.context("default"), rc_context(STYLE):
        figure = _new_figure(max(11.0, 3.65 * len(panels[0])), 2.9 * len(panels) + 0.8)
        grid = _panels(figure, len(panels), len(panels[0]), Margins(bottom=0.95, down=0.9))
        for axes_row, panel_row in zip(grid, panels, strict=True):
            for panel, (level, measure) in zip(axes_row, panel_row, strict=True):
                for index, robot in enumerate(robots):
                    chosen = (
                        cells[
                            (cells["measure"] == measure)
                            & (cells["num_features"] == level)
                            & (cells["robot"] == robot)
                        ]
                        .set_index("human")
                        .reindex(list(humans))
                    )
                    errors = np.vstack(
                        [chosen["mean"] - chosen["ci95_low"], chosen["ci95_high"] - chosen["mean"]]
                    )
                    panel.bar(
                        positions + (index - (len(robots) - 1) / 2) * width,
                        chosen["mean"],
                        width,
                        yerr=errors,
                        capsize=2,
                        color=ROBOT_COLOURS[index % len(ROBOT_COLOURS)],
                        label=f"robot {robot}",
                    )
                panel.set_xticks(positions, [h.replace("_", "\n") for h in humans], fontsize=8)
                panel.set_title(f"{_titled(measure)}, {level} features")
                panel.set_ylabel(f"mean {measure_label(measure)} (95% CI)", fontsize=8)
        for panel in grid[-1]:
            panel.set_xlabel("human")
        _figure_legend(figure, grid[0][0], columns=len(robots))
        figure.suptitle(f"{better(measures)}: mean (95% CI) by human and robot")
        return figure


def _curves(
    axes: Axes,
    frame: pd.DataFrame,
    x: str,
    series: Sequence[tuple[str, pd.DataFrame, dict[str, Any]]],
) -> None:
    for label, rows, style in series:
        rows = rows.sort_values(x)
        errors = np.vstack([rows["mean"] - rows["ci95_low"], rows["ci95_high"] - rows["mean"]])
        axes.errorbar(rows[x], rows["mean"], yerr=errors, label=label, **{"capsize": 3, **style})
    if (frame[x] > 0).all():
        _log_axis(axes)


def _log_axis(axes: Axes) -> None:
    """A log x axis labelled in plain numbers (0.01, 1, 100), without minor ticks.

    Plain labels read as the values a pipeline file states, and they spare the mathtext
    parser that matplotlib's default ``10^n`` labels start in every process. There are no
    minor ticks, each a tick with its own label laid out (empty or not): the points the
    figures show sit on the labelled values or between them.
    """
    axes.set_xscale("log")
    axes.xaxis.set_major_formatter(ticker.FuncFormatter(lambda value, _: f"{value:g}"))
    axes.xaxis.set_minor_locator(ticker.NullLocator())


STAR_SIZE = 22.0
"""Size of the gold star that marks a point (:func:`_star_on`), in points: about four times a
point's marker, so it shows around the marker it lies beneath."""

LOWEST_REGRET = "lowest best-response regret"
"""The legend's name for the star of :func:`lambda_figure`."""


def _star_on(axes: Axes, x: float, y: float, label: str) -> None:
    """A gold star centred on the data point ``(x, y)`` it marks, beneath every line and
    marker (``zorder`` 1.5, below the lines' 2): it rims the point's own marker and hides
    nothing, neither that marker, its interval, nor a neighbour's."""
    axes.plot(x, y, marker="*", markersize=STAR_SIZE, color="gold", markeredgecolor="#7f6000",
              markeredgewidth=0.8, linestyle="none", label=label, zorder=1.5)  # fmt: skip


OTHER_HUMAN_COLOURS = ("#E69F00", "#009E73", "#D55E00", "#CC79A7", "#56B4E9", "#000000", "#F0E442")
"""Colours of the humans beyond the paper's two, in the run's order: Okabe and Ito's
colour-blind-safe palette (yellow last: it is faint on white). The paper's humans keep their
grey and blue (:data:`HUMAN_COLOURS`), as in every figure."""

OTHER_HUMAN_MARKERS = ("^", "D", "v", "P", "X", "h", "<", ">")
"""Markers of the humans beyond the paper's two (circle and square: :data:`HUMAN_MARKERS`), in
the run's order, so that no two humans share colour and marker even in grey print."""


def human_styles(humans: Sequence[str]) -> dict[str, dict[str, str]]:
    """Each human's colour and marker, by name: the paper's humans their own
    (:data:`HUMAN_COLOURS`, :data:`HUMAN_MARKERS`), every other one the next of
    :data:`OTHER_HUMAN_COLOURS` and :data:`OTHER_HUMAN_MARKERS` in the order of ``humans``
    (distinct for up to seven others)."""
    styles = {}
    others = 0
    for human in humans:
        if human in HUMAN_COLOURS:
            styles[human] = {"color": HUMAN_COLOURS[human], "marker": HUMAN_MARKERS[human]}
            continue
        styles[human] = {
            "color": OTHER_HUMAN_COLOURS[others % len(OTHER_HUMAN_COLOURS)],
            "marker": OTHER_HUMAN_MARKERS[others % len(OTHER_HUMAN_MARKERS)],
        }
        others += 1
    return styles


def human_label(human: str) -> str:
    """A human as the figures name it: the paper's by :data:`HUMAN_LABELS`, others by name."""
    return HUMAN_LABELS.get(human, human)


def _dodge(humans: Sequence[str], rationalities: Sequence[float]) -> dict[str, float]:
    """Factors that shift each human's points sideways on a log lambda axis, in the order of
    ``humans`` from left to right around the true lambda: neighbours a factor ``1.08**2``
    apart (:data:`DODGE`, for two humans), closer where that would spread the group over more
    than half the gap between neighbouring lambdas."""
    values = sorted({float(value) for value in rationalities if value > 0})
    gaps = np.diff(np.log10(values))
    gap = float(gaps.min()) if len(gaps) else 1.0
    step = min(2 * float(np.log10(DODGE[BEST_RESPONSE])), 0.5 * gap / max(len(humans) - 1, 1))
    middle = (len(humans) - 1) / 2
    return {human: 10 ** (step * (i - middle)) for i, human in enumerate(humans)}


def lambda_curve(
    sweep: pd.DataFrame, humans: Sequence[str] = (), robots: Sequence[str] = ()
) -> Rendered:
    """Figure 2 (right), rendered: see :func:`lambda_figure`."""
    with matplotlib.style.context("default"), rc_context(STYLE):
        return render(lambda_figure(sweep, humans, robots))


LAMBDA_PANEL = (4.0, 2.65)
"""Width and height of each panel of :func:`lambda_figure`, in inches."""


def lambda_figure(
    sweep: pd.DataFrame, humans: Sequence[str] = (), robots: Sequence[str] = ()
) -> Figure:
    """Figure 2 (right): regret against the robot's rationality lambda, log axis.

    A panel per feature level (across) and robot (down, titled with its name where the sweep
    has several); in each, one line per human of the sweep, each in its colour and marker
    (:func:`human_styles`: colour-blind safe, no two alike for up to 8 humans), dodged
    sideways so that none hides another where they coincide (:func:`_dodge`); bars are 95%
    CIs. A gold star beneath the best response's point of lowest mean regret, centred on it,
    marks the point of the paper's claim. Every panel has its own regret scale, labelled; the
    legend (the humans, the star) stands right of the panels, outside the data.

    Args:
        sweep: rows ``measure, rationality, human, robot, num_features, mean, ci95_low,
            ci95_high`` (without ``robot``: one robot).
        humans: the humans in the order drawn (default: as they first appear in ``sweep``);
            those without a row are left out.
        robots: the robots in the order drawn, likewise.
    """
    regret = sweep[sweep["measure"] == "regret"]
    if "robot" not in regret.columns:
        regret = regret.assign(robot="")
    humans = _present(humans, regret["human"])
    robots = _present(robots, regret["robot"])
    levels = sorted(regret["num_features"].unique())
    styles = human_styles(humans)
    dodge = _dodge(humans, regret["rationality"])
    labels = [human_label(human) for human in humans]
    starred = BEST_RESPONSE in humans
    legend = max(map(_text_width, [*labels, LOWEST_REGRET if starred else ""])) + 0.55
    margins = Margins(right=legend + 0.25, down=0.6)
    panel_width, panel_height = LAMBDA_PANEL
    with matplotlib.style.context("default"), rc_context(STYLE):
        figure = _new_figure(
            margins.left + margins.right + len(levels) * panel_width
            + (len(levels) - 1) * margins.across,
            margins.bottom + margins.top + len(robots) * panel_height
            + (len(robots) - 1) * margins.down,
        )  # fmt: skip
        grid = _panels(figure, len(robots), len(levels), margins)
        for row, robot in enumerate(robots):
            for axes, level in zip(grid[row], levels, strict=True):
                cell = regret[(regret["robot"] == robot) & (regret["num_features"] == level)]
                _curves(axes, cell, "rationality", _human_series(cell, humans, dodge, styles))
                best = cell[cell["human"] == BEST_RESPONSE]
                if best["mean"].notna().any():
                    lowest = best.loc[best["mean"].idxmin()]
                    _star_on(axes, lowest["rationality"] * dodge[BEST_RESPONSE],
                             lowest["mean"], LOWEST_REGRET)  # fmt: skip
                where = f"robot {robot}, " if len(robots) > 1 else ""
                axes.set_title(f"{where}{level} features")
                axes.set_ylabel("mean regret (95% CI)")
                axes.tick_params(axis="x", labelsize=8)
                if row == len(robots) - 1:
                    axes.set_xlabel("robot's rationality λ")
        keys = [
            Line2D([], [], markersize=6, label=label, **styles[human])
            for human, label in zip(humans, labels, strict=True)
        ]
        if starred:
            keys.append(
                Line2D([], [], marker="*", markersize=STAR_SIZE * 0.75, color="gold",
                       markeredgecolor="#7f6000", linestyle="none", label=LOWEST_REGRET)
            )  # fmt: skip
        width, height = figure.get_size_inches()
        figure.legend(
            handles=keys,
            loc="center left",
            bbox_to_anchor=((width - margins.right + 0.15) / width, 0.5),
            frameon=False,
        )
        figure.suptitle(
            "Regret against the rationality the robot assumes (lower is better)",
            y=1 - 0.1 / height,
            va="top",
        )
        return figure


def _present(order: Sequence[str], column: pd.Series) -> list[str]:
    """The values of ``column`` in the order of ``order`` (by first appearance without one),
    those it lacks left out."""
    present = list(dict.fromkeys(column.tolist()))
    return [value for value in order if value in present] if order else present


def _human_series(
    rows: pd.DataFrame,
    humans: Sequence[str],
    dodge: Mapping[str, float],
    styles: Mapping[str, Mapping[str, str]],
) -> list[tuple[str, pd.DataFrame, dict[str, Any]]]:
    """Each human's rows, dodged along a log x axis, in the human's colour and marker."""
    return [
        (
            human_label(human),
            rows[rows["human"] == human].assign(
                rationality=rows.loc[rows["human"] == human, "rationality"] * dodge[human]
            ),
            {
                **styles[human],
                "markersize": 6,
                "capsize": 3 if len(humans) < 4 else 2,
                "elinewidth": 1.5 if len(humans) < 4 else 1.0,
            },
        )
        for human in humans
        if (rows["human"] == human).any()
    ]


def eta_curve(means: pd.DataFrame, choice: pd.DataFrame) -> Rendered:
    """The eta cross-validation: mean best-response regret against eta, chosen eta starred.

    One panel per feature level (their regrets differ tenfold), in the best response's colour
    as everywhere else; a gold star beneath the chosen eta's point, centred on it
    (:func:`_star_on`), marks the chosen eta, and a dashed line one standard error above its
    mean: every eta below the line is as good by the one-standard-error rule.

    Args:
        means: rows ``num_features, eta, mean, ci95_low, ci95_high``.
        choice: rows ``num_features, eta, mean, se``
            (:func:`cirl_study.analysis.statistics.procedures.eta_choice_uncertainty`).
    """
    levels = sorted(means["num_features"].unique())
    style = {
        "color": HUMAN_COLOURS[BEST_RESPONSE],
        "marker": HUMAN_MARKERS[BEST_RESPONSE],
        "markersize": 5,
    }
    with matplotlib.style.context("default"), rc_context(STYLE):
        figure = _new_figure(4.2 * len(levels), 3.6)
        panels = _panels(figure, 1, len(levels))[0]
        for axes, level in zip(panels, levels, strict=True):
            rows = means[means["num_features"] == level]
            _curves(axes, rows, "eta", [(HUMAN_LABELS[BEST_RESPONSE], rows, style)])
            row = choice[choice["num_features"] == level]
            if not row.empty:
                line = float(row["mean"].iloc[0] + row["se"].iloc[0])
                axes.axhline(line, color="black", linestyle="--", linewidth=0.8,
                             label="one SE above the chosen")  # fmt: skip
                chosen = rows[rows["eta"] == float(row["eta"].iloc[0])]
                if not chosen.empty:
                    _star_on(axes, float(chosen["eta"].iloc[0]), float(chosen["mean"].iloc[0]),
                             "chosen η")  # fmt: skip
            axes.set_title(f"{level} features")
            axes.set_xlabel("η (trade-off between reward and feature matching)")
        panels[0].set_ylabel("mean best-response regret (95% CI)")
        legend = panels[0].legend(frameon=False, fontsize=8)
        for handle in legend.legend_handles:  # the star at the size of the lambda figure's key
            if isinstance(handle, Line2D) and handle.get_marker() == "*":
                handle.set_markersize(STAR_SIZE * 0.75)
        figure.suptitle("Cross-validation of η: the lowest mean regret is chosen")
        return render(figure)


def robot_difference_curve(sweep: pd.DataFrame, reference: str, other: str) -> Rendered:
    """Mean paired regret difference ``other - reference`` against lambda, per feature level.

    One panel per feature level, one line per human (the human's colour; the humans
    are dodged sideways so their intervals do not hide each other); bars are 95% CIs of
    the mean difference; below the zero line the other robot did better.

    Args:
        sweep: rows ``measure, rationality, num_features, human, mean_diff, ci95_low,
            ci95_high`` (:func:`cirl_study.analysis.statistics.procedures.paired_differences`).
        reference: the reference robot's name.
        other: the other robot's name.
    """
    regret = sweep[sweep["measure"] == "regret"].rename(columns={"mean_diff": "mean"})
    levels = sorted(regret["num_features"].unique())
    with matplotlib.style.context("default"), rc_context(STYLE):
        figure = _new_figure(4.0 * len(levels), 3.6)
        panels = _panels(figure, 1, len(levels), Margins(across=0.3), sharey=True)[0]
        for axes, level in zip(panels, levels, strict=True):
            axes.axhline(0.0, color="black", linewidth=0.8)
            at_level = regret[regret["num_features"] == level]
            series = _human_series(at_level, PAPER_HUMANS, DODGE, human_styles(PAPER_HUMANS))
            _curves(axes, at_level, "rationality", series)
            axes.set_title(f"{level} features")
            axes.set_xlabel("robot's rationality λ")
        panels[0].set_ylabel(f"regret, {other} minus {reference} (95% CI)")
        panels[0].legend(frameon=False, fontsize=8, title="human")
        figure.suptitle(f"Below zero: {other} did better than {reference}")
        return render(figure)


def specification_curve(
    effects: pd.DataFrame, choices: pd.DataFrame, measure: str, marked: str
) -> Rendered:
    """The specification curve of one measure (Simonsohn, Simmons & Nelson 2020).

    Top: each universe's human effect (mean of ``best response - expert``, 95% CI), sorted
    by size; filled where ``p < .05``, hollow otherwise; the universe ``marked`` (the
    pipeline's own, the paper's reading) in red. Below: the dashboard, one row per level of
    every axis that varies, a mark where the universe above made that choice.

    Args:
        effects: rows ``universe, mean_diff, ci95_low, ci95_high, p`` of this measure.
        choices: one row per universe (index: its id), one column per varied axis.
        measure: the measure's name (a registered one, its :func:`measure_label` shown).
        marked: the id of the universe to mark.
    """
    ordered = effects.sort_values(["mean_diff", "universe"], kind="mergesort").reset_index(
        drop=True
    )
    x = np.arange(len(ordered), dtype=np.float64)
    significant = (ordered["p"] < 0.05).to_numpy()
    rows = [(axis, level) for axis in choices.columns for level in _levels(choices[axis])]
    with matplotlib.style.context("default"), rc_context(STYLE):
        figure = _new_figure(max(6.0, 0.12 * len(ordered) + 3.0), 3.2 + 0.22 * len(rows))
        labels = [f"{axis} = {level}" for axis, level in rows]
        margins = Margins(
            left=max(0.8, 0.3 + max(map(_text_width, labels), default=0.0)),
            top=0.45,
            bottom=0.4,
            down=0.15,
        )
        curve, dashboard = _panels(
            figure, 2, 1, margins, sharex=True, height_ratios=[3.0, max(1.0, 0.22 * len(rows))]
        )[:, 0]
        curve.axhline(0.0, color="black", linewidth=0.8)
        colours = np.where(ordered["universe"] == marked, "#d62728", "#1f77b4")
        errors = np.vstack(
            [
                ordered["mean_diff"] - ordered["ci95_low"],
                ordered["ci95_high"] - ordered["mean_diff"],
            ]
        )
        curve.errorbar(x, ordered["mean_diff"], yerr=errors, fmt="none", ecolor="#9e9e9e", lw=0.8)
        for filled in (True, False):
            at = significant == filled
            curve.scatter(
                x[at],
                ordered["mean_diff"][at],
                s=18,
                c=colours[at] if filled else "white",
                edgecolors=colours[at],
                zorder=3,
            )
        curve.set_ylabel(f"{measure_label(measure)}: best response - expert")
        keys = [
            Line2D([], [], linestyle="none", marker="o", color="#1f77b4", label="p < .05"),
            Line2D(
                [], [], linestyle="none", marker="o", color="#1f77b4", markerfacecolor="white",
                label="p >= .05",
            ),
        ]  # fmt: skip
        curve.legend(handles=keys, frameon=False, fontsize=8, loc="upper left")
        for position, universe in enumerate(ordered["universe"]):
            for row, (axis, level) in enumerate(rows):
                if choices.at[universe, axis] == level:
                    dashboard.scatter(
                        position, row, s=10, marker="s", c=colours[position], linewidths=0
                    )
        dashboard.set_yticks(np.arange(len(rows)), labels)
        dashboard.set_ylim(len(rows) - 0.5, -0.5)
        dashboard.set_xlabel("universes, by effect (red: the pipeline's own settings)")
        dashboard.set_xticks([])
        figure.suptitle(f"Specification curve: the human effect on {measure_label(measure)}")
        return render(figure)


def calibration_plot(points: pd.DataFrame) -> Rendered:
    """Target against measured cell means, both on log scales, for the nearest universes.

    One marker per universe (by rank, the nearest filled) and one colour per measure; the
    diagonal is agreement, the dashed lines a factor of 2 either way.

    Args:
        points: rows ``rank, universe, measure, target, measured``.
    """
    with matplotlib.style.context("default"), rc_context(STYLE):
        figure = _new_figure(5.6, 4.6)
        (axes,) = _panels(figure, 1, 1, Margins(right=2.0, top=0.45))[0]
        values = np.concatenate([points["target"], points["measured"]])
        low, high = values.min() / 2.5, values.max() * 2.5
        line = np.array([low, high])
        axes.plot(line, line, color="black", linewidth=0.8)
        for factor in (0.5, 2.0):
            axes.plot(line, factor * line, color="#9e9e9e", linewidth=0.8, linestyle="--")
        colours = {
            m: MEASURE_COLOURS[position % len(MEASURE_COLOURS)]
            for position, m in enumerate(MEASURES)
        }
        for rank, universe in points.groupby("rank", sort=True)["universe"].first().items():
            at = points[points["rank"] == rank]
            marker = LEVEL_MARKERS[(rank - 1) % len(LEVEL_MARKERS)]
            axes.scatter(
                at["target"],
                at["measured"],
                s=28,
                marker=marker,
                c=[colours[m] if rank == 1 else "white" for m in at["measure"]],
                edgecolors=[colours[m] for m in at["measure"]],
                linewidths=1.0,
                label=f"#{rank} {universe}" if len(universe) <= 40 else f"#{rank}",
                zorder=3,
            )
        axes.set_xscale("log")
        axes.set_yscale("log")
        axes.set_xlim(low, high)
        axes.set_ylim(low, high)
        axes.set_xlabel("target cell mean")
        axes.set_ylabel("measured cell mean")
        keys = [
            Line2D([], [], linestyle="none", marker="o", color=colour, label=measure_label(m))
            for m, colour in colours.items()
            if m in set(points["measure"])
        ]
        keys += [
            Line2D(
                [], [], linestyle="none", color="black", label=label,
                marker=LEVEL_MARKERS[(rank - 1) % len(LEVEL_MARKERS)],
                markerfacecolor="black" if rank == 1 else "white",
            )
            for rank, label in enumerate(axes.get_legend_handles_labels()[1], start=1)
        ]  # fmt: skip
        axes.legend(
            handles=keys, frameon=False, fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0)
        )
        figure.suptitle("Calibration: target against measured (dashed: a factor of 2)")
        return render(figure)


def _text_width(text: str) -> float:
    """The width in inches of ``text`` set in the figures' font at their size."""
    font = FontProperties(family=STYLE["font.family"], size=STYLE["font.size"])
    return TextPath((0, 0), text, prop=font).get_extents().width / 72


def _levels(column: pd.Series) -> list[Any]:
    """A dashboard axis's levels in the order they first appear."""
    return list(dict.fromkeys(column.tolist()))
