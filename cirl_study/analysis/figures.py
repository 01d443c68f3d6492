"""The report's figures, rendered with matplotlib's Agg backend to deterministic PNG bytes.

Identical input gives identical bytes: each figure is drawn on its own
:class:`~matplotlib.figure.Figure` (no pyplot state) under matplotlib's default style
plus :data:`STYLE`, at a fixed size and :data:`DPI`, and saved without the ``Software``
metadata entry (PNG files carry no timestamp).

- Figure 1 (:func:`reward_maps`): for one reward draw, the true reward map, and each
  policy's demonstration over the MAP reward map the robot inferred from it.
- Figure 2 (:func:`measure_bars`, :func:`lambda_curve`): the three measures by policy and
  feature level; the regret against the robot's rationality lambda.
- :func:`eta_curve`: the cross-validation of the best response's eta.
- :func:`robot_difference_curve`: a run with two robots, the paired regret difference of
  the other robot to the reference against lambda.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import matplotlib.style
import numpy as np
import pandas as pd
from matplotlib import rc_context
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from numpy.typing import NDArray

from cirl_study.core.gridworld import feature_matrix
from cirl_study.record import MEASURES, PAPER_POLICIES, TrialRecord

DPI = 120
"""Resolution of every figure, in dots per inch."""

STYLE: dict[str, Any] = {
    "font.family": "DejaVu Sans",
    "font.size": 9,
    "axes.titlesize": 10,
    "figure.dpi": DPI,
    "savefig.dpi": DPI,
}
"""Settings applied over matplotlib's default style."""

POLICY_LABELS = {"expert": "expert", "best_response": "best response"}
POLICY_COLOURS = {"expert": "#9e9e9e", "best_response": "#1f77b4"}
MEASURE_LABELS = {
    "regret": "regret",
    "kl": "KL divergence",
    "reward_l2": "reward L2 distance",
}
LEVEL_MARKERS = ("o", "s", "^", "D", "v")


def render_png(figure: Figure) -> bytes:
    """The PNG bytes of ``figure``, without metadata that could vary between runs."""
    canvas = FigureCanvasAgg(figure)
    buffer = io.BytesIO()
    canvas.print_png(buffer, metadata={"Software": None})
    return buffer.getvalue()


def _new_figure(width: float, height: float) -> Figure:
    return Figure(figsize=(width, height), dpi=DPI, layout="constrained")


@dataclass(frozen=True)
class RewardScene:
    """What Figure 1 needs of one trial record.

    ``features`` is the record's ``(width * height, K)`` RBF matrix ``Phi``
    (:meth:`~cirl_study.record.TrialSpec.feature_matrix`), ``centers`` its ``(K, 2)``
    centres and ``states`` the ``(T + 1, 2)`` cells of the demonstration.
    """

    width: int
    height: int
    centers: NDArray[np.float64]
    features: NDArray[np.float64]
    theta: NDArray[np.float64]
    theta_hat: NDArray[np.float64]
    states: NDArray[np.float64]

    @classmethod
    def from_record(cls, record: TrialRecord) -> RewardScene:
        """The grid, features, parameters and demonstration of a trial record.

        The record is taken as consistent (``theta``, ``theta_hat`` and the centres of one
        length), as :func:`cirl_study.logs.record_checks.record_faults` checks when logs are
        read.
        """
        return cls(
            width=record.grid.width,
            height=record.grid.height,
            centers=np.asarray(record.features.centers, dtype=np.float64),
            features=feature_matrix(record),
            theta=np.asarray(record.theta, dtype=np.float64),
            theta_hat=np.asarray(record.theta_hat, dtype=np.float64),
            states=np.asarray(record.demonstration.states, dtype=np.float64),
        )

    def reward_map(self, weights: NDArray[np.float64]) -> NDArray[np.float64]:
        """``(height, width)`` array of ``weights . phi([x, y])``, row ``y``, column ``x``."""
        return (self.features @ weights).reshape(self.height, self.width)


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
    """The demonstration: an arrow per move, a white dot at the start, a square at the end."""
    steps = np.diff(states, axis=0)
    axes.quiver(
        states[:-1, 0],
        states[:-1, 1],
        steps[:, 0],
        steps[:, 1],
        angles="xy",
        scale_units="xy",
        scale=1,
        width=0.012,
        color="black",
    )
    for index, marker in ((0, "o"), (-1, "s")):
        axes.plot(
            states[index, 0],
            states[index, 1],
            marker=marker,
            markersize=9,
            markerfacecolor="white",
            markeredgecolor="black",
            linestyle="none",
        )


