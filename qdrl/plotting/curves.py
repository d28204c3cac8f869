"""Learning curves: one run's metrics, or several runs (and their seeds) compared."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, overload

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure, FigureBase

from qdrl.plotting._common import (
    _AXIS_LABELS,
    _MARKER_BELOW,
    COUNTER_KEYS,
    X_KEYS,
    FigT,
    Rows,
    _as_float,
    _draw,
    _figure,
    _file_stem,
    _has_key,
    _nan_quiet,
    _new_figure,
    _panels,
    _points,
    _tidy_x,
)
from qdrl.stats import bootstrap_ci

__all__ = ["default_x_keys", "default_y_keys", "plot_comparison", "plot_curves"]


def default_x_keys(rows: Rows) -> list[str]:
    """The columns of `X_KEYS` that the rows hold with a non-zero value somewhere.

    Args:
      rows: metric rows of one run.

    Returns:
      Those columns in `X_KEYS` order, or `["wall_s"]` when there is none. A task that
      steps no environment counts no env steps, so its curves use evaluations and
      wall time only.
    """
    keys = []
    for key in X_KEYS:
        values = [_as_float(row.get(key)) for row in rows]
        if any(v is not None and v != 0.0 for v in values):
            keys.append(key)
    return keys or ["wall_s"]


def default_y_keys(rows: Rows, x_keys: Sequence[str] = ()) -> list[str]:
    """The numeric columns of `rows` in first-seen order, minus x keys and counters.

    Args:
      rows: metric rows of one run.
      x_keys: columns to leave out besides `COUNTER_KEYS`.

    Returns:
      The metric names.
    """
    keys: dict[str, None] = {}
    for row in rows:
        for key, value in row.items():
            if key in keys or key in COUNTER_KEYS or key in x_keys:
                continue
            if _as_float(value) is not None:
                keys[key] = None
    return list(keys)


def _draw_curve(ax: Axes, rows: Rows, x_key: str, y_key: str) -> None:
    """One panel of `plot_curves`: `y_key` against `x_key`, or "no data"."""
    xs, ys = _points(rows, x_key, y_key)
    if xs:
        _draw(ax, xs, ys)
    else:
        ax.text(0.5, 0.5, "no data", ha="center", va="center", transform=ax.transAxes)
    ax.set_xlabel(_AXIS_LABELS.get(x_key, x_key))
    ax.set_ylabel(y_key)
    ax.grid(True, alpha=0.3)
    _tidy_x(ax)


@overload
def plot_curves(
    rows: Rows,
    out_dir: str | Path,
    x_keys: Sequence[str] = ...,
    y_keys: Sequence[str] | None = ...,
    title: str = ...,
    *,
    fig: None = None,
) -> list[Path]: ...
@overload
def plot_curves(
    rows: Rows,
    out_dir: str | Path | None = ...,
    x_keys: Sequence[str] = ...,
    y_keys: Sequence[str] | None = ...,
    title: str = ...,
    *,
    fig: FigT,
) -> FigT: ...
@overload
def plot_curves(
    rows: Rows,
    out_dir: None = None,
    x_keys: Sequence[str] = ...,
    y_keys: Sequence[str] | None = ...,
    title: str = ...,
    *,
    fig: None = None,
) -> Figure: ...
def plot_curves(
    rows: Rows,
    out_dir: str | Path | None = None,
    x_keys: Sequence[str] = ("env_steps", "wall_s"),
    y_keys: Sequence[str] | None = None,
    title: str = "",
    *,
    fig: FigureBase | None = None,
) -> list[Path] | FigureBase:
    """Plots each metric of one run against each x key.

    Args:
      rows: metric rows of one run, e.g. `{"env_steps": 1e4, "wall_s": 12.5,
        "eval_return": 310.0}`; missing, None, NaN or infinite values are skipped.
      out_dir: directory for one PNG per metric, `out_dir/{y}.png` (one panel per x
        key; characters other than letters, digits, `.`, `_`, `-` become `_`), or None.
      x_keys: the x columns.
      y_keys: the metrics; default every numeric column but the x keys and `COUNTER_KEYS`.
      title: prefixed to each file's metric name; the title of `fig`.
      fig: an empty Figure or SubFigure to draw in: one row of panels per metric,
        one column per x key.

    Returns:
      `fig` when given, else the paths written in `y_keys` order when `out_dir` is
      given, else a new Figure laid out as `fig` would be.

    Raises:
      ValueError: if an x key or a requested y key appears in no row.
    """
    if not x_keys:
        raise ValueError("x_keys is empty; give at least one x column")
    for x_key in x_keys:
        if not _has_key(rows, x_key):
            raise ValueError(f"x key {x_key!r} appears in no row")
    if y_keys is None:
        y_keys = default_y_keys(rows, x_keys)
    else:
        unknown = [y for y in y_keys if not _has_key(rows, y)]
        if unknown:
            raise ValueError(f"y keys {unknown} appear in no row")

    paths = []
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        for y_key in y_keys:
            page = _new_figure(len(x_keys))
            axes = page.subplots(1, len(x_keys), squeeze=False)[0]
            for ax, x_key in zip(axes, x_keys, strict=True):
                _draw_curve(ax, rows, x_key, y_key)
            page.suptitle(f"{title}: {y_key}" if title else y_key)
            path = out / f"{_file_stem(y_key)}.png"
            page.savefig(path, dpi=100)
            paths.append(path)
        if fig is None:
            return paths

    target = fig if fig is not None else _figure(5.0 * len(x_keys), 3.6 * max(1, len(y_keys)))
    if y_keys:
        grid = target.subplots(len(y_keys), len(x_keys), squeeze=False)
        for row_axes, y_key in zip(grid, y_keys, strict=True):
            for ax, x_key in zip(row_axes, x_keys, strict=True):
                _draw_curve(ax, rows, x_key, y_key)
    if title:
        target.suptitle(title)
    return target


def _is_rows(value: Any) -> bool:
    return not value or isinstance(value[0], Mapping)


def _seed_curves(runs: Sequence[Rows], x_key: str, y_key: str) -> tuple[np.ndarray, np.ndarray]:
    """x (T,) and y (n, T) of n seeds aligned by log point; x is the seeds' mean x.

    Seeds of one spec log at the same points (the same evaluations or env steps;
    wall time differs), so log point t of every seed is one point of the curve.
    Missing values (a shorter, interrupted seed) are NaN and left out of the mean.
    """
    length = max((len(rows) for rows in runs), default=0)
    xs = np.full((len(runs), length), np.nan)
    ys = np.full((len(runs), length), np.nan)
    for i, rows in enumerate(runs):
        for t, row in enumerate(rows):
            x, y = _as_float(row.get(x_key)), _as_float(row.get(y_key))
            if x is not None and y is not None:
                xs[i, t], ys[i, t] = x, y
    keep = ~np.all(np.isnan(xs), axis=0)
    with _nan_quiet():
        return np.nanmean(xs[:, keep], axis=0), ys[:, keep]


def _draw_comparison(
    ax: Axes, groups: Mapping[str, Sequence[Rows]], x_key: str, y_key: str, confidence: float
) -> None:
    """One panel of `plot_comparison`: a mean line (and a band for several seeds) per name."""

    for index, (name, seeds) in enumerate(groups.items()):
        colour = f"C{index % 10}"
        xs, ys = _seed_curves(seeds, x_key, y_key)
        shown = np.sum(~np.isnan(ys), axis=0) > 0
        if not np.any(shown):
            # A run without data still gets its legend entry, so its absence is visible.
            ax.plot([], [], color=colour, label=f"{name} (no data)")
            continue
        with _nan_quiet():
            mean = np.nanmean(ys, axis=0)
        label = name if len(seeds) == 1 else f"{name} ({len(seeds)} seeds)"
        marker = "o" if int(shown.sum()) < _MARKER_BELOW else None
        ax.plot(xs[shown], mean[shown], color=colour, marker=marker, markersize=3, linewidth=1.5, label=label)
        if len(seeds) > 1:
            low, high = bootstrap_ci(ys[:, shown], confidence=confidence)
            ax.fill_between(xs[shown], low, high, color=colour, alpha=0.2, linewidth=0)
    ax.set_xlabel(_AXIS_LABELS.get(x_key, x_key))
    ax.set_ylabel(y_key)
    ax.grid(True, alpha=0.3)
    _tidy_x(ax)


@overload
def plot_comparison(
    runs: Mapping[str, Rows | Sequence[Rows]],
    y_key: str,
    x_key: str | Sequence[str],
    path: str | Path,
    title: str = ...,
    confidence: float = ...,
    *,
    ax: None = None,
    fig: None = None,
) -> Path: ...
@overload
def plot_comparison(
    runs: Mapping[str, Rows | Sequence[Rows]],
    y_key: str,
    x_key: str | Sequence[str],
    path: str | Path | None = ...,
    title: str = ...,
    confidence: float = ...,
    *,
    ax: Axes,
    fig: None = None,
) -> Axes: ...
@overload
def plot_comparison(
    runs: Mapping[str, Rows | Sequence[Rows]],
    y_key: str,
    x_key: str | Sequence[str],
    path: str | Path | None = ...,
    title: str = ...,
    confidence: float = ...,
    *,
    ax: None = None,
    fig: FigT,
) -> FigT: ...
@overload
def plot_comparison(
    runs: Mapping[str, Rows | Sequence[Rows]],
    y_key: str,
    x_key: str | Sequence[str],
    path: None = None,
    title: str = ...,
    confidence: float = ...,
    *,
    ax: None = None,
    fig: None = None,
) -> Figure: ...
def plot_comparison(
    runs: Mapping[str, Rows | Sequence[Rows]],
    y_key: str,
    x_key: str | Sequence[str],
    path: str | Path | None = None,
    title: str = "",
    confidence: float = 0.95,
    *,
    ax: Axes | None = None,
    fig: FigureBase | None = None,
) -> Path | Axes | FigureBase:
    """Plots several runs' `y_key` against `x_key`, one colour per name.

    A name maps to one run's rows (a line) or to several seeds' rows: then the line
    is their mean at each log point and a band its `confidence` percentile bootstrap
    interval over the seeds (`qdrl.stats`).

    Args:
      runs: name -> that run's metric rows, or a list of row lists, one per seed.
      y_key: the metric; must appear in at least one run.
      x_key: the x column, or several (one panel each, side by side); each must
        appear in at least one run.
      path: PNG to write (its directory is created), or None.
      title: the figure title (default `y_key`); with `ax`, its title when given.
      confidence: the band's confidence level.
      ax: an Axes to draw on (one x key only).
      fig: an empty Figure or SubFigure to draw the panels in.

    Returns:
      `ax` or `fig` when given, else `path` when given, else a new Figure.

    Raises:
      ValueError: if `runs` is empty, a key appears in no run, both `ax` and `fig`
        are given, or `ax` with several x keys.
    """
    if not runs:
        raise ValueError("runs is empty; nothing to compare")
    groups: dict[str, list[Rows]] = {
        name: [value] if _is_rows(value) else list(value)  # type: ignore[list-item, arg-type]
        for name, value in runs.items()
    }
    x_keys = [x_key] if isinstance(x_key, str) else list(x_key)
    for role, key in (("y_key", y_key), *(("x_key", x) for x in x_keys)):
        if not any(_has_key(rows, key) for seeds in groups.values() for rows in seeds):
            raise ValueError(f"{role} {key!r} appears in no row of runs {sorted(runs)}")
    if ax is not None and fig is not None:
        raise ValueError("give ax or fig, not both")
    if ax is not None and len(x_keys) != 1:
        raise ValueError(f"ax takes one panel; pass fig for the {len(x_keys)} x keys {x_keys}")

    def draw(figure: FigureBase) -> None:
        axes = figure.subplots(1, len(x_keys), squeeze=False)[0]
        for panel, x in zip(axes, x_keys, strict=True):
            _draw_comparison(panel, groups, x, y_key, confidence)
        axes[0].legend(fontsize=8)

    size = (5.0 * len(x_keys), 3.6)  # `_new_figure(len(x_keys))`
    if ax is None:
        return _panels(draw, path, fig, title or y_key, size)
    if path is not None:
        _panels(draw, path, None, title or y_key, size)
    _draw_comparison(ax, groups, x_keys[0], y_key, confidence)
    ax.legend(fontsize=8)
    if title:
        ax.set_title(title)
    return ax
