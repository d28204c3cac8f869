"""A QD run at a glance: descriptors of any dimension in parallel axes, and the one-figure summary
(QD score, coverage and max fitness along the run's cost, beside the final repertoire)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, overload

import numpy as np
from matplotlib.axes import Axes
from matplotlib.cm import ScalarMappable
from matplotlib.collections import LineCollection
from matplotlib.figure import FigureBase

from qdrl.plotting._common import FigT, _draw, _names, _one_panel, _panels, _points, _tidy_x
from qdrl.plotting.repertoires import _colour_scale, _draw_repertoire
from qdrl.plotting.sources import elites_of

__all__ = ["plot_parallel_axes", "plot_qd_summary"]

SUMMARY_METRICS = ("qd_score", "coverage", "max_fitness")


def _draw_parallel(
    ax: Axes, elites: Any, low: Any, high: Any, labels: Sequence[str] | None, norm: Any, colours: Any,
    max_lines: int,
) -> None:
    fitnesses = np.asarray(elites.fitnesses, dtype=np.float64)
    descriptors = np.asarray(elites.descriptors, dtype=np.float64)
    d = descriptors.shape[1]
    lo = np.broadcast_to(np.asarray(low, np.float64), (d,))
    hi = np.broadcast_to(np.asarray(high, np.float64), (d,))
    filled = np.flatnonzero(fitnesses > -np.inf)
    order = filled[np.argsort(fitnesses[filled], kind="stable")][-max_lines:]  # the fittest, drawn last
    scaled = (descriptors[order] - lo) / np.where(hi > lo, hi - lo, 1.0)
    xs = np.arange(d, dtype=np.float64)
    lines = LineCollection(
        [np.stack([xs, row], axis=1) for row in scaled], cmap=colours, norm=norm, linewidths=0.8, alpha=0.7
    )
    lines.set_array(fitnesses[order])
    ax.add_collection(lines)
    for x in xs:
        ax.axvline(x, color="0.5", linewidth=0.6)
    ax.set_xlim(-0.05, max(d - 1, 1) + 0.05)
    ax.set_ylim(-0.02, 1.02)
    ax.set_xticks(xs, _names(labels, d), rotation=30 if d > 4 else 0, ha="right" if d > 4 else "center")
    ax.set_yticks([0.0, 1.0], ["low", "high"])
    if not len(order):
        ax.text(0.5, 0.5, "empty repertoire", ha="center", va="center", transform=ax.transAxes)


@overload
def plot_parallel_axes(
    source: Any, path: str | Path, low: Any = ..., high: Any = ..., labels: Sequence[str] | None = ...,
    title: str = ..., cmap: str = ..., max_lines: int = ..., *, ax: None = None,
) -> Path: ...
@overload
def plot_parallel_axes(
    source: Any, path: str | Path | None = ..., low: Any = ..., high: Any = ..., labels: Sequence[str] | None = ...,
    title: str = ..., cmap: str = ..., max_lines: int = ..., *, ax: Axes,
) -> Axes: ...
@overload
def plot_parallel_axes(
    source: Any, path: None = ..., low: Any = ..., high: Any = ..., labels: Sequence[str] | None = ...,
    title: str = ..., cmap: str = ..., max_lines: int = ..., *, ax: None = None,
) -> Axes: ...
def plot_parallel_axes(
    source: Any,
    path: str | Path | None = None,
    low: Any = None,
    high: Any = None,
    labels: Sequence[str] | None = None,
    title: str = "",
    cmap: str = "viridis",
    max_lines: int = 2000,
    *,
    ax: Axes | None = None,
) -> Path | Axes:
    """Every elite as a line across one vertical axis per descriptor dimension (each scaled from
    its `low` to its `high`), coloured by fitness: descriptors of any dimension on one panel.

    Args:
      source: a repertoire, a loaded run or a DataFrame of elites (as `plot_repertoire`).
      path: PNG to write, or None.
      low, high: descriptor bounds (default: the source's, as `plot_repertoire`).
      labels: the dimensions' names (default: the source's, else "descriptor i").
      title: the title (the figure's; with `ax`, the panel's).
      cmap: matplotlib colormap name.
      max_lines: at most this many elites are drawn, the fittest.
      ax: an Axes to draw on.

    Returns:
      `ax` when given, else `path` when given, else the Axes of a new figure.
    """
    elites, low, high, labels = elites_of(source, low, high, labels)
    norm, colours = _colour_scale([elites], None, None, cmap)

    def draw(panel: Axes) -> None:
        _draw_parallel(panel, elites, low, high, labels, norm, colours, max_lines)
        panel.figure.colorbar(ScalarMappable(norm=norm, cmap=colours), ax=panel, label="fitness")

    width = 2.0 + 1.2 * max(np.shape(elites.descriptors)[1], 2)
    return _one_panel(draw, path, ax, title, size=(width, 4.4))


def _rows_of(metrics: Any) -> list[Mapping[str, Any]]:
    if hasattr(metrics, "to_dict"):  # a DataFrame (`run.metrics`)
        return list(metrics.to_dict("records"))
    return list(metrics)


def _cost_key(rows: Sequence[Mapping[str, Any]]) -> str:
    """The x axis: evaluations when the run counts them, else env steps, else iterations."""
    for key in ("evaluations", "env_steps", "iteration"):
        if any(float(r.get(key) or 0) > 0 for r in rows):
            return key
    return "log_point"


@overload
def plot_qd_summary(
    metrics: Any, repertoire: Any = ..., path: str | Path = ..., low: Any = ..., high: Any = ...,
    labels: Sequence[str] | None = ..., title: str = ..., *, fig: None = None,
) -> Path: ...
@overload
def plot_qd_summary(
    metrics: Any, repertoire: Any = ..., path: str | Path | None = ..., low: Any = ..., high: Any = ...,
    labels: Sequence[str] | None = ..., title: str = ..., *, fig: FigT,
) -> FigT: ...
def plot_qd_summary(
    metrics: Any,
    repertoire: Any = None,
    path: str | Path | None = None,
    low: Any = None,
    high: Any = None,
    labels: Sequence[str] | None = None,
    title: str = "",
    *,
    fig: FigureBase | None = None,
) -> Path | FigureBase:
    """A QD run in one figure: QD score, coverage and max fitness along the run's cost
    (evaluations, else env steps), and the final repertoire (a heatmap for descriptors of one or
    two dimensions, parallel axes beyond).

    Args:
      metrics: a loaded run (`qdrl.load_run`: its metrics and repertoire), or its metrics
        (a DataFrame like `run.metrics`, or rows as dicts) with `repertoire` given.
      repertoire: the repertoire, a loaded run or a DataFrame of elites; default the run's.
      path: PNG to write, or None.
      low, high, labels: descriptor bounds and names (default: the source's).
      title: the figure title.
      fig: an empty Figure or SubFigure to draw the four panels in.

    Returns:
      `fig` when given, else `path` when given, else a new Figure.
    """
    run = metrics if hasattr(metrics, "metrics") and hasattr(metrics, "repertoire") else None
    rows = _rows_of(run.metrics if run is not None else metrics)
    source = repertoire if repertoire is not None else run
    if source is None:
        raise ValueError("plot_qd_summary: expected a loaded run, or metrics with a repertoire")
    if not title and run is not None:
        title = f"{getattr(run, 'algorithm', '')} on {getattr(run, 'task_name', '')}"
    elites, low, high, labels = elites_of(source, low, high, labels)
    x_key = _cost_key(rows)
    shown = [k for k in SUMMARY_METRICS if any(k in r for r in rows)]

    def draw(figure: FigureBase) -> None:
        axes = figure.subplots(1, len(shown) + 1, squeeze=False, width_ratios=[1.0] * len(shown) + [1.3])[0]
        for panel, key in zip(axes, shown, strict=False):
            _draw(panel, *_points(rows, x_key, key))
            panel.set_xlabel(x_key.replace("_", " "))
            panel.set_title(key.replace("_", " "), fontsize=10)
            _tidy_x(panel)
        panel = axes[-1]
        norm, colours = _colour_scale([elites], None, None, "viridis")
        if np.shape(elites.descriptors)[1] <= 2:
            _draw_repertoire(panel, elites, low, high, (0, 1), norm, colours, labels)
        else:
            _draw_parallel(panel, elites, low, high, labels, norm, colours, 2000)
        panel.set_title("final repertoire", fontsize=10)
        figure.colorbar(ScalarMappable(norm=norm, cmap=colours), ax=panel, label="fitness")

    return _panels(draw, path, fig, title, (4.2 * len(shown) + 5.6, 4.0))
