"""A run at a glance: descriptors of any dimension in parallel axes, a QD run's one-figure summary
(QD score, coverage and max fitness along the run's cost, beside the final repertoire), and an
RL, PBT or skill-discovery run's (the evaluation return, the passive archive's QD score,
coverage and heatmap, and every other metric in small panels)."""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, overload

import numpy as np
from matplotlib.axes import Axes
from matplotlib.cm import ScalarMappable
from matplotlib.collections import LineCollection
from matplotlib.figure import FigureBase

from qdrl.plotting._common import (
    _AXIS_LABELS,
    FigT,
    _as_float,
    _draw,
    _names,
    _one_panel,
    _panels,
    _points,
    _tidy_x,
)
from qdrl.plotting.curves import default_y_keys
from qdrl.plotting.repertoires import _colour_scale, _draw_repertoire
from qdrl.plotting.sources import elites_of

__all__ = ["plot_parallel_axes", "plot_qd_summary", "plot_rl_summary"]

SUMMARY_METRICS = ("qd_score", "coverage", "max_fitness")
# plot_rl_summary: the passive archive's curves after the return; PBT's population statistics
# beside the best member's return, its members' returns (`eval_return_m<i>`) on one panel.
ARCHIVE_METRICS = ("qd_score", "coverage")
RETURN_STATISTICS = ("eval_return_median", "eval_return_mean")
_MEMBER_RETURN = re.compile(r"eval_return_m\d+")
_SUMMARY_COLUMNS = 5  # small panels a row; the return spans two columns and two rows


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


def _summary_source(metrics: Any, elites: Any, title: str) -> tuple[list[Any], Any, str]:
    """(the metric rows, where the elites come from, the title) of a one-figure summary:
    `metrics` a loaded run (its metrics; its elites unless `elites` is given; "<algorithm> on
    <task>" unless `title` is) or the metrics themselves (a DataFrame or rows)."""
    run = metrics if hasattr(metrics, "metrics") and hasattr(metrics, "repertoire") else None
    rows = _rows_of(run.metrics if run is not None else metrics)
    if not title and run is not None:
        title = f"{getattr(run, 'algorithm', '')} on {getattr(run, 'task_name', '')}"
    return rows, (elites if elites is not None else run), title


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
    rows, source, title = _summary_source(metrics, repertoire, title)
    if source is None:
        raise ValueError("plot_qd_summary: expected a loaded run, or metrics with a repertoire")
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


def _rl_panels(rows: Sequence[Mapping[str, Any]], x_key: str) -> list[tuple[str, list[str]]]:
    """The small panels, (title, columns drawn), in order: the archive's QD score and coverage,
    PBT's members' returns on one panel, the losses, then every other metric."""
    keys = [k for k in default_y_keys(rows, (x_key,)) if not k.endswith("env_steps")]
    members = [k for k in keys if _MEMBER_RETURN.fullmatch(k)]
    rest = [k for k in keys if k not in {"eval_return", "eval_return_std", *RETURN_STATISTICS, *members}]
    archive = [k for k in ARCHIVE_METRICS if k in rest]
    losses = [k for k in rest if "loss" in k and k not in archive]
    others = [k for k in rest if k not in archive and k not in losses]
    panels = [(k.replace("_", " "), [k]) for k in archive]
    if members:
        panels.append(("members' eval return", members))
    return panels + [(k.replace("_", " "), [k]) for k in losses + others]


def _draw_return(ax: Axes, rows: Sequence[Mapping[str, Any]], x_key: str) -> None:
    """The evaluation return, a band of one standard deviation over its episodes (when the rows
    hold `eval_return_std`) and PBT's population median and mean."""
    xs, ys = _points(rows, x_key, "eval_return")
    if not xs:
        ax.text(0.5, 0.5, "no data", ha="center", va="center", transform=ax.transAxes)
    population = any(key in row for row in rows for key in RETURN_STATISTICS)
    _draw(ax, xs, ys, label="best member" if population else "eval return")
    band = [
        point for point in ([_as_float(row.get(k)) for k in (x_key, "eval_return", "eval_return_std")] for row in rows)
        if None not in point
    ]
    if band:
        bx, by, bs = (np.asarray(v, dtype=np.float64) for v in zip(*band, strict=True))
        ax.fill_between(bx, by - bs, by + bs, color="C0", alpha=0.2, linewidth=0, label="± std over episodes")
    for i, key in enumerate(RETURN_STATISTICS):
        sx, sy = _points(rows, x_key, key)
        if sx:
            label = f"population {key.removeprefix('eval_return_')}"
            ax.plot(sx, sy, color=f"C{i + 1}", linestyle="--", linewidth=1.2, label=label)
    ax.set_xlabel(_AXIS_LABELS.get(x_key, x_key))
    ax.set_ylabel("return")
    ax.set_title("evaluation return", fontsize=11)
    ax.grid(True, alpha=0.3)
    if len(ax.get_legend_handles_labels()[0]) > 1:
        ax.legend(fontsize=8)
    _tidy_x(ax)


