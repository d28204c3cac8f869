"""Skill discovery plots: each skill's trajectory beside the passive archive, and maze walls."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, overload

import numpy as np
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.colors import Normalize
from matplotlib.figure import Figure, FigureBase
from matplotlib.patches import Polygon

from qdrl.plotting._common import FigT, _names, _panels
from qdrl.plotting.repertoires import _draw_grid

__all__ = ["Wall", "draw_walls", "env_walls", "plot_skills"]

# (start x-y, end x-y, half-thickness): a wall seen from above; half-thickness 0 is a segment.
Wall = tuple[tuple[float, float], tuple[float, float], float]


def env_walls(env: Any) -> list[Wall]:
    """The walls of a maze environment seen from above (none for other environments).

    Args:
      env: the point maze (segments `env.walls`, (W, 2, 2)) or a brax ant maze / ant
        trap (capsules `env.brax_env.walls`: `start`, `end`, `radius`), or any other.

    Returns:
      The walls; empty for an environment without any.
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


def draw_walls(ax: Axes, walls: Sequence[Wall], dims: tuple[int, int] = (0, 1)) -> Axes:
    """Draws walls (x-y, from above) on `ax`: capsules filled grey, segments as thick lines.

    Args:
      ax: the Axes to draw on.
      walls: the walls, e.g. `env_walls(env)`.
      dims: the descriptor dimensions `ax` shows; nothing is drawn unless (0, 1),
        as walls live in the x-y plane.

    Returns:
      `ax`.
    """

    if tuple(dims) != (0, 1):
        return ax
    for wall in walls:
        if wall[2] > 0:
            ax.add_patch(Polygon(_outline(wall), closed=True, color="0.45", zorder=3))
        else:
            ax.plot([wall[0][0], wall[1][0]], [wall[0][1], wall[1][1]], color="0.3", linewidth=3, zorder=3)
    return ax