def reward_maps(expert: TrialRecord, best_response: TrialRecord, title: str) -> bytes:
    """Figure 1: true reward; each demonstration over the MAP reward inferred from it.

    The reward of cell ``s`` is ``theta . phi(s)`` with ``phi_k(s) = exp(-||s - c_k||^2 /
    (2 sigma^2))``; the three panels share one symmetric colour scale. The demonstration
    runs from the white dot to the white square; the crosses are the RBF centres.

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
        "expert demonstration\nover its MAP reward",
        "best-response demonstration\nover its MAP reward",
    )
    with matplotlib.style.context("default"), rc_context(STYLE):
        figure = _new_figure(10.0, 3.8)
        axes = figure.subplots(1, 3)
        for panel, (values, name) in enumerate(zip(maps, titles, strict=True)):
            image = _draw_map(axes[panel], values, limit, name)
            axes[panel].plot(
                scenes[0].centers[:, 0],
                scenes[0].centers[:, 1],
                marker="x",
                color="black",
                linestyle="none",
                markersize=6,
            )
            if panel:
                _draw_path(axes[panel], scenes[panel - 1].states)
            axes[panel].set_xlim(-0.5, scenes[0].width - 0.5)
            axes[panel].set_ylim(-0.5, scenes[0].height - 0.5)
        figure.colorbar(image, ax=list(axes), shrink=0.8, label="reward of the cell")
        figure.suptitle(title)
        return render_png(figure)


def measure_bars(cells: pd.DataFrame) -> bytes:
    """Figure 2 (left, middle): each measure's mean with its 95% CI by policy and level.

    Args:
        cells: rows ``measure, num_features, policy, mean, ci95_low, ci95_high``.
    """
    levels = sorted(cells["num_features"].unique())
    positions = np.arange(len(levels), dtype=np.float64)
    width = 0.38
    with matplotlib.style.context("default"), rc_context(STYLE):
        figure = _new_figure(10.0, 3.4)
        axes = figure.subplots(1, len(MEASURES))
        for panel, measure in zip(axes, MEASURES, strict=True):
            for offset, policy in zip((-width / 2, width / 2), PAPER_POLICIES, strict=True):
                rows = (
                    cells[(cells["measure"] == measure) & (cells["policy"] == policy)]
                    .set_index("num_features")
                    .loc[levels]
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
                    color=POLICY_COLOURS[policy],
                    label=POLICY_LABELS[policy],
                )
            panel.set_xticks(positions, [f"{level} features" for level in levels])
            panel.set_title(MEASURE_LABELS[measure])
            panel.set_ylabel(f"mean {MEASURE_LABELS[measure]} (95% CI)")
        figure.legend(
            *axes[0].get_legend_handles_labels(), loc="outside lower center", ncols=2, frameon=False
        )
        figure.suptitle("Lower is better: the three measures by policy and number of features")
        return render_png(figure)


def _curves(
    axes: Axes,
    frame: pd.DataFrame,
    x: str,
    series: Sequence[tuple[str, pd.DataFrame, dict[str, Any]]],
) -> None:
    for label, rows, style in series:
        rows = rows.sort_values(x)
        errors = np.vstack([rows["mean"] - rows["ci95_low"], rows["ci95_high"] - rows["mean"]])
        axes.errorbar(rows[x], rows["mean"], yerr=errors, capsize=3, label=label, **style)
    if (frame[x] > 0).all():
        axes.set_xscale("log")


def lambda_curve(sweep: pd.DataFrame) -> bytes:
    """Figure 2 (right): regret against the robot's rationality lambda, log axis.

    Best response solid, expert dashed, one marker per feature level; bars are 95% CIs.

    Args:
        sweep: rows ``measure, rationality, policy, num_features, mean, ci95_low, ci95_high``.
    """
    regret = sweep[sweep["measure"] == "regret"]
    series = []
    for index, level in enumerate(sorted(regret["num_features"].unique())):
        for policy, line in zip(PAPER_POLICIES, ("--", "-"), strict=True):
            rows = regret[(regret["num_features"] == level) & (regret["policy"] == policy)]
            style = {
                "color": POLICY_COLOURS[policy],
                "linestyle": line,
                "marker": LEVEL_MARKERS[index % len(LEVEL_MARKERS)],
            }
            series.append((f"{POLICY_LABELS[policy]}, {level} features", rows, style))
    with matplotlib.style.context("default"), rc_context(STYLE):
        figure = _new_figure(6.0, 4.0)
        axes = figure.subplots()
        _curves(axes, regret, "rationality", series)
        axes.set_xlabel("robot's rationality λ")
        axes.set_ylabel("mean regret (95% CI)")
        axes.set_title("Regret against the rationality the robot assumes")
        axes.legend(frameon=False, fontsize=8)
        return render_png(figure)


def eta_curve(means: pd.DataFrame, chosen: pd.DataFrame) -> bytes:
    """The eta cross-validation: mean best-response regret against eta, chosen eta starred.

    Args:
        means: rows ``num_features, eta, mean, ci95_low, ci95_high``.
        chosen: rows ``num_features, eta, mean``.
    """
    levels = sorted(means["num_features"].unique())
    series = [
        (
            f"{level} features",
            means[means["num_features"] == level],
            {"marker": LEVEL_MARKERS[index % len(LEVEL_MARKERS)], "color": f"C{index}"},
        )
        for index, level in enumerate(levels)
    ]
    with matplotlib.style.context("default"), rc_context(STYLE):
        figure = _new_figure(6.0, 4.0)
        axes = figure.subplots()
        _curves(axes, means, "eta", series)
        for index, level in enumerate(levels):
            row = chosen[chosen["num_features"] == level]
            axes.plot(
                row["eta"],
                row["mean"],
                marker="*",
                markersize=16,
                color=f"C{index}",
                markeredgecolor="black",
                linestyle="none",
            )
        axes.set_xlabel("η (trade-off between reward and feature matching)")
        axes.set_ylabel("mean best-response regret (95% CI)")
        axes.set_title("Cross-validation of η (star: chosen)")
        axes.legend(frameon=False)
        return render_png(figure)


def robot_difference_curve(sweep: pd.DataFrame, reference: str, other: str) -> bytes:
    """Mean paired regret difference ``other - reference`` against lambda, per feature level.

    One panel per feature level, one line per policy (the policy's colour; the policies
    are dodged sideways so their intervals do not hide each other); bars are 95% CIs of
    the mean difference; below the zero line the other robot did better.

    Args:
        sweep: rows ``measure, rationality, num_features, policy, mean_diff, ci95_low,
            ci95_high`` (:func:`cirl_study.analysis.statistics.paired_differences`).
        reference: the reference robot's name.
        other: the other robot's name.
    """
    regret = sweep[sweep["measure"] == "regret"].rename(columns={"mean_diff": "mean"})
    levels = sorted(regret["num_features"].unique())
    dodge = {policy: 1.08 ** (index - 0.5) for index, policy in enumerate(PAPER_POLICIES)}
    with matplotlib.style.context("default"), rc_context(STYLE):
        figure = _new_figure(4.0 * len(levels), 3.6)
        panels = np.atleast_1d(figure.subplots(1, len(levels), sharey=True))
        for axes, level in zip(panels, levels, strict=True):
            axes.axhline(0.0, color="black", linewidth=0.8)
            series = []
            for index, policy in enumerate(PAPER_POLICIES):
                rows = regret[(regret["num_features"] == level) & (regret["policy"] == policy)]
                rows = rows.assign(rationality=rows["rationality"] * dodge[policy])
                style = {
                    "color": POLICY_COLOURS[policy],
                    "marker": LEVEL_MARKERS[index % len(LEVEL_MARKERS)],
                }
                series.append((POLICY_LABELS[policy], rows, style))
            _curves(axes, regret, "rationality", series)
            axes.set_title(f"{level} features")
            axes.set_xlabel("robot's rationality λ")
        panels[0].set_ylabel(f"regret, {other} minus {reference} (95% CI)")
        panels[0].legend(frameon=False, fontsize=8, title="human")
        figure.suptitle(f"Below zero: {other} did better than {reference}")
        return render_png(figure)
