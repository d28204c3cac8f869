"""Multi-objective plots: Pareto fronts and MOME's per-cell hypervolumes and fronts."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, overload

import numpy as np
from matplotlib.axes import Axes

from qdrl.plotting._common import _one_panel
from qdrl.plotting.repertoires import _repertoire_panel

__all__ = ["plot_cell_fronts", "plot_cell_hypervolumes", "plot_pareto_front"]


def _staircase(ax: Axes, front: np.ndarray, reference: Sequence[float], sign: float = 1.0, **style: Any) -> None:
    """The attainment boundary of a 2-objective front (maximisation) down to the reference; only
    the points that dominate the reference (the others add no hypervolume) are joined. Drawn
    at `sign` times the coordinates (-1: in the minimisation view)."""
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
    ax.plot(sign * np.asarray(xs), sign * np.asarray(ys), drawstyle="default", **style)


@overload
def plot_pareto_front(
    fronts: Mapping[str, np.ndarray],
    path: str | Path,
    reference: Sequence[float] | None = ...,
    true_front: np.ndarray | None = ...,
    title: str = ...,
    objective_names: Sequence[str] | None = ...,
    *,
    ax: None = None,
    minimised: bool = ...,
) -> Path: ...
@overload
def plot_pareto_front(
    fronts: Mapping[str, np.ndarray],
    path: str | Path | None = ...,
    reference: Sequence[float] | None = ...,
    true_front: np.ndarray | None = ...,
    title: str = ...,
    objective_names: Sequence[str] | None = ...,
    *,
    ax: Axes,
    minimised: bool = ...,
) -> Axes: ...
@overload
def plot_pareto_front(
    fronts: Mapping[str, np.ndarray],
    path: None = None,
    reference: Sequence[float] | None = ...,
    true_front: np.ndarray | None = ...,
    title: str = ...,
    objective_names: Sequence[str] | None = ...,
    *,
    ax: None = None,
    minimised: bool = ...,
) -> Axes: ...
def plot_pareto_front(
    fronts: Mapping[str, np.ndarray],
    path: str | Path | None = None,
    reference: Sequence[float] | None = None,
    true_front: np.ndarray | None = None,
    title: str = "",
    objective_names: Sequence[str] | None = None,
    *,
    ax: Axes | None = None,
    minimised: bool = False,
) -> Path | Axes:
    """Draws one or more Pareto fronts (objectives maximised), e.g. of several algorithms.

    The points are fitnesses (every objective maximised). With `minimised`, for tasks whose
    objectives are minimised and scored negated (ZDT, DTLZ: `Task.minimised`), everything
    is drawn in the objectives' own view: minus each point, reference and true front.

    Args:
      fronts: label -> (k, M) points; M = 2 draws each front with its attainment
        boundary down to `reference`, M >= 3 a 3-D scatter of the first three objectives.
      path: PNG to write (its directory is created), or None.
      reference: the hypervolume's reference point (drawn as a cross).
      true_front: (k, M) points of the known front, drawn as a grey line / cloud.
      title: the title (the figure's; with `ax`, the panel's).
      objective_names: axis labels (default "objective k").
      ax: an Axes to draw on; a 3-D one (`projection="3d"`) when M >= 3.
      minimised: draw minus the fitnesses (the minimised objectives), axes "f1 (minimised)".

    Returns:
      `ax` when given, else `path` when given, else the Axes of a new figure.

    Raises:
      ValueError: if M >= 3 and `ax` is not 3-D.
    """
    m = max([np.asarray(f).shape[1] for f in fronts.values()] or [2])
    sign = -1.0 if minimised else 1.0
    default = [f"f{k + 1} (minimised)" if minimised else f"objective {k}" for k in range(m)]
    names = list(objective_names or default)
    if ax is not None and m >= 3 and getattr(ax, "name", "") != "3d":
        raise ValueError(f"{m} objectives are drawn in 3-D: pass an Axes with projection='3d'")

    def draw(panel: Axes) -> None:
        if true_front is not None:
            t = sign * np.asarray(true_front, np.float64)
            if m >= 3:
                panel.scatter(t[:, 0], t[:, 1], t[:, 2], s=2, c="0.7", label="true front")  # type: ignore[misc]
            else:
                t = t[np.argsort(t[:, 0])]
                panel.plot(t[:, 0], t[:, 1], ".", ms=2, c="0.6", label="true front")
        for i, (label, front) in enumerate(fronts.items()):
            f = np.asarray(front, np.float64)
            colour = f"C{i}"
            shown = sign * f
            if m >= 3:
                panel.scatter(shown[:, 0], shown[:, 1], shown[:, 2], s=8, c=colour, label=f"{label} ({len(f)})")  # type: ignore[misc]
            else:
                panel.scatter(shown[:, 0], shown[:, 1], s=10, c=colour, label=f"{label} ({len(f)})", zorder=3)
                if reference is not None:
                    _staircase(panel, f, reference, sign, c=colour, lw=0.8)
        if reference is not None and m == 2:
            panel.plot([sign * reference[0]], [sign * reference[1]], "kx", label="reference point")
        panel.set_xlabel(names[0])
        panel.set_ylabel(names[1])
        if m >= 3:
            panel.set_zlabel(names[2])  # type: ignore[attr-defined]
        panel.legend(loc="best", fontsize="small")

    return _one_panel(draw, path, ax, title, projection="3d" if m >= 3 else None)


class _CellValues:
    """A repertoire-shaped view of one value per cell, for `plot_repertoire`."""

    def __init__(self, layout: Any, values: np.ndarray) -> None:
        self.fitnesses = values
        self.descriptors = np.asarray(layout.centroids)
        self.centroids = self.descriptors
        self.grid_shape = getattr(layout, "grid_shape", None)
        self.low = getattr(layout, "low", None)
        self.high = getattr(layout, "high", None)


@overload
def plot_cell_hypervolumes(
    layout: Any,
    hypervolumes: np.ndarray,
    path: str | Path,
    low: float | Sequence[float],
    high: float | Sequence[float],
    title: str = ...,
    *,
    ax: None = None,
) -> Path: ...
@overload
def plot_cell_hypervolumes(
    layout: Any,
    hypervolumes: np.ndarray,
    path: str | Path | None,
    low: float | Sequence[float],
    high: float | Sequence[float],
    title: str = ...,
    *,
    ax: Axes,
) -> Axes: ...
@overload
def plot_cell_hypervolumes(
    layout: Any,
    hypervolumes: np.ndarray,
    path: None,
    low: float | Sequence[float],
    high: float | Sequence[float],
    title: str = ...,
    *,
    ax: None = None,
) -> Axes: ...
def plot_cell_hypervolumes(
    layout: Any,
    hypervolumes: np.ndarray,
    path: str | Path | None,
    low: float | Sequence[float],
    high: float | Sequence[float],
    title: str = "",
    *,
    ax: Axes | None = None,
) -> Path | Axes:
    """Draws a heatmap of the hypervolume of each cell's front (MOME); empty cells blank.

    Args:
      layout: the repertoire's cells (a `CellRepertoire`, or anything with
        `centroids` and, for a grid, `grid_shape`, `low`, `high`).
      hypervolumes: (C,) per cell, 0 or -inf where empty; the colour bar's values.
      path: PNG to write (its directory is created), or None.
      low, high: descriptor bounds for the axes.
      title: prefixed to the title "hypervolume per cell".
      ax: an Axes to draw on.

    Returns:
      `ax` when given, else `path` when given, else the Axes of a new figure.
    """
    values = np.asarray(hypervolumes, np.float64)
    values = np.where(values > 0, values, -np.inf)
    heading = f"{title}: hypervolume per cell" if title else "hypervolume per cell"
    return _repertoire_panel(
        _CellValues(layout, values), path, low, high, heading, (0, 1), "viridis", None, None, None, ax
    )


@overload
def plot_cell_fronts(
    fitnesses: np.ndarray,
    hypervolumes: np.ndarray,
    path: str | Path,
    reference: Sequence[float] | None = ...,
    num_cells: int = ...,
    title: str = ...,
    *,
    ax: None = None,
) -> Path: ...
@overload
def plot_cell_fronts(
    fitnesses: np.ndarray,
    hypervolumes: np.ndarray,
    path: str | Path | None = ...,
    reference: Sequence[float] | None = ...,
    num_cells: int = ...,
    title: str = ...,
    *,
    ax: Axes,
) -> Axes: ...
@overload
def plot_cell_fronts(
    fitnesses: np.ndarray,
    hypervolumes: np.ndarray,
    path: None = None,
    reference: Sequence[float] | None = ...,
    num_cells: int = ...,
    title: str = ...,
    *,
    ax: None = None,
) -> Axes: ...
def plot_cell_fronts(
    fitnesses: np.ndarray,
    hypervolumes: np.ndarray,
    path: str | Path | None = None,
    reference: Sequence[float] | None = None,
    num_cells: int = 4,
    title: str = "",
    *,
    ax: Axes | None = None,
) -> Path | Axes:
    """Draws a few cells' fronts (MOME) on the first two objectives.

    The cells are those at the maximum, upper quartile, median and lower quartile of
    the per-cell hypervolume (for `num_cells` = 4).

    Args:
      fitnesses: (C, P, M), -inf rows for empty slots.
      hypervolumes: (C,) per cell.
      path: PNG to write (its directory is created), or None.
      reference: the reference point, for each front's attainment boundary.
      num_cells: how many cells to draw, at most.
      title: the title (the figure's; with `ax`, the panel's).
      ax: an Axes to draw on.

    Returns:
      `ax` when given, else `path` when given, else the Axes of a new figure.
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

    def draw(panel: Axes) -> None:
        for i, c in enumerate(picks):
            front = f[c][np.all(np.isfinite(f[c]), axis=-1)]
            panel.scatter(front[:, 0], front[:, 1], s=12, c=f"C{i}", label=f"cell {c}: hypervolume {hv[c]:.4g}")
            if reference is not None:
                _staircase(panel, front[:, :2], reference[:2], c=f"C{i}", lw=0.8)
        if not picks:
            panel.text(0.5, 0.5, "empty repertoire", ha="center", va="center", transform=panel.transAxes)
        panel.set_xlabel("objective 0")
        panel.set_ylabel("objective 1")
        if picks:
            panel.legend(loc="best", fontsize="small")

    return _one_panel(draw, path, ax, title)
