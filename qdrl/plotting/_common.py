"""Helpers shared by the plotting modules: figures, saving, tick labels, numeric cells."""

from __future__ import annotations

import contextlib
import math
import numbers
import re
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure, FigureBase
from matplotlib.ticker import FuncFormatter, MaxNLocator

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
# The columns a run's metrics are drawn against, in this order when present.
X_KEYS = ("evaluations", "env_steps", "wall_s")
# Below this many points each point gets a marker, so a single point is visible.
_MARKER_BELOW = 30

Rows = Sequence[Mapping[str, Any]]
# A Figure or a SubFigure given by the caller, returned as it was given.
FigT = TypeVar("FigT", bound=FigureBase)


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


def _points(rows: Rows, x_key: str, y_key: str) -> tuple[list[float], list[float]]:
    """The (x, y) pairs of the rows where both values are finite numbers, in row order."""
    xs, ys = [], []
    for row in rows:
        x, y = _as_float(row.get(x_key)), _as_float(row.get(y_key))
        if x is not None and y is not None:
            xs.append(x)
            ys.append(y)
    return xs, ys


def _has_key(rows: Rows, key: str) -> bool:
    return any(key in row for row in rows)


def _file_stem(key: str) -> str:
    # Metric names such as "eval/return" must not create subdirectories.
    return re.sub(r"[^A-Za-z0-9._-]+", "_", key).strip("_") or "metric"


def _draw(ax: Axes, xs: list[float], ys: list[float], label: str | None = None) -> None:
    marker = "o" if len(xs) < _MARKER_BELOW else None
    ax.plot(xs, ys, marker=marker, markersize=3, linewidth=1.5, label=label)


def _compact(value: float, _pos: int | None = None) -> str:
    """A tick label of at most a few characters: 150000 -> 150k, 2500000 -> 2.5M."""
    size = abs(value)
    for scale, suffix in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if size >= scale:
            return f"{value / scale:.3g}{suffix}"
    return f"{value:.3g}"


def _tidy_x(ax: Axes) -> None:
    """At most 6 x ticks with compact labels, so labels of large counts never overlap."""

    ax.xaxis.set_major_locator(MaxNLocator(nbins=5, min_n_ticks=2))
    ax.xaxis.set_major_formatter(FuncFormatter(_compact))


@contextlib.contextmanager
def _nan_quiet() -> Iterator[None]:
    """Silences numpy's "mean of empty slice" warnings (the result is NaN, as wanted)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        yield


def _names(labels: Sequence[str] | None, num_dims: int) -> list[str]:
    if not labels:
        return [f"descriptor {i}" for i in range(num_dims)]
    if len(labels) != num_dims:
        raise ValueError(f"labels: expected {num_dims} names (one per descriptor), got {list(labels)}")
    return list(labels)


# --- figures -------------------------------------------------------------------------
#
# Figures are built with matplotlib's object API on the Agg canvas, never through
# `pyplot`: no display is needed, the caller's backend is left alone and no figure is
# registered globally. A caller's own Axes or Figure (e.g. from `plt.subplots` in a
# notebook) is drawn on as it is.


def _figure(width: float, height: float) -> Figure:
    """An empty constrained-layout Figure on the Agg canvas, unknown to pyplot."""
    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _new_figure(ncols: int) -> Figure:
    """The figure of `ncols` learning-curve panels side by side."""
    return _figure(5.0 * ncols, 3.6)


def _save(fig: Figure, path: str | Path, title: str = "") -> Path:
    """Titles `fig` (when `title`) and writes it as a PNG at `path`, creating its directory."""
    if title:
        fig.suptitle(title)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    return out


def _one_panel(
    draw: Callable[[Axes], None],
    path: str | Path | None,
    ax: Axes | None,
    title: str,
    size: tuple[float, float] = (6.0, 5.0),
    projection: str | None = None,
) -> Path | Axes:
    """Runs `draw` for a single-panel plot and returns by the package's rule.

    Args:
      draw: draws the panel on the Axes it is given.
      path: PNG to write from a figure of its own (`size`, titled `title`), or None.
      ax: the caller's Axes to draw on too (titled `title`), or None.
      title: the title.
      size: the written figure's size in inches.
      projection: the written figure's projection, e.g. "3d".

    Returns:
      `ax` when given, else the written path, else the Axes of a new figure.
    """
    if ax is not None:
        if path is not None:
            _one_panel(draw, path, None, title, size, projection)
        draw(ax)
        if title:
            ax.set_title(title)
        return ax
    fig = _figure(*size)
    panel: Axes = fig.add_subplot(projection=projection) if projection else fig.subplots()
    draw(panel)
    if path is None:
        if title:
            fig.suptitle(title)
        return panel
    return _save(fig, path, title)


def _panels(
    draw: Callable[[FigureBase], None],
    path: str | Path | None,
    fig: FigureBase | None,
    title: str,
    size: tuple[float, float],
) -> Path | FigureBase:
    """Runs `draw` for a multi-panel plot and returns by the package's rule.

    Args:
      draw: lays out and draws the panels in the (empty) figure it is given.
      path: PNG to write from a figure of its own (`size`), or None.
      fig: the caller's Figure or SubFigure to draw in too, or None.
      title: the figure title.
      size: the written figure's size in inches.

    Returns:
      `fig` when given, else the written path, else a new Figure.
    """
    if fig is not None:
        if path is not None:
            _panels(draw, path, None, title, size)
        draw(fig)
        if title:
            fig.suptitle(title)
        return fig
    new = _figure(*size)
    draw(new)
    if path is None:
        if title:
            new.suptitle(title)
        return new
    return _save(new, path, title)
