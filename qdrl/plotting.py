"""Learning-curve plots (PNG) from a run's metric rows, one run or several compared,
and fitness heatmaps of QD repertoires.

Figures are built with matplotlib's object API (`matplotlib.figure.Figure`)
rendered by the Agg canvas, never through `pyplot`: no display is needed, the
caller's backend (e.g. a notebook's inline one) is left alone, and no figure
is registered globally, so nothing accumulates across calls.
"""

from __future__ import annotations

import contextlib
import math
import numbers
import re
import warnings
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

__all__ = [
    "COUNTER_KEYS",
    "X_KEYS",
    "Wall",
    "default_x_keys",
    "default_y_keys",
    "draw_walls",
    "env_walls",
    "plot_cell_fronts",
    "plot_cell_hypervolumes",
    "plot_comparison",
    "plot_curves",
    "plot_pareto_front",
    "plot_repertoire",
    "plot_repertoires",
    "plot_skills",
]

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


def _compact(value: float, _pos: int | None = None) -> str:
    """A tick label of at most a few characters: 150000 -> 150k, 2500000 -> 2.5M."""
    size = abs(value)
    for scale, suffix in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if size >= scale:
            return f"{value / scale:.3g}{suffix}"
    return f"{value:.3g}"


def _tidy_x(ax: Axes) -> None:
    """At most 6 x ticks with compact labels, so labels of large counts never overlap."""
    from matplotlib.ticker import FuncFormatter, MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(nbins=5, min_n_ticks=2))
    ax.xaxis.set_major_formatter(FuncFormatter(_compact))


