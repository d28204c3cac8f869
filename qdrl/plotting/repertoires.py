"""Fitness heatmaps of QD repertoires: grids, CVT (Voronoi) archives, unstructured archives."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, overload

import numpy as np
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.cm import ScalarMappable
from matplotlib.colors import Normalize
from matplotlib.figure import Figure, FigureBase
from scipy.spatial import cKDTree

from qdrl.plotting._common import FigT, _names, _one_panel, _panels
from qdrl.plotting.sources import elites_of

__all__ = ["plot_repertoire", "plot_repertoires"]

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


def _colour_scale(repertoires: Sequence[Any], vmin: float | None, vmax: float | None, cmap: str) -> tuple[Any, Any]:
    """A colour normalisation over the filled cells of every repertoire, and the colormap
    with empty cells (NaN) white."""

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
    own_lo, own_hi = getattr(repertoire, "low", None), getattr(repertoire, "high", None)
    grid_lo = lo if own_lo is None else _repertoire_bounds(own_lo, num_dims, "low")
    grid_hi = hi if own_hi is None else _repertoire_bounds(own_hi, num_dims, "high")

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


def _repertoire_panel(
    repertoire: Any,
    path: str | Path | None,
    low: float | Sequence[float] | None,
    high: float | Sequence[float] | None,
    title: str,
    dims: tuple[int, int],
    cmap: str,
    vmin: float | None,
    vmax: float | None,
    labels: Sequence[str] | None,
    ax: Axes | None,
) -> Path | Axes:
    """`plot_repertoire`, untyped by overloads, for the functions built on it."""

    repertoire, low, high, labels = elites_of(repertoire, low, high, labels)
    norm, colours = _colour_scale([repertoire], vmin, vmax, cmap)

    def draw(panel: Axes) -> None:
        _draw_repertoire(panel, repertoire, low, high, dims, norm, colours, labels)
        panel.figure.colorbar(ScalarMappable(norm=norm, cmap=colours), ax=panel, label="fitness")

    return _one_panel(draw, path, ax, title)


@overload
def plot_repertoire(
    repertoire: Any,
    path: str | Path,
    low: float | Sequence[float] | None = ...,
    high: float | Sequence[float] | None = ...,
    title: str = ...,
    dims: tuple[int, int] = ...,
    cmap: str = ...,
    vmin: float | None = ...,
    vmax: float | None = ...,
    labels: Sequence[str] | None = ...,
    *,
    ax: None = None,
) -> Path: ...
@overload
def plot_repertoire(
    repertoire: Any,
    path: str | Path | None = ...,
    low: float | Sequence[float] | None = ...,
    high: float | Sequence[float] | None = ...,
    title: str = ...,
    dims: tuple[int, int] = ...,
    cmap: str = ...,
    vmin: float | None = ...,
    vmax: float | None = ...,
    labels: Sequence[str] | None = ...,
    *,
    ax: Axes,
) -> Axes: ...
@overload
def plot_repertoire(
    repertoire: Any,
    path: None = ...,
    low: float | Sequence[float] | None = ...,
    high: float | Sequence[float] | None = ...,
    title: str = ...,
    dims: tuple[int, int] = ...,
    cmap: str = ...,
    vmin: float | None = ...,
    vmax: float | None = ...,
    labels: Sequence[str] | None = ...,
    *,
    ax: None = None,
) -> Axes: ...
def plot_repertoire(
    repertoire: Any,
    path: str | Path | None = None,
    low: float | Sequence[float] | None = None,
    high: float | Sequence[float] | None = None,
    title: str = "",
    dims: tuple[int, int] = (0, 1),
    cmap: str = "viridis",
    vmin: float | None = None,
    vmax: float | None = None,
    labels: Sequence[str] | None = None,
    *,
    ax: Axes | None = None,
) -> Path | Axes:
    """Draws a heatmap of a repertoire's elite fitness over two descriptor dimensions.

    The kind is read from the repertoire's attributes: `grid_shape` is a grid (one
    rectangle per cell; with D > 2 the max over the other dimensions), `centroids`
    without it a CVT archive (D = 2: the Voronoi cells as a fine raster; D > 2: the
    centroids binned on `dims`, max per bin), neither an unstructured archive (a
    scatter, fittest on top). Empty cells stay white; a 1-D repertoire is a strip.
    A colour bar is added beside the panel.

    Args:
      repertoire: `fitnesses` (C,) (-inf where empty) and `descriptors` (C, D),
        e.g. `qdrl.qd.repertoires.CellRepertoire`; or a loaded run (`qdrl.load_run`:
        its final repertoire, bounds and descriptor names); or a DataFrame of elites
        (`run.table`, `qdrl.load_repertoires`: `fitness` and `descriptor_*` columns,
        drawn as points since a table holds no empty cells).
      path: PNG to write (its directory is created), or None.
      low, high: descriptor bounds for the axes (scalars or D values); default the
        run's, the grid's, else the descriptors' range.
      title: the title (the figure's; with `ax`, the panel's).
      dims: the two descriptor dimensions shown (x, y) when D >= 2.
      cmap: matplotlib colormap name.
      vmin, vmax: colour range; default the stored fitnesses' range.
      labels: the descriptor dimensions' names (default "descriptor 0", ...).
      ax: an Axes to draw on.

    Returns:
      `ax` when given, else `path` when given, else the Axes of a new figure.
    """
    return _repertoire_panel(repertoire, path, low, high, title, dims, cmap, vmin, vmax, labels, ax)


@overload
def plot_repertoires(
    repertoires: Mapping[str, Any],
    path: str | Path,
    low: float | Sequence[float] | None = ...,
    high: float | Sequence[float] | None = ...,
    title: str = ...,
    dims: tuple[int, int] = ...,
    cmap: str = ...,
    labels: Sequence[str] | None = ...,
    *,
    fig: None = None,
) -> Path: ...
@overload
def plot_repertoires(
    repertoires: Mapping[str, Any],
    path: str | Path | None = ...,
    low: float | Sequence[float] | None = ...,
    high: float | Sequence[float] | None = ...,
    title: str = ...,
    dims: tuple[int, int] = ...,
    cmap: str = ...,
    labels: Sequence[str] | None = ...,
    *,
    fig: FigT,
) -> FigT: ...
@overload
def plot_repertoires(
    repertoires: Mapping[str, Any],
    path: None = ...,
    low: float | Sequence[float] | None = ...,
    high: float | Sequence[float] | None = ...,
    title: str = ...,
    dims: tuple[int, int] = ...,
    cmap: str = ...,
    labels: Sequence[str] | None = ...,
    *,
    fig: None = None,
) -> Figure: ...
def plot_repertoires(
    repertoires: Mapping[str, Any],
    path: str | Path | None = None,
    low: float | Sequence[float] | None = None,
    high: float | Sequence[float] | None = None,
    title: str = "",
    dims: tuple[int, int] = (0, 1),
    cmap: str = "viridis",
    labels: Sequence[str] | None = None,
    *,
    fig: FigureBase | None = None,
) -> Path | FigureBase:
    """Draws several repertoires of one task side by side on one colour scale.

    Args:
      repertoires: panel title (e.g. the spec's name) -> repertoire, loaded run or
        DataFrame, each drawn as `plot_repertoire` draws one.
      path: PNG to write (its directory is created), or None.
      low, high: descriptor bounds for the axes (scalars or D values); default the
        first one's (`plot_repertoire`).
      title: the figure title.
      dims: the two descriptor dimensions shown.
      cmap: matplotlib colormap name.
      labels: the descriptor dimensions' names.
      fig: an empty Figure or SubFigure to draw the panels in.

    Returns:
      `fig` when given, else `path` when given, else a new Figure.

    Raises:
      ValueError: if `repertoires` is empty.
    """

    if not repertoires:
        raise ValueError("repertoires is empty; nothing to draw")
    resolved: dict[str, Any] = {}
    lo: Any = low
    hi: Any = high
    for name, source in repertoires.items():
        resolved[name], lo, hi, labels = elites_of(source, lo, hi, labels)
    repertoires = resolved
    norm, colours = _colour_scale(list(repertoires.values()), None, None, cmap)

    def draw(figure: FigureBase) -> None:
        axes = figure.subplots(1, len(repertoires), squeeze=False)[0]
        for panel, (name, repertoire) in zip(axes, repertoires.items(), strict=True):
            _draw_repertoire(panel, repertoire, lo, hi, dims, norm, colours, labels)
            panel.set_title(name, fontsize=10)
        figure.colorbar(ScalarMappable(norm=norm, cmap=colours), ax=list(axes), label="fitness")

    return _panels(draw, path, fig, title, (4.6 * len(repertoires) + 1.2, 4.4))
