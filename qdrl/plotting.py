"""Learning-curve plots (PNG) from a run's metric rows, one run or several compared.

Figures are built with matplotlib's object API (`matplotlib.figure.Figure`)
rendered by the Agg canvas, never through `pyplot`: no display is needed, the
caller's backend (e.g. a notebook's inline one) is left alone, and no figure
is registered globally, so nothing accumulates across calls.
"""

from __future__ import annotations

import math
import numbers
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

__all__ = ["COUNTER_KEYS", "default_y_keys", "plot_comparison", "plot_curves"]

# Columns that count progress rather than measure it; never plotted as y by default.
COUNTER_KEYS = frozenset(
    {
        "iteration",
        "iterations",
        "step",
        "steps",
        "epoch",
        "chunk",
        "log_point",
        "env_steps",
        "grad_steps",
        "evaluations",
        "num_evaluations",
        "wall_s",
        "time",
        "timestamp",
    }
)
_AXIS_LABELS = {
    "env_steps": "environment steps",
    "wall_s": "wall time (s)",
    "evaluations": "evaluations",
}
# Below this many points each point gets a marker, so a single point is visible.
_MARKER_BELOW = 30


def _as_float(value: Any) -> float | None:
    """The value as a finite float, or None when it is missing, non-numeric or not finite."""
    if value is None or isinstance(value, bool | np.bool_):
        return None
    if isinstance(value, numbers.Real):
        out = float(value)
    elif hasattr(value, "shape") and tuple(value.shape) == () and hasattr(value, "dtype"):
        # 0-d numpy / jax arrays, as metrics often come straight from a jitted step.
        if not np.issubdtype(np.dtype(value.dtype), np.number):
            return None
        out = float(value)
    else:
        return None
    return out if math.isfinite(out) else None


def _points(
    rows: Sequence[Mapping[str, Any]], x_key: str, y_key: str
) -> tuple[list[float], list[float]]:
    """The (x, y) pairs of the rows where both values are finite numbers, in row order."""
    xs, ys = [], []
    for row in rows:
        x, y = _as_float(row.get(x_key)), _as_float(row.get(y_key))
        if x is not None and y is not None:
            xs.append(x)
            ys.append(y)
    return xs, ys


def _has_key(rows: Sequence[Mapping[str, Any]], key: str) -> bool:
    return any(key in row for row in rows)


def _file_stem(key: str) -> str:
    # Metric names such as "eval/return" must not create subdirectories.
    return re.sub(r"[^A-Za-z0-9._-]+", "_", key).strip("_") or "metric"


def _draw(ax: Axes, xs: list[float], ys: list[float], label: str | None = None) -> None:
    marker = "o" if len(xs) < _MARKER_BELOW else None
    ax.plot(xs, ys, marker=marker, markersize=3, linewidth=1.5, label=label)


def _new_figure(ncols: int) -> Figure:
    fig = Figure(figsize=(5.0 * ncols, 3.6), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def default_y_keys(rows: Sequence[Mapping[str, Any]], x_keys: Sequence[str] = ()) -> list[str]:
    """Numeric columns of `rows` in first-seen order, minus x keys and counters."""
    keys: dict[str, None] = {}
    for row in rows:
        for key, value in row.items():
            if key in keys or key in COUNTER_KEYS or key in x_keys:
                continue
            if _as_float(value) is not None:
                keys[key] = None
    return list(keys)


def plot_curves(
    rows: Sequence[Mapping[str, Any]],
    out_dir: str | Path,
    x_keys: Sequence[str] = ("env_steps", "wall_s"),
    y_keys: Sequence[str] | None = None,
    title: str = "",
) -> list[Path]:
    """Writes one PNG per metric, `out_dir/{y}.png`, with one panel per x key.

    Args:
      rows: metric rows of one run, e.g. `{"env_steps": 1e4, "wall_s": 12.5,
        "eval_return": 310.0}`. Missing, None, NaN or infinite values are skipped
        point by point.
      out_dir: directory for the PNGs; created if needed.
      x_keys: columns used as x axes, one panel each.
      y_keys: metrics to plot; default every numeric column except the x keys
        and counters (`COUNTER_KEYS`, e.g. `iteration`).
      title: figure title, prefixed to each metric's name.

    Returns:
      The paths written, in `y_keys` order. Characters other than letters,
      digits, `.`, `_`, `-` in a metric name become `_` in its file name.

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
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)

    paths = []
    for y_key in y_keys:
        fig = _new_figure(len(x_keys))
        axes = fig.subplots(1, len(x_keys), squeeze=False)[0]
        for ax, x_key in zip(axes, x_keys, strict=True):
            xs, ys = _points(rows, x_key, y_key)
            if xs:
                _draw(ax, xs, ys)
            else:
                ax.text(0.5, 0.5, "no data", ha="center", va="center", transform=ax.transAxes)
            ax.set_xlabel(_AXIS_LABELS.get(x_key, x_key))
            ax.set_ylabel(y_key)
            ax.grid(True, alpha=0.3)
        fig.suptitle(f"{title}: {y_key}" if title else y_key)
        path = out / f"{_file_stem(y_key)}.png"
        fig.savefig(path, dpi=100)
        paths.append(path)
    return paths


def plot_comparison(
    runs: Mapping[str, Sequence[Mapping[str, Any]]],
    y_key: str,
    x_key: str,
    path: str | Path,
    title: str = "",
) -> Path:
    """Writes one PNG with every run's `y_key` against `x_key`, labelled by run name.

    Args:
      runs: run name (e.g. the algorithm) -> that run's metric rows.
      y_key: metric to compare; must appear in at least one run.
      x_key: x column, e.g. `env_steps` or `wall_s`; must appear in at least one run.
      path: PNG to write; its parent directory is created if needed.
      title: figure title; defaults to `y_key`.

    Returns:
      `path`.

    Raises:
      ValueError: if `runs` is empty or a key appears in no run.
    """
    if not runs:
        raise ValueError("runs is empty; nothing to compare")
    for role, key in (("y_key", y_key), ("x_key", x_key)):
        if not any(_has_key(rows, key) for rows in runs.values()):
            raise ValueError(f"{role} {key!r} appears in no row of runs {sorted(runs)}")
    fig = _new_figure(1)
    ax = fig.subplots()
    for name, rows in runs.items():
        xs, ys = _points(rows, x_key, y_key)
        # A run without data still gets its legend entry, so its absence is visible.
        _draw(ax, xs, ys, label=name if xs else f"{name} (no data)")
    ax.set_xlabel(_AXIS_LABELS.get(x_key, x_key))
    ax.set_ylabel(y_key)
    ax.grid(True, alpha=0.3)
    ax.legend()
    fig.suptitle(title or y_key)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    return out