@overload
def plot_skills(
    trajectories: np.ndarray,
    skills: np.ndarray,
    mask: np.ndarray,
    path: str | Path,
    low: Sequence[float],
    high: Sequence[float],
    archive: Any = ...,
    title: str = ...,
    trajectories_are_positions: bool = ...,
    dims: tuple[int, int] = ...,
    walls: Sequence[Wall] = ...,
    labels: Sequence[str] | None = ...,
    *,
    ax: None = None,
    fig: None = None,
) -> Path: ...
@overload
def plot_skills(
    trajectories: np.ndarray,
    skills: np.ndarray,
    mask: np.ndarray,
    path: str | Path | None,
    low: Sequence[float],
    high: Sequence[float],
    archive: Any = ...,
    title: str = ...,
    trajectories_are_positions: bool = ...,
    dims: tuple[int, int] = ...,
    walls: Sequence[Wall] = ...,
    labels: Sequence[str] | None = ...,
    *,
    ax: Axes,
    fig: None = None,
) -> Axes: ...
@overload
def plot_skills(
    trajectories: np.ndarray,
    skills: np.ndarray,
    mask: np.ndarray,
    path: str | Path | None,
    low: Sequence[float],
    high: Sequence[float],
    archive: Any = ...,
    title: str = ...,
    trajectories_are_positions: bool = ...,
    dims: tuple[int, int] = ...,
    walls: Sequence[Wall] = ...,
    labels: Sequence[str] | None = ...,
    *,
    ax: None = None,
    fig: FigT,
) -> FigT: ...
@overload
def plot_skills(
    trajectories: np.ndarray,
    skills: np.ndarray,
    mask: np.ndarray,
    path: None,
    low: Sequence[float],
    high: Sequence[float],
    archive: Any = ...,
    title: str = ...,
    trajectories_are_positions: bool = ...,
    dims: tuple[int, int] = ...,
    walls: Sequence[Wall] = ...,
    labels: Sequence[str] | None = ...,
    *,
    ax: None = None,
    fig: None = None,
) -> Figure: ...
def plot_skills(
    trajectories: np.ndarray,
    skills: np.ndarray,
    mask: np.ndarray,
    path: str | Path | None,
    low: Sequence[float],
    high: Sequence[float],
    archive: Any = None,
    title: str = "",
    trajectories_are_positions: bool = True,
    dims: tuple[int, int] = (0, 1),
    walls: Sequence[Wall] = (),
    labels: Sequence[str] | None = None,
    *,
    ax: Axes | None = None,
    fig: FigureBase | None = None,
) -> Path | Axes | FigureBase:
    """Draws each skill's trajectory in descriptor space, beside the archive's heatmap.

    One line per episode, coloured by its skill, from its start (dot) to its end
    (cross): the state descriptor itself with `trajectories_are_positions` (x-y
    positions), else its running mean, which ends at the episode's descriptor. A
    second panel shows `archive`'s fitness heatmap when it is given.

    Args:
      trajectories: (T, B, D) state descriptors after each step of B episodes.
      skills: (B,) int skill of each episode.
      mask: (T, B) 1.0 for the steps inside each episode.
      path: PNG to write (its directory is created), or None.
      low, high: descriptor bounds (axes limits).
      archive: a grid passive archive (`fitnesses`, `grid_shape`), or None.
      title: the figure title; with `ax`, the panel's title in place of its default.
      trajectories_are_positions: see above.
      dims: the two descriptor dimensions shown.
      walls: a maze's walls (`env_walls`), drawn on every panel when the trajectories
        are x-y positions.
      labels: the descriptor dimensions' names (default "descriptor 0", ...).
      ax: an Axes to draw the trajectories on (without `archive`).
      fig: an empty Figure or SubFigure to draw the panel(s) in.

    Returns:
      `ax` or `fig` when given, else `path` when given, else a new Figure.

    Raises:
      ValueError: on mismatched shapes, both `ax` and `fig`, or `ax` with `archive`.
    """

    traj = np.asarray(trajectories, dtype=np.float64)
    valid = np.asarray(mask, dtype=np.float64)
    if traj.ndim != 3 or valid.shape != traj.shape[:2]:
        raise ValueError(
            f"trajectories (T, B, D) and mask (T, B) expected, got {traj.shape} and {valid.shape}"
        )
    if ax is not None and fig is not None:
        raise ValueError("give ax or fig, not both")
    if ax is not None and archive is not None:
        raise ValueError("the archive is a second panel: pass fig, or draw it with plot_repertoire")
    dx, dy = dims
    names = _names(labels, traj.shape[2])
    if not trajectories_are_positions:
        counts = np.maximum(np.cumsum(valid, axis=0), 1.0)[..., None]
        traj = np.cumsum(traj * valid[..., None], axis=0) / counts
    skills = np.asarray(skills, dtype=np.int64)
    num_skills = int(skills.max()) + 1 if skills.size else 1
    palette = colormaps["tab20" if num_skills <= 20 else "turbo"]
    kind = "trajectories" if trajectories_are_positions else "running-mean descriptors"

    def draw_paths(panel: Axes) -> None:
        for b in range(traj.shape[1]):
            n = int(valid[:, b].sum())
            if n == 0:
                continue
            colour = palette((skills[b] % 20) / 19.0 if num_skills <= 20 else skills[b] / num_skills)
            xs, ys = traj[:n, b, dx], traj[:n, b, dy]
            panel.plot(xs, ys, color=colour, linewidth=1.0, alpha=0.8)
            panel.plot(xs[0], ys[0], "o", color=colour, markersize=3)
            panel.plot(xs[-1], ys[-1], "x", color=colour, markersize=6)
        panel.set_xlim(low[dx], high[dx])
        panel.set_ylim(low[dy], high[dy])
        # The paths are positions over time: "final x" on the archive is "x" along a path.
        path_names = [n.removeprefix("final ") for n in names] if trajectories_are_positions else names
        panel.set_xlabel(path_names[dx])
        panel.set_ylabel(path_names[dy])

    def draw(figure: FigureBase) -> None:
        axes = figure.subplots(1, 2 if archive is not None else 1, squeeze=False)[0]
        draw_paths(axes[0])
        if trajectories_are_positions:
            for panel in axes:
                draw_walls(panel, walls, (dx, dy))
        axes[0].set_title(f"{num_skills} skills: {kind}")
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
            figure.colorbar(mesh, ax=axes[1], label="fitness (return)")

    size = (11.0 if archive is not None else 5.5, 5.0)
    if ax is None:
        return _panels(draw, path, fig, title, size)
    if path is not None:
        _panels(draw, path, None, title, size)
    draw_paths(ax)
    if trajectories_are_positions:
        draw_walls(ax, walls, (dx, dy))
    ax.set_title(title or f"{num_skills} skills: {kind}")
    return ax
