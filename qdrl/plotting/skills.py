"""Skill discovery plots: each skill's trajectory (at one or several evaluations) beside the passive
archive, and maze walls."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, overload

import numpy as np
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.cm import ScalarMappable
from matplotlib.colors import BoundaryNorm, Colormap, ListedColormap, Normalize
from matplotlib.figure import Figure, FigureBase
from matplotlib.lines import Line2D
from matplotlib.patches import Polygon

from qdrl.plotting._common import FigT, _names, _panels
from qdrl.plotting.repertoires import _draw_grid, _draw_repertoire

__all__ = ["LEGEND_MAX", "Wall", "draw_walls", "env_walls", "plot_skills", "skill_colours"]

# (start x-y, end x-y, half-thickness): a wall seen from above; half-thickness 0 is a segment.
Wall = tuple[tuple[float, float], tuple[float, float], float]
# Up to this many skills a legend names them; beyond, a colour bar does.
LEGEND_MAX = 10
Bounds = Literal["data", "task"]


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
    trajectories: np.ndarray | Mapping[str, np.ndarray],
    skills: np.ndarray,
    mask: np.ndarray | Mapping[str, np.ndarray],
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
    num_skills: int | None = ...,
    bounds: Bounds = ...,
    ax: None = None,
    fig: None = None,
) -> Path: ...
@overload
def plot_skills(
    trajectories: np.ndarray | Mapping[str, np.ndarray],
    skills: np.ndarray,
    mask: np.ndarray | Mapping[str, np.ndarray],
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
    num_skills: int | None = ...,
    bounds: Bounds = ...,
    ax: Axes,
    fig: None = None,
) -> Axes: ...
@overload
def plot_skills(
    trajectories: np.ndarray | Mapping[str, np.ndarray],
    skills: np.ndarray,
    mask: np.ndarray | Mapping[str, np.ndarray],
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
    num_skills: int | None = ...,
    bounds: Bounds = ...,
    ax: None = None,
    fig: FigT,
) -> FigT: ...
@overload
def plot_skills(
    trajectories: np.ndarray | Mapping[str, np.ndarray],
    skills: np.ndarray,
    mask: np.ndarray | Mapping[str, np.ndarray],
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
    num_skills: int | None = ...,
    bounds: Bounds = ...,
    ax: None = None,
    fig: None = None,
) -> Figure: ...
def plot_skills(
    trajectories: np.ndarray | Mapping[str, np.ndarray],
    skills: np.ndarray,
    mask: np.ndarray | Mapping[str, np.ndarray],
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
    num_skills: int | None = None,
    bounds: Bounds = "data",
    ax: Axes | None = None,
    fig: FigureBase | None = None,
) -> Path | Axes | FigureBase:
    """Draws each skill's trajectory in descriptor space, beside the archive's heatmap.

    One line per episode, coloured by its skill, from its start (dot) to its end
    (cross): the state descriptor itself with `trajectories_are_positions` (x-y
    positions), else its running mean, which ends at the episode's descriptor. A
    mapping of evaluations (e.g. the first, middle and last of a run) gives one panel
    each, its key the panel's title. Up to `LEGEND_MAX` skills a legend names the
    skill ids, beyond that a colour bar. A last panel shows `archive`'s fitness
    heatmap when it is given.

    Args:
      trajectories: (T, B, D) state descriptors after each step of B episodes, or a
        mapping of panel titles to such arrays (one evaluation each, same B).
      skills: (B,) int skill of each episode.
      mask: (T, B) 1.0 for the steps inside each episode (a mapping with the same keys
        as `trajectories` when it is one).
      path: PNG to write (its directory is created), or None.
      low, high: descriptor bounds: the archive's extent, and the paths' axes with
        `bounds="task"`.
      archive: a grid or CVT passive archive (`fitnesses` and `grid_shape` or `centroids`), or None.
      title: the figure title; with `ax`, the panel's title in place of its default.
      trajectories_are_positions: see above.
      dims: the two descriptor dimensions shown.
      walls: a maze's walls (`env_walls`), drawn on every panel when the trajectories
        are x-y positions.
      labels: the descriptor dimensions' names (default "descriptor 0", ...).
      num_skills: the number of skills (colours and legend); default: the largest
        id in `skills` plus one.
      bounds: "data" fits the paths' axes to the paths (shared by their panels);
        "task" uses `low` and `high`.
      ax: an Axes to draw one evaluation's trajectories on (without `archive`).
      fig: an empty Figure or SubFigure to draw the panel(s) in.

    Returns:
      `ax` or `fig` when given, else `path` when given, else a new Figure.

    Raises:
      ValueError: on mismatched shapes or keys, both `ax` and `fig`, or `ax` with
        `archive` or several evaluations.
    """

    named = dict(trajectories) if isinstance(trajectories, Mapping) else {"": trajectories}
    masks = dict(mask) if isinstance(mask, Mapping) else {"": mask}
    if list(named) != list(masks):
        raise ValueError(f"trajectories and mask: expected the same evaluations, got {list(named)} and {list(masks)}")
    if not named:
        raise ValueError("trajectories: expected at least one evaluation, got an empty mapping")
    skills = np.asarray(skills, dtype=np.int64)
    evaluations: list[tuple[str, np.ndarray, np.ndarray]] = []
    for name, traj_in in named.items():
        traj = np.asarray(traj_in, dtype=np.float64)
        valid = np.asarray(masks[name], dtype=np.float64)
        if traj.ndim != 3 or valid.shape != traj.shape[:2] or skills.shape != traj.shape[1:2]:
            raise ValueError(
                f"trajectories (T, B, D), mask (T, B) and skills (B,) expected, got {traj.shape}, "
                f"{valid.shape} and {skills.shape}" + (f" for {name!r}" if name else "")
            )
        if not trajectories_are_positions:
            counts = np.maximum(np.cumsum(valid, axis=0), 1.0)[..., None]
            traj = np.cumsum(traj * valid[..., None], axis=0) / counts
        evaluations.append((name, traj, valid))
    if evaluations[0][1].shape[2] == 1:
        # One descriptor dimension (halfcheetah_omni's x): drawn against the step, as METRA's
        # figures draw HalfCheetah's skills; a 1-D archive has no panel of its own.
        evaluations = [
            (name, np.concatenate([traj, np.broadcast_to(np.arange(traj.shape[0], dtype=np.float64)[:, None, None],
                                                         traj.shape)], axis=-1), valid)
            for name, traj, valid in evaluations
        ]
        steps = float(evaluations[0][1].shape[0])
        low, high = (*low[:1], 0.0), (*high[:1], steps)
        labels = (*(labels or ("descriptor 0",))[:1], "step")
        dims, archive = (0, 1), None
    if bounds not in ("data", "task"):
        raise ValueError(f"bounds: expected 'data' or 'task', got {bounds!r}")
    if ax is not None and fig is not None:
        raise ValueError("give ax or fig, not both")
    if ax is not None and archive is not None:
        raise ValueError("the archive is a second panel: pass fig, or draw it with plot_repertoire")
    if ax is not None and len(evaluations) > 1:
        raise ValueError("several evaluations are several panels: pass fig, or one evaluation with ax")
    dx, dy = dims
    names = _names(labels, evaluations[0][1].shape[2])
    k = num_skills if num_skills is not None else (int(skills.max()) + 1 if skills.size else 1)
    cmap, norm = skill_colours(k)
    kind = "trajectories" if trajectories_are_positions else "running-mean descriptors"
    limits = _limits(evaluations, (dx, dy), low, high) if bounds == "data" else None
    # The paths are positions over time: "final x" on the archive is "x" along a path.
    path_names = [n.removeprefix("final ") for n in names] if trajectories_are_positions else names

    def draw_paths(panel: Axes, traj: np.ndarray, valid: np.ndarray) -> None:
        for b in range(traj.shape[1]):
            n = int(valid[:, b].sum())
            if n == 0:
                continue
            colour = cmap(norm(skills[b]))
            xs, ys = traj[:n, b, dx], traj[:n, b, dy]
            panel.plot(xs, ys, color=colour, linewidth=1.0, alpha=0.8)
            panel.plot(xs[0], ys[0], "o", color=colour, markersize=3)
            panel.plot(xs[-1], ys[-1], "x", color=colour, markersize=6)
        (x0, x1), (y0, y1) = limits or ((low[dx], high[dx]), (low[dy], high[dy]))
        panel.set_xlim(x0, x1)
        panel.set_ylim(y0, y1)
        panel.set_xlabel(path_names[dx])
        panel.set_ylabel(path_names[dy])
        if trajectories_are_positions:
            draw_walls(panel, walls, (dx, dy))

    def name_skills(figure: FigureBase, panels: list[Axes]) -> None:
        if k <= LEGEND_MAX:
            handles = [Line2D([], [], color=cmap(norm(z)), label=str(z)) for z in range(k)]
            panels[-1].legend(handles=handles, title="skill", fontsize=7, title_fontsize=8, loc="best")
            return
        ticks = np.unique(np.linspace(0, k - 1, min(k, 11)).round().astype(int))
        figure.colorbar(ScalarMappable(norm, cmap), ax=panels, label="skill", ticks=ticks)

    def panel_title(name: str) -> str:
        return f"{name}: {kind}" if name else f"{k} skills: {kind}"

    def draw(figure: FigureBase) -> None:
        width = len(evaluations) + (archive is not None)
        axes = list(figure.subplots(1, width, squeeze=False)[0])
        for panel, (name, traj, valid) in zip(axes, evaluations, strict=False):
            draw_paths(panel, traj, valid)
            panel.set_title(panel_title(name))
        name_skills(figure, axes[: len(evaluations)])
        if archive is not None:
            fitnesses = np.asarray(archive.fitnesses, dtype=np.float64)
            shown = fitnesses[np.isfinite(fitnesses)]
            heat = Normalize(*(shown.min(), shown.max()) if shown.size else (0.0, 1.0))
            colours = colormaps["viridis"].with_extremes(bad="white")
            mesh: Any
            if getattr(archive, "grid_shape", None) is not None:
                mesh = _draw_grid(axes[-1], fitnesses, archive.grid_shape, (dx, dy), low, high, colours, heat)
            else:  # CVT cells
                _draw_repertoire(axes[-1], archive, low, high, (dx, dy), heat, colours, names)
                mesh = ScalarMappable(norm=heat, cmap=colours)
            if trajectories_are_positions:
                draw_walls(axes[-1], walls, (dx, dy))
            filled = int(np.sum(fitnesses > -np.inf))
            axes[-1].set_title(f"passive archive: {filled} / {fitnesses.size} cells")
            axes[-1].set_xlabel(names[dx])
            axes[-1].set_ylabel(names[dy])
            figure.colorbar(mesh, ax=axes[-1], label="fitness (return)")

    size = (5.5 * (len(evaluations) + (archive is not None)), 5.0)
    if ax is None:
        return _panels(draw, path, fig, title, size)
    if path is not None:
        _panels(draw, path, None, title, size)
    name, traj, valid = evaluations[0]
    draw_paths(ax, traj, valid)
    name_skills(ax.figure, [ax])
    ax.set_title(title or panel_title(name))
    return ax


def skill_colours(num_skills: int) -> tuple[Colormap, BoundaryNorm]:
    """One colour per skill id (tab10 / tab20's, turbo's beyond 20) and the norm that maps ids to them."""
    if num_skills <= 20:
        base = colormaps["tab10" if num_skills <= 10 else "tab20"]
        cmap: Colormap = ListedColormap([base(i) for i in range(num_skills)])
    else:
        cmap = colormaps["turbo"].resampled(num_skills)
    return cmap, BoundaryNorm(np.arange(num_skills + 1) - 0.5, num_skills)


def _limits(
    evaluations: Sequence[tuple[str, np.ndarray, np.ndarray]], dims: tuple[int, int],
    low: Sequence[float], high: Sequence[float],
) -> tuple[tuple[float, float], tuple[float, float]]:
    """The axes' limits that hold every valid point of every evaluation, with a margin; the
    task's bounds on a dimension where there is no valid point."""
    out = []
    for d in dims:
        points = np.concatenate([traj[..., d][valid > 0] for _, traj, valid in evaluations])
        points = points[np.isfinite(points)]
        if not points.size:
            out.append((float(low[d]), float(high[d])))
            continue
        lo, hi = float(points.min()), float(points.max())
        # 5% margins; a path that does not move on this axis gets 5% of the task's extent.
        pad = 0.05 * (hi - lo) if hi > lo else 0.05 * max(float(high[d]) - float(low[d]), 1e-6)
        out.append((lo - pad, hi + pad))
    return out[0], out[1]
