"""Replays of a run's elites: an HTML viewer for brax tasks, a PNG of the path in the mazes.

`render(run, cell, out)` rolls the elite out through the task's own scoring
(`LoadedRun.rollout`, the stored return bit for bit) and writes

- for brax tasks, brax's own HTML viewer (`brax.io.html`) of the episode: the
  robot (and, in ant_maze / ant_trap, the walls) at every step. The page loads
  brax's viewer script from its CDN, as brax's own pages do;
- for point_maze, ant_maze and ant_trap, a PNG of the path (point position or
  torso x-y at every step) over the walls, with the start and the goal.

ant_maze and ant_trap write the PNG by default and the HTML replay when `out`
ends with `.html`.
"""

from __future__ import annotations

import types
from pathlib import Path
from typing import Any

import jax
import numpy as np
from brax.io import html
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from qdrl.envs.brax import WALLED_ENVS, BraxEnv
from qdrl.envs.point_maze import PointMazeEnv
from qdrl.plotting import Wall, draw_walls, env_walls
from qdrl.runs import LoadedRun, RunError, Trajectory

__all__ = ["render", "write_html", "write_path_png"]



def _kind(run: LoadedRun) -> tuple[str, tuple[str, ...]]:
    """("brax" | "point_maze", the output suffixes this task supports, default first)."""

    env = run.require_qd("render").task.env
    if isinstance(env, PointMazeEnv):
        return "point_maze", (".png",)
    if isinstance(env, BraxEnv):
        return "brax", ((".png", ".html") if env.name in WALLED_ENVS else (".html",))
    raise RunError(
        f"render: expected a run of a brax task or point_maze, got task {run.task_name!r}"
    )


def render(run: LoadedRun, cell: int | None = None, out: str | Path | None = None) -> dict[str, Any]:
    """Writes the replay of the elite of `cell` (default: the best) and says what it wrote.

    `out` defaults to `DIR/plots/replay_cell<N>.html` (brax) or `.png` (mazes); its
    suffix picks the format where a task has two. Returns {"out", "cell",
    "fitness", "return", "length"}.
    """
    kind, suffixes = _kind(run)
    elite = run.best() if cell is None else run.elite(cell)
    path = Path(out) if out is not None else run.path / "plots" / f"replay_cell{elite.cell}{suffixes[0]}"
    if path.suffix not in suffixes:
        raise RunError(
            f"--out: expected a file ending with {' or '.join(suffixes)} for task {run.task_name!r}, "
            f"got {str(path)!r}"
        )
    episode = run.rollout(elite)
    env = run.qd_task.env
    title = f"{run.algorithm} on {run.task_name}, cell {elite.cell}: return {episode.return_:.2f}"
    if path.suffix == ".html":
        write_html(env.brax_env.sys, episode, path)
    elif kind == "point_maze":
        goal = np.asarray(env.goal)
        write_path_png(
            episode, path, env_walls(env), (-1.0, -1.0), (1.0, 1.0), goal=(float(goal[0]), float(goal[1])),
            goal_half_width=float(env.goal_half_width), title=title,
        )
    else:
        write_path_png(
            episode, path, env_walls(env), run.qd_task.descriptor_low, run.qd_task.descriptor_high,
            goal=env.brax_env.target, goal_half_width=0.5, title=title,
        )
    return {
        "out": str(path), "cell": elite.cell, "fitness": elite.fitness, "return": episode.return_,
        "length": episode.length,
    }


def write_html(sys: Any, episode: Trajectory, path: Path) -> Path:
    """brax's HTML viewer of `episode` (its `states`: link poses, (T, ...)) up to its end."""

    if episode.states is None:
        raise RunError("render: expected an episode rolled out with brax link poses (record)")
    # brax's viewer reads only `state.x` (link positions and rotations) of each state.
    frames = [
        types.SimpleNamespace(x=jax.tree.map(lambda a, t=t: np.asarray(a[t]), episode.states))
        for t in range(max(episode.length, 1))
    ]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(html.render(sys, frames))  # type: ignore[arg-type]
    return path


def write_path_png(
    episode: Trajectory,
    path: Path,
    walls: list[Wall],
    low: Any,
    high: Any,
    goal: tuple[float, float] | None = None,
    goal_half_width: float = 0.0,
    title: str = "",
) -> Path:
    """A PNG of the episode's x-y path (its state descriptors) over the walls, seen from above."""

    xy = np.asarray(episode.state_descriptors)[: episode.length + 1, :2]
    lo = np.minimum(np.asarray(low, float)[:2], xy.min(axis=0))
    hi = np.maximum(np.asarray(high, float)[:2], xy.max(axis=0))
    pad = 0.03 * (hi - lo)
    aspect = float(np.clip((hi[1] - lo[1]) / (hi[0] - lo[0]), 0.4, 1.5))
    fig = Figure(figsize=(6.0, 1.0 + 5.0 * aspect), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    draw_walls(ax, walls)
    if goal is not None:
        w = goal_half_width
        ax.add_patch(Rectangle((goal[0] - w, goal[1] - w), 2 * w, 2 * w, color="tab:red", alpha=0.6, label="goal"))
    ax.plot(xy[:, 0], xy[:, 1], color="tab:blue", linewidth=1.5, label="path")
    ax.plot(*xy[0], "o", color="tab:green", label="start")
    ax.plot(*xy[-1], "X", color="tab:blue", markersize=9, label="end")
    ax.set_xlim(lo[0] - pad[0], hi[0] + pad[0])
    ax.set_ylim(lo[1] - pad[1], hi[1] + pad[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.legend(loc="best", fontsize=8)
    if title:
        ax.set_title(title, fontsize=10)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    return path