def _draw_small(ax: Axes, rows: Sequence[Mapping[str, Any]], x_key: str, keys: Sequence[str], title: str) -> None:
    """One small panel: `keys` along `x_key` (one line each, a legend beyond one)."""
    for key in keys:
        _draw(ax, *_points(rows, x_key, key), label=key.removeprefix("eval_return_"))
    if len(keys) > 1:
        ax.legend(fontsize=6, ncols=1 + (len(keys) - 1) // 4)
    ax.set_title(title, fontsize=9)
    ax.tick_params(labelsize=7)
    ax.grid(True, alpha=0.3)
    _tidy_x(ax)


@overload
def plot_rl_summary(
    metrics: Any, archive: Any = ..., path: str | Path = ..., low: Any = ..., high: Any = ...,
    labels: Sequence[str] | None = ..., title: str = ..., *, fig: None = None,
) -> Path: ...
@overload
def plot_rl_summary(
    metrics: Any, archive: Any = ..., path: str | Path | None = ..., low: Any = ..., high: Any = ...,
    labels: Sequence[str] | None = ..., title: str = ..., *, fig: FigT,
) -> FigT: ...
@overload
def plot_rl_summary(
    metrics: Any, archive: Any = ..., path: None = ..., low: Any = ..., high: Any = ...,
    labels: Sequence[str] | None = ..., title: str = ..., *, fig: None = None,
) -> FigureBase: ...
def plot_rl_summary(
    metrics: Any,
    archive: Any = None,
    path: str | Path | None = None,
    low: Any = None,
    high: Any = None,
    labels: Sequence[str] | None = None,
    title: str = "",
    *,
    fig: FigureBase | None = None,
) -> Path | FigureBase:
    """An RL, PBT or skill-discovery run in one figure, along its environment steps: the
    evaluation return (a band of one standard deviation over the episodes; PBT: the best
    member's, beside the population's median and mean) first and largest, then the passive
    archive's QD score and coverage, its heatmap (as `plots/archive.png`), the losses and every
    other metric column in small panels (PBT's members' returns on one).

    Args:
      metrics: a loaded run (`qdrl.load_run`: its metrics and passive archive), or its metrics
        (a DataFrame like `run.metrics`, or rows as dicts).
      archive: the passive archive, a loaded run or a DataFrame of elites; default the run's;
        none: no heatmap.
      path: PNG to write, or None.
      low, high, labels: descriptor bounds and names (default: the source's).
      title: the figure title (default, for a run: "<algorithm> on <task>").
      fig: an empty Figure or SubFigure to draw the panels in.

    Returns:
      `fig` when given, else `path` when given, else a new Figure.
    """
    rows, source, title = _summary_source(metrics, archive, title)
    elites = None
    if source is not None:
        elites, low, high, labels = elites_of(source, low, high, labels)
    x_key = _cost_key(rows)
    panels = _rl_panels(rows, x_key)
    c = _SUMMARY_COLUMNS
    # Slots beside the return: column 2 of its two rows, and columns 3-4 when no heatmap takes them.
    top = [(0, 2), (1, 2)] if elites is not None else [(0, 2), (1, 2), (0, 3), (0, 4), (1, 3), (1, 4)]
    below = max(0, len(panels) - len(top))
    nrows = 2 + math.ceil(below / c)
    slots = top + [(2 + i // c, i % c) for i in range(below)]

    def draw(figure: FigureBase) -> None:
        grid = figure.add_gridspec(nrows, c, height_ratios=[1.25, 1.25] + [1.0] * (nrows - 2))
        _draw_return(figure.add_subplot(grid[0:2, 0:2]), rows, x_key)
        for (name, keys), (r, col) in zip(panels, slots, strict=False):
            _draw_small(figure.add_subplot(grid[r, col]), rows, x_key, keys, name)
        if elites is not None:
            panel = figure.add_subplot(grid[0:2, 3:5])
            norm, colours = _colour_scale([elites], None, None, "viridis")
            _draw_repertoire(panel, elites, low, high, (0, 1), norm, colours, labels)
            panel.set_title("passive archive", fontsize=11)
            figure.colorbar(ScalarMappable(norm=norm, cmap=colours), ax=panel, label="episode return")
        if nrows > 2:
            figure.supxlabel(_AXIS_LABELS.get(x_key, x_key).replace("_", " "), fontsize=10)

    return _panels(draw, path, fig, title, (3.3 * c, 2.9 * 2 + 2.3 * (nrows - 2) + 0.6))