def default_x_keys(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """The columns of `X_KEYS` that the rows hold with a non-zero value somewhere.

    A task that steps no environment (a function, the arm) counts no env steps: its
    QD curves are drawn against evaluations and wall time only.
    """
    keys = []
    for key in X_KEYS:
        values = [_as_float(row.get(key)) for row in rows]
        if any(v is not None and v != 0.0 for v in values):
            keys.append(key)
    return keys or ["wall_s"]


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
            _tidy_x(ax)
        fig.suptitle(f"{title}: {y_key}" if title else y_key)
        path = out / f"{_file_stem(y_key)}.png"
        fig.savefig(path, dpi=100)
        paths.append(path)
    return paths


Rows = Sequence[Mapping[str, Any]]


@contextlib.contextmanager
def _nan_quiet() -> Iterator[None]:
    """Silences numpy's "mean of empty slice" warnings (the result is NaN, as wanted)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        yield


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


def plot_comparison(
    runs: Mapping[str, Rows | Sequence[Rows]],
    y_key: str,
    x_key: str | Sequence[str],
    path: str | Path,
    title: str = "",
    confidence: float = 0.95,
) -> Path:
    """Writes one PNG comparing runs' `y_key` against `x_key`, one colour per name.

    A name maps to one run's rows (drawn as a line) or to several runs of it
    (seeds): then the line is their mean at each log point and a band its
    `confidence` percentile bootstrap interval over the seeds (`qdrl.stats`).

    Args:
      runs: name (e.g. the spec or algorithm) -> that run's metric rows, or a list
        of such row lists, one per seed.
      y_key: metric to compare; must appear in at least one run.
      x_key: x column, e.g. `evaluations`, `env_steps` or `wall_s`, or several (one
        panel each, side by side); each must appear in at least one run.
      path: PNG to write; its parent directory is created if needed.
      title: figure title; defaults to `y_key`.
      confidence: the band's confidence level.

    Returns:
      `path`.

    Raises:
      ValueError: if `runs` is empty or a key appears in no run.
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
    fig = _new_figure(len(x_keys))
    axes = fig.subplots(1, len(x_keys), squeeze=False)[0]
    for ax, x in zip(axes, x_keys, strict=True):
        _draw_comparison(ax, groups, x, y_key, confidence)
    axes[0].legend(fontsize=8)
    fig.suptitle(title or y_key)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    return out


def _draw_comparison(
    ax: Axes, groups: Mapping[str, Sequence[Rows]], x_key: str, y_key: str, confidence: float
) -> None:
    """One panel of `plot_comparison`: a mean line (and a band for several seeds) per name."""
    from qdrl.stats import bootstrap_ci

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


# --- repertoires -------------------------------------------------------------------

# Pixels per side of the raster that draws CVT cells (each pixel takes the colour
# of its nearest centroid), and at most this many bins per side for projections.
_CVT_RESOLUTION = 400
_MAX_PROJECTION_BINS = 64


def _repertoire_bounds(value: Any, dim: int, name: str) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full((dim,), float(arr))
    if arr.shape != (dim,):
        raise ValueError(f"{name} must be a scalar or have {dim} entries, got shape {arr.shape}")
    return arr


def _append_column(a: np.ndarray, value: float) -> np.ndarray:
    """`a` with one more entry `value` along its last axis."""
    return np.concatenate([a, np.full((*a.shape[:-1], 1), value)], axis=-1)


def _max_by_bin(
    points: np.ndarray, values: np.ndarray, lo: np.ndarray, hi: np.ndarray, bins: int
) -> np.ndarray:
    """(bins, bins) max of `values` per 2-D bin of `points` (N, 2) in the box; -inf where empty."""
    idx = np.floor((points - lo) / (hi - lo) * bins).astype(np.int64)
    idx = np.clip(idx, 0, bins - 1)
    out = np.full((bins, bins), -np.inf)
    np.maximum.at(out, (idx[:, 0], idx[:, 1]), values)
    return out


def _save(fig: Figure, path: str | Path, title: str = "") -> Path:
    """Titles `fig` (when `title`) and writes it as a PNG at `path`, creating its directory."""
    if title:
        fig.suptitle(title)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    return out


def _draw_grid(
    ax: Axes,
    fitnesses: np.ndarray,
    grid_shape: Sequence[int],
    dims: tuple[int, int],
    low: Any,
    high: Any,
    cmap: Any,
    norm: Any,
) -> Any:
    """Draws a grid repertoire's cells on `dims` (max over the other dimensions); empty cells blank."""
    dx, dy = dims
    values = np.moveaxis(np.asarray(fitnesses).reshape(tuple(grid_shape)), (dx, dy), (0, 1))
    values = values.reshape(values.shape[0], values.shape[1], -1).max(axis=-1)
    x_edges = np.linspace(low[dx], high[dx], values.shape[0] + 1)
    y_edges = np.linspace(low[dy], high[dy], values.shape[1] + 1)
    image = np.ma.masked_invalid(np.where(values > -np.inf, values, np.nan).T)
    return ax.pcolormesh(x_edges, y_edges, image, cmap=cmap, norm=norm)


def plot_repertoire(
    repertoire: Any,
    path: str | Path,
    low: float | Sequence[float],
    high: float | Sequence[float],
    title: str = "",
    dims: tuple[int, int] = (0, 1),
    cmap: str = "viridis",
    vmin: float | None = None,
    vmax: float | None = None,
    labels: Sequence[str] | None = None,
) -> Path:
    """Writes a PNG heatmap of the elites' fitness over two descriptor dimensions.

    The kind of repertoire is read from its attributes (duck typing, so plotting
    needs no QD import): a `grid_shape` means a grid, `centroids` without a grid
    shape a CVT archive, neither an unstructured archive.

    - grid: one rectangle per cell; with D > 2 descriptors, each rectangle shows the
      MAX fitness over the other dimensions (a projection on `dims`);
    - CVT, D = 2: the Voronoi cells, drawn as a fine raster where each pixel takes
      its nearest centroid's fitness; D > 2: the filled cells' centroids projected
      on `dims`, max fitness per bin of a regular 2-D grid;
    - unstructured: a scatter of the elites' descriptors on `dims`, fittest on top.

    Empty cells are left white. A 1-D repertoire is drawn as a strip.

    Args:
      repertoire: a repertoire with `fitnesses` (C,) (-inf where empty) and
        `descriptors` (C, D), e.g. `qdrl.qd.repertoires.CellRepertoire`.
      path: PNG to write; its parent directory is created if needed.
      low, high: descriptor bounds for the axes (scalars or D values).
      title: figure title.
      dims: the two descriptor dimensions shown (x, y) when D >= 2.
      cmap: matplotlib colormap name.
      vmin, vmax: colour range; default the range of the stored fitnesses (fix it
        to compare several plots).
      labels: the descriptor dimensions' names for the axes (`Task.descriptor_names`,
        e.g. "back foot contact"); default "descriptor 0", "descriptor 1", ...

    Returns:
      `path`.
    """
    from matplotlib.cm import ScalarMappable

    norm, colours = _colour_scale([repertoire], vmin, vmax, cmap)
    fig = Figure(figsize=(6.0, 5.0), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    _draw_repertoire(ax, repertoire, low, high, dims, norm, colours, labels)
    fig.colorbar(ScalarMappable(norm=norm, cmap=colours), ax=ax, label="fitness")
    return _save(fig, path, title)


def plot_repertoires(
    repertoires: Mapping[str, Any],
    path: str | Path,
    low: float | Sequence[float],
    high: float | Sequence[float],
    title: str = "",
    dims: tuple[int, int] = (0, 1),
    cmap: str = "viridis",
    labels: Sequence[str] | None = None,
) -> Path:
    """Writes one PNG with several repertoires of one task side by side, on one colour scale.

    Each panel is drawn as `plot_repertoire` draws one; `repertoires` maps a panel's
    title (e.g. the spec's name) to its repertoire. Returns `path`.
    """
    from matplotlib.cm import ScalarMappable

    if not repertoires:
        raise ValueError("repertoires is empty; nothing to draw")
    norm, colours = _colour_scale(list(repertoires.values()), None, None, cmap)
    fig = Figure(figsize=(4.6 * len(repertoires) + 1.2, 4.4), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, len(repertoires), squeeze=False)[0]
    for ax, (name, repertoire) in zip(axes, repertoires.items(), strict=True):
        _draw_repertoire(ax, repertoire, low, high, dims, norm, colours, labels)
        ax.set_title(name, fontsize=10)
    fig.colorbar(ScalarMappable(norm=norm, cmap=colours), ax=list(axes), label="fitness")
    return _save(fig, path, title)


def _colour_scale(repertoires: Sequence[Any], vmin: float | None, vmax: float | None, cmap: str) -> tuple[Any, Any]:
    """A colour normalisation over the filled cells of every repertoire, and the colormap
    with empty cells (NaN) white."""
    from matplotlib import colormaps
    from matplotlib.colors import Normalize

    values = np.concatenate([np.asarray(r.fitnesses, dtype=np.float64).ravel() for r in repertoires])
    shown = values[np.isfinite(values)]
    lo_c = vmin if vmin is not None else (float(shown.min()) if shown.size else 0.0)
    hi_c = vmax if vmax is not None else (float(shown.max()) if shown.size else 1.0)
    return Normalize(lo_c, hi_c if hi_c > lo_c else lo_c + 1.0), colormaps[cmap].with_extremes(bad="white")


def _draw_repertoire(
    ax: Axes,
    repertoire: Any,
    low: float | Sequence[float],
    high: float | Sequence[float],
    dims: tuple[int, int],
    norm: Any,
    colours: Any,
    labels: Sequence[str] | None,
) -> None:
    """Draws one repertoire's heatmap on `ax` (see `plot_repertoire`)."""
    fitnesses = np.asarray(repertoire.fitnesses, dtype=np.float64)
    descriptors = np.asarray(repertoire.descriptors, dtype=np.float64)
    num_dims = descriptors.shape[1]
    names = _names(labels, num_dims)
    lo = _repertoire_bounds(low, num_dims, "low")
    hi = _repertoire_bounds(high, num_dims, "high")
    grid_shape = getattr(repertoire, "grid_shape", None)
    centroids = getattr(repertoire, "centroids", None)
    centroids = None if centroids is None else np.asarray(centroids, dtype=np.float64)
    grid_lo = np.asarray(getattr(repertoire, "low", None) or lo, dtype=np.float64)
    grid_hi = np.asarray(getattr(repertoire, "high", None) or hi, dtype=np.float64)

    strip = num_dims == 1
    if strip:
        # A strip: a dummy second dimension of range [0, 1] with every point at 0.5.
        descriptors = _append_column(descriptors, 0.5)
        centroids = None if centroids is None else _append_column(centroids, 0.5)
        lo, hi = _append_column(lo, 0.0), _append_column(hi, 1.0)
        grid_lo, grid_hi = _append_column(grid_lo, 0.0), _append_column(grid_hi, 1.0)
        grid_shape = None if grid_shape is None else (*grid_shape, 1)
        dims, num_dims = (0, 1), 2
    dx, dy = (int(d) for d in dims)
    if dx == dy or not (0 <= dx < num_dims and 0 <= dy < num_dims):
        raise ValueError(f"dims must be two distinct dimensions in [0, {num_dims}), got {dims}")
    if np.any(hi <= lo):
        raise ValueError(f"need low < high, got low={lo.tolist()}, high={hi.tolist()}")

    filled = fitnesses > -np.inf
    shown = fitnesses[filled & np.isfinite(fitnesses)]
    ax.set_facecolor("white")
    box = (lo[dx], hi[dx], lo[dy], hi[dy])

    if grid_shape is not None:
        _draw_grid(ax, fitnesses, grid_shape, (dx, dy), grid_lo, grid_hi, colours, norm)
    elif centroids is not None and num_dims == 2:
        from scipy.spatial import cKDTree

        xs = np.linspace(box[0], box[1], _CVT_RESOLUTION)
        ys = np.linspace(box[2], box[3], _CVT_RESOLUTION)
        grid_x, grid_y = np.meshgrid(xs, ys)  # rows follow y
        pixels = np.stack([grid_x.ravel(), grid_y.ravel()], axis=-1)
        _, nearest = cKDTree(centroids[:, [dx, dy]]).query(pixels)
        values = fitnesses[nearest].reshape(grid_x.shape)
        image = np.ma.masked_invalid(np.where(values > -np.inf, values, np.nan))
        ax.imshow(
            image,
            origin="lower",
            extent=box,
            aspect="auto",
            cmap=colours,
            norm=norm,
            interpolation="nearest",
        )
    elif centroids is not None:
        bins = int(min(_MAX_PROJECTION_BINS, max(8, round(len(fitnesses) ** 0.5))))
        pts_lo, pts_hi = np.array([lo[dx], lo[dy]]), np.array([hi[dx], hi[dy]])
        values = _max_by_bin(
            centroids[filled][:, [dx, dy]], fitnesses[filled], pts_lo, pts_hi, bins
        )
        image = np.ma.masked_invalid(np.where(values > -np.inf, values, np.nan).T)
        ax.pcolormesh(
            np.linspace(box[0], box[1], bins + 1),
            np.linspace(box[2], box[3], bins + 1),
            image,
            cmap=colours,
            norm=norm,
        )
    else:
        order = np.argsort(fitnesses[filled], kind="stable")  # fittest drawn last, on top
        points = descriptors[filled][order]
        ax.scatter(
            points[:, dx],
            points[:, dy],
            c=fitnesses[filled][order],
            cmap=colours,
            norm=norm,
            s=12,
            edgecolors="none",
        )

    if not shown.size:
        ax.text(0.5, 0.5, "empty repertoire", ha="center", va="center", transform=ax.transAxes)
    ax.set_xlim(box[0], box[1])
    ax.set_ylim(box[2], box[3])
    ax.set_xlabel(names[dx])
    if strip:
        ax.set_yticks([])
    else:
        ax.set_ylabel(names[dy])


def _names(labels: Sequence[str] | None, num_dims: int) -> list[str]:
    if not labels:
        return [f"descriptor {i}" for i in range(num_dims)]
    if len(labels) != num_dims:
        raise ValueError(f"labels: expected {num_dims} names (one per descriptor), got {list(labels)}")
    return list(labels)


# (start x-y, end x-y, half-thickness): a wall seen from above; half-thickness 0 is a segment.
Wall = tuple[tuple[float, float], tuple[float, float], float]


def env_walls(env: Any) -> list[Wall]:
    """The walls of a maze environment seen from above (none for other environments).

    The point maze's segments (`env.walls`, (W, 2, 2)) and the capsules of brax's
    ant maze and ant trap (`env.brax_env.walls`: `start`, `end`, `radius`).
    """
    brax_env = getattr(env, "brax_env", None)
    if brax_env is not None:
        return [(tuple(w.start), tuple(w.end), float(w.radius)) for w in getattr(brax_env, "walls", ())]
    segments = getattr(env, "walls", None)
    if segments is None:
        return []
    return [((a[0], a[1]), (b[0], b[1]), 0.0) for a, b in np.asarray(segments, np.float64).tolist()]


def _outline(wall: Wall) -> np.ndarray:
    """The outline of a capsule (a segment widened by its half-thickness) as a polygon (k, 2)."""
    (x0, y0), (x1, y1), r = wall
    angle = np.arctan2(y1 - y0, x1 - x0)
    half = np.linspace(-np.pi / 2, np.pi / 2, 16)
    end = np.stack([x1 + r * np.cos(angle + half), y1 + r * np.sin(angle + half)], axis=1)
    start = np.stack([x0 + r * np.cos(angle + np.pi + half), y0 + r * np.sin(angle + np.pi + half)], axis=1)
    return np.concatenate([end, start])


def draw_walls(ax: Axes, walls: Sequence[Wall], dims: tuple[int, int] = (0, 1)) -> None:
    """Draws walls (x-y, from above) on `ax`: capsules filled grey, segments as thick lines.

    Nothing is drawn unless `dims` is (0, 1): walls live in the x-y plane.
    """
    from matplotlib.patches import Polygon

    if tuple(dims) != (0, 1):
        return
    for wall in walls:
        if wall[2] > 0:
            ax.add_patch(Polygon(_outline(wall), closed=True, color="0.45", zorder=3))
        else:
            ax.plot([wall[0][0], wall[1][0]], [wall[0][1], wall[1][1]], color="0.3", linewidth=3, zorder=3)


def plot_skills(
    trajectories: np.ndarray,
    skills: np.ndarray,
    mask: np.ndarray,
    path: str | Path,
    low: Sequence[float],
    high: Sequence[float],
    archive: Any = None,
    title: str = "",
    trajectories_are_positions: bool = True,
    dims: tuple[int, int] = (0, 1),
    walls: Sequence[Wall] = (),
    labels: Sequence[str] | None = None,
) -> Path:
    """Writes a PNG of each skill's trajectory in descriptor space, beside the archive heatmap.

    Left: one line per episode, coloured by its skill, from its start (dot) to its
    end (cross). With `trajectories_are_positions` (final-position tasks: the state
    descriptor is the x-y position) the line is the state descriptor itself;
    otherwise (episode-mean descriptors, e.g. feet contact) it is the running mean
    of the state descriptor, which ends at the episode's descriptor. Right (when
    `archive` is a grid repertoire): its fitness heatmap.

    Args:
      trajectories: (T, B, D) state descriptors after each step of B episodes.
      skills: (B,) int skill of each episode.
      mask: (T, B) 1.0 for the steps inside each episode.
      path: PNG to write.
      low, high: descriptor bounds (axes limits).
      archive: a grid passive archive (`fitnesses`, `grid_shape`), or None.
      title: figure title.
      trajectories_are_positions: see above.
      dims: the two descriptor dimensions shown.
      walls: a maze's walls (`env_walls`), drawn on both panels when the trajectories
        are x-y positions.
      labels: the descriptor dimensions' names (default "descriptor 0", ...).
    """
    from matplotlib import colormaps
    from matplotlib.colors import Normalize

    traj = np.asarray(trajectories, dtype=np.float64)
    valid = np.asarray(mask, dtype=np.float64)
    if traj.ndim != 3 or valid.shape != traj.shape[:2]:
        raise ValueError(
            f"trajectories (T, B, D) and mask (T, B) expected, got {traj.shape} and {valid.shape}"
        )
    dx, dy = dims
    names = _names(labels, traj.shape[2])
    if not trajectories_are_positions:
        counts = np.maximum(np.cumsum(valid, axis=0), 1.0)[..., None]
        traj = np.cumsum(traj * valid[..., None], axis=0) / counts
    skills = np.asarray(skills, dtype=np.int64)
    num_skills = int(skills.max()) + 1 if skills.size else 1
    palette = colormaps["tab20" if num_skills <= 20 else "turbo"]
    fig = Figure(figsize=(11.0 if archive is not None else 5.5, 5.0), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2 if archive is not None else 1, squeeze=False)[0]
    ax = axes[0]
    for b in range(traj.shape[1]):
        n = int(valid[:, b].sum())
        if n == 0:
            continue
        colour = palette((skills[b] % 20) / 19.0 if num_skills <= 20 else skills[b] / num_skills)
        xs, ys = traj[:n, b, dx], traj[:n, b, dy]
        ax.plot(xs, ys, color=colour, linewidth=1.0, alpha=0.8)
        ax.plot(xs[0], ys[0], "o", color=colour, markersize=3)
        ax.plot(xs[-1], ys[-1], "x", color=colour, markersize=6)
    ax.set_xlim(low[dx], high[dx])
    ax.set_ylim(low[dy], high[dy])
    # The paths are positions over time: "final x" on the archive is "x" along a path.
    path_names = [n.removeprefix("final ") for n in names] if trajectories_are_positions else names
    ax.set_xlabel(path_names[dx])
    ax.set_ylabel(path_names[dy])
    if trajectories_are_positions:
        for panel in axes:
            draw_walls(panel, walls, (dx, dy))
    kind = "trajectories" if trajectories_are_positions else "running-mean descriptors"
    ax.set_title(f"{num_skills} skills: {kind}")
    if archive is not None:
        fitnesses = np.asarray(archive.fitnesses, dtype=np.float64)
        shown = fitnesses[np.isfinite(fitnesses)]
        norm = Normalize(*(shown.min(), shown.max()) if shown.size else (0.0, 1.0))
        mesh = _draw_grid(
            axes[1], fitnesses, archive.grid_shape, (dx, dy), low, high,
            colormaps["viridis"].with_extremes(bad="white"), norm,
        )
        filled = int(np.sum(fitnesses > -np.inf))
        axes[1].set_title(f"passive archive: {filled} / {fitnesses.size} cells")
        axes[1].set_xlabel(names[dx])
        axes[1].set_ylabel(names[dy])
        fig.colorbar(mesh, ax=axes[1], label="fitness (return)")
    return _save(fig, path, title)


def _front_axes(fig: Figure, num_objectives: int) -> Axes:
    if num_objectives >= 3:
        return fig.add_subplot(projection="3d")
    return fig.subplots()


def _staircase(ax: Axes, front: np.ndarray, reference: Sequence[float], **style: Any) -> None:
    """The attainment boundary of a 2-objective front (maximisation) down to the reference; only
    the points that dominate the reference (the others add no hypervolume) are joined."""
    front = front[np.all(front > np.asarray(reference, np.float64)[:2], axis=1)]
    if not len(front):
        return
    pts = front[np.argsort(-front[:, 0], kind="stable")]
    xs, ys = [float(pts[0, 0])], [float(reference[1])]
    best = float(reference[1])
    for x, y in pts:
        if y > best:
            xs += [float(x), float(x)]
            ys += [best, float(y)]
            best = float(y)
    xs.append(float(reference[0]))
    ys.append(best)
    ax.plot(xs, ys, drawstyle="default", **style)


def plot_pareto_front(
    fronts: Mapping[str, np.ndarray],
    path: str | Path,
    reference: Sequence[float] | None = None,
    true_front: np.ndarray | None = None,
    title: str = "",
    objective_names: Sequence[str] | None = None,
) -> Path:
    """Writes a PNG of one or more Pareto fronts (objectives maximised), e.g. of several algorithms.

    Args:
      fronts: label -> (k, M) points; M = 2 draws each front with its attainment
        boundary down to `reference`, M >= 3 a 3-D scatter of the first three objectives.
      path: PNG to write.
      reference: the hypervolume's reference point (drawn as a cross).
      true_front: (k, M) points of the known front, drawn as a grey line / cloud.
      objective_names: axis labels (default "objective k").
    """
    m = max([np.asarray(f).shape[1] for f in fronts.values()] or [2])
    names = list(objective_names or [f"objective {k}" for k in range(m)])
    fig = Figure(figsize=(6.0, 5.0), layout="constrained")
    FigureCanvasAgg(fig)
    ax = _front_axes(fig, m)
    if true_front is not None:
        t = np.asarray(true_front, np.float64)
        if m >= 3:
            ax.scatter(t[:, 0], t[:, 1], t[:, 2], s=2, c="0.7", label="true front")  # type: ignore[misc]
        else:
            t = t[np.argsort(t[:, 0])]
            ax.plot(t[:, 0], t[:, 1], ".", ms=2, c="0.6", label="true front")
    for i, (label, front) in enumerate(fronts.items()):
        f = np.asarray(front, np.float64)
        colour = f"C{i}"
        if m >= 3:
            ax.scatter(f[:, 0], f[:, 1], f[:, 2], s=8, c=colour, label=f"{label} ({len(f)})")  # type: ignore[misc]
        else:
            ax.scatter(f[:, 0], f[:, 1], s=10, c=colour, label=f"{label} ({len(f)})", zorder=3)
            if reference is not None:
                _staircase(ax, f, reference, c=colour, lw=0.8)
    if reference is not None and m == 2:
        ax.plot([reference[0]], [reference[1]], "kx", label="reference point")
    ax.set_xlabel(names[0])
    ax.set_ylabel(names[1])
    if m >= 3:
        ax.set_zlabel(names[2])  # type: ignore[attr-defined]
    ax.legend(loc="best", fontsize="small")
    return _save(fig, path, title)


class _CellValues:
    """A repertoire-shaped view of one value per cell, for `plot_repertoire`."""

    def __init__(self, layout: Any, values: np.ndarray) -> None:
        self.fitnesses = values
        self.descriptors = np.asarray(layout.centroids)
        self.centroids = self.descriptors
        self.grid_shape = getattr(layout, "grid_shape", None)
        self.low = getattr(layout, "low", None)
        self.high = getattr(layout, "high", None)


def plot_cell_hypervolumes(
    layout: Any,
    hypervolumes: np.ndarray,
    path: str | Path,
    low: float | Sequence[float],
    high: float | Sequence[float],
    title: str = "",
) -> Path:
    """Writes a PNG heatmap of the hypervolume of each cell's front (MOME); empty cells blank.

    `layout` is the repertoire's cells (a `CellRepertoire`, or anything with
    `centroids` and, for a grid, `grid_shape`, `low`, `high`); `hypervolumes` (C,)
    with 0 or -inf for empty cells. The colour bar's values are hypervolumes.
    """
    values = np.asarray(hypervolumes, np.float64)
    values = np.where(values > 0, values, -np.inf)
    heading = f"{title}: hypervolume per cell" if title else "hypervolume per cell"
    return plot_repertoire(_CellValues(layout, values), path, low, high, title=heading)


def plot_cell_fronts(
    fitnesses: np.ndarray,
    hypervolumes: np.ndarray,
    path: str | Path,
    reference: Sequence[float] | None = None,
    num_cells: int = 4,
    title: str = "",
) -> Path:
    """Writes a PNG of a few cells' fronts (MOME), the first two objectives: the cells at the
    maximum, upper quartile, median and lower quartile of the per-cell hypervolume.

    `fitnesses` (C, P, M) with -inf rows for empty slots; `hypervolumes` (C,).
    """
    f = np.asarray(fitnesses, np.float64)
    hv = np.asarray(hypervolumes, np.float64)
    filled = np.flatnonzero(np.any(np.all(np.isfinite(f), axis=-1), axis=-1))
    ranked = filled[np.argsort(-hv[filled], kind="stable")]
    picks: list[int] = []
    for q in np.linspace(0.0, 0.75, num_cells):
        if len(ranked):
            c = int(ranked[min(len(ranked) - 1, int(q * len(ranked)))])
            if c not in picks:
                picks.append(c)
    fig = Figure(figsize=(6.0, 5.0), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    for i, c in enumerate(picks):
        front = f[c][np.all(np.isfinite(f[c]), axis=-1)]
        ax.scatter(front[:, 0], front[:, 1], s=12, c=f"C{i}", label=f"cell {c}: hypervolume {hv[c]:.4g}")
        if reference is not None:
            _staircase(ax, front[:, :2], reference[:2], c=f"C{i}", lw=0.8)
    if not picks:
        ax.text(0.5, 0.5, "empty repertoire", ha="center", va="center", transform=ax.transAxes)
    ax.set_xlabel("objective 0")
    ax.set_ylabel("objective 1")
    if picks:
        ax.legend(loc="best", fontsize="small")
    return _save(fig, path, title)
