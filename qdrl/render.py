"""Replays of a run's elites or skills: an HTML viewer or a GIF for brax tasks, a PNG of the path in the mazes.

`render(run, cell, out)` rolls a QD run's elite out through the task's own scoring
(`LoadedRun.rollout`, the stored return bit for bit); `render(run, skill=z)` plays
skill z of a skill-discovery run's agent as the run's last evaluation played it
(skills.csv's return). Either writes

- for brax tasks, an HTML replay of the episode: the robot (and, in ant_maze /
  ant_trap, the walls) at every step. By default one self-contained page that
  fetches nothing (`qdrl.viewer`), with `offline=False` brax's own viewer
  (`brax.io.html`), whose page loads its scripts from CDNs;
- for brax tasks, when `out` ends with `.gif`, a GIF video of the same episode
  (`qdrl.viewer.write_video`: MuJoCo's offscreen renderer on a headless EGL
  context, in real time up to 50 frames a second; RunError where no EGL context
  can be made);
- for point_maze, ant_maze and ant_trap, a PNG of the path (point position or
  torso x-y at every step) over the walls, with the start and the goal.

ant_maze and ant_trap write the PNG by default, the HTML replay when `out` ends
with `.html` and the GIF when it ends with `.gif`. Without a skill, a skill run's PNG
draws every skill's path (one colour per skill, a legend of skill ids) and its HTML
or GIF replay plays skill 0. The rollouts compile inside jax's persistent
compilation cache (`LoadedRun.compiling`): a second render of the run, in a new
process, loads its programs from there.
"""

from __future__ import annotations

import math
import types
from collections.abc import Mapping
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
from qdrl.plotting.skills import skill_colours
from qdrl.runs import LoadedRun, RunError, Trajectory

__all__ = ["render", "write_gif", "write_html", "write_path_png", "write_paths_png"]



def _replayed_env(run: LoadedRun) -> Any:
    """The environment a render replays: a QD run's task's, or the agent's of an RL or skill run."""
    if run.is_qd:
        return run.qd_task.env
    parts = run.run.agent
    if parts is None:
        raise RunError(
            f"render: expected a QD run (an elite's replay) or a run of one agent (SAC, TD3, a skill's); "
            f"this {run.algorithm} run's passive archive stores no genotypes and it has no agent"
        )
    return parts.env


def _kind(run: LoadedRun) -> tuple[str, tuple[str, ...]]:
    """("brax" | "point_maze", the output suffixes this task supports, default first)."""

    env = _replayed_env(run)
    if isinstance(env, PointMazeEnv):
        return "point_maze", (".png",)
    if isinstance(env, BraxEnv):
        return "brax", ((".png", ".html", ".gif") if env.name in WALLED_ENVS else (".html", ".gif"))
    raise RunError(
        f"render: expected a run of a brax task or point_maze, got task {run.task_name!r}"
    )


def _out_path(run: LoadedRun, out: str | Path | None, name: str, suffixes: tuple[str, ...]) -> Path:
    """`out`, or DIR/plots/<name> with the task's default suffix; RunError for a suffix it cannot write."""
    path = Path(out) if out is not None else run.path / "plots" / f"{name}{suffixes[0]}"
    if path.suffix not in suffixes:
        raise RunError(
            f"--out: expected a file ending with {' or '.join(suffixes)} for task {run.task_name!r}, "
            f"got {str(path)!r}"
        )
    return path


def render(
    run: LoadedRun, cell: int | None = None, out: str | Path | None = None, skill: int | None = None,
    offline: bool = True,
) -> dict[str, Any]:
    """Writes the replay of a QD run's elite of `cell` (default: the best), or of a skill-discovery
    run's `skill`, and says what it wrote.

    `out` defaults to `DIR/plots/replay_cell<N>.html` (brax) or `.png` (mazes), for skills
    `replay_skill<Z>.html|png`; its suffix picks the format: `.html` or `.gif` (brax tasks),
    `.png` (mazes). Without `skill`, a skill run's PNG draws every skill's path
    (`replay_skills.png`) and its HTML or GIF replay plays skill 0. Returns {"out",
    "cell", "fitness", "return", "length"} for an elite, {"out", "skill", "return",
    "length"} for one skill, and {"out", "skills", "returns", "lengths"} for every
    skill. RunError for `skill` on a QD run, `cell` on a skill run, or a run that is
    neither. An HTML replay is the self-contained page (`offline`, the default) or
    brax's CDN page (`write_html`); a GIF needs a headless EGL context (`write_gif`).
    """
    kind, suffixes = _kind(run)
    with run.compiling():
        if not run.is_qd:
            if cell is not None:
                k = run.num_skills
                raise RunError(
                    f"--cell: expected a QD run's elite; this {run.algorithm} run replays its agent"
                    + (f": pass --skill Z (0 to {k - 1})" if k else " (no option needed)")
                )
            return _render_skills(run, kind, suffixes, skill, out, offline)
        if skill is not None:
            raise RunError(
                f"--skill: expected a skill-discovery run; this {run.algorithm} run is a QD run: "
                "pass --cell N (default: the best elite)"
            )
        return _render_elite(run, kind, suffixes, cell, out, offline)


def _render_elite(
    run: LoadedRun, kind: str, suffixes: tuple[str, ...], cell: int | None, out: str | Path | None,
    offline: bool = True,
) -> dict[str, Any]:
    elite = run.best() if cell is None else run.elite(cell)
    path = _out_path(run, out, f"replay_cell{elite.cell}", suffixes)
    episode = run.rollout(elite)
    env = run.qd_task.env
    title = f"{run.algorithm} on {run.task_name}, cell {elite.cell}: return {episode.return_:.2f}"
    if path.suffix in (".html", ".gif"):
        _write_replay(env.brax_env, episode, path, offline)
    else:
        _write_maze_png(
            {"path": episode}, path, env, kind, run.qd_task.descriptor_low, run.qd_task.descriptor_high, title
        )
    return {
        "out": str(path), "cell": elite.cell, "fitness": elite.fitness, "return": episode.return_,
        "length": episode.length,
    }


def _render_skills(
    run: LoadedRun, kind: str, suffixes: tuple[str, ...], skill: int | None, out: str | Path | None,
    offline: bool = True,
) -> dict[str, Any]:
    """One skill's replay, or (PNG, no skill) every skill's path on one figure; an agent without
    skills (SAC, TD3): its evaluation's first episode (`replay_agent.png|html`)."""
    if run.num_skills == 0:
        path = _out_path(run, out, "replay_agent", suffixes)
        episode = run.rollout(skill=skill)  # RunError for a skill given
        env = run.require_agent("render").env
        title = f"{run.algorithm} on {run.task_name}: return {episode.return_:.2f}"
        if path.suffix in (".html", ".gif"):
            _write_replay(env.brax_env, episode, path, offline)
        else:
            _write_maze_png({"agent": episode}, path, env, kind, *_bounds(run), title)
        return {"out": str(path), "return": episode.return_, "length": episode.length}
    every = skill is None and (Path(out).suffix if out is not None else suffixes[0]) == ".png"
    path = _out_path(run, out, "replay_skills" if every else f"replay_skill{skill or 0}", suffixes)
    shown = range(run.num_skills) if every else [skill or 0]
    episodes = {z: run.rollout(skill=z) for z in shown}  # one evaluation plays them all
    env = run.require_agent("render").env
    what = f"{run.algorithm} on {run.task_name}"
    if path.suffix in (".html", ".gif"):
        _write_replay(env.brax_env, episodes[skill or 0], path, offline)
    else:
        returns = [e.return_ for e in episodes.values()]
        title = (
            f"{what}: {len(returns)} skills, returns {min(returns):.2f} to {max(returns):.2f}" if every
            else f"{what}, skill {skill}: return {returns[0]:.2f}"
        )
        _write_maze_png({f"skill {z}": e for z, e in episodes.items()}, path, env, kind, *_bounds(run), title)
    if every:
        return {
            "out": str(path), "skills": list(episodes),
            "returns": [e.return_ for e in episodes.values()], "lengths": [e.length for e in episodes.values()],
        }
    ((z, episode),) = episodes.items()
    return {"out": str(path), "skill": z, "return": episode.return_, "length": episode.length}


def _bounds(run: LoadedRun) -> tuple[Any, Any]:
    """The run's descriptor bounds (its passive archive's), the axes of a maze's PNG."""
    space = run.run.descriptor_space
    return (space.low, space.high) if space is not None else ((-1.0, -1.0), (1.0, 1.0))


def _write_maze_png(
    episodes: Mapping[str, Trajectory], path: Path, env: Any, kind: str, low: Any, high: Any, title: str
) -> Path:
    """The episodes' paths over a maze's walls and goal: point_maze's [-1, 1]^2, a brax maze's `low`-`high`."""
    if kind == "point_maze":
        goal = np.asarray(env.goal)
        return write_paths_png(
            episodes, path, env_walls(env), (-1.0, -1.0), (1.0, 1.0), goal=(float(goal[0]), float(goal[1])),
            goal_half_width=float(env.goal_half_width), title=title,
        )
    return write_paths_png(
        episodes, path, env_walls(env), low, high, goal=env.brax_env.target, goal_half_width=0.5, title=title,
    )


def _write_replay(brax_env: Any, episode: Trajectory, path: Path, offline: bool) -> Path:
    """`episode`'s HTML replay or GIF, by `path`'s suffix."""
    if path.suffix == ".gif":
        return write_gif(brax_env.sys, episode, path, brax_env.dt)
    return write_html(brax_env.sys, episode, path, offline)


def _poses(episode: Trajectory) -> Any:
    """The episode's link poses (`state.x`, (T, ...)) up to its end, as numpy arrays."""
    if episode.states is None:
        raise RunError("render: expected an episode rolled out with brax link poses (record)")
    return jax.tree.map(lambda a: np.asarray(a)[: max(episode.length, 1)], episode.states)


def write_gif(sys: Any, episode: Trajectory, path: Path, dt: float) -> Path:
    """A GIF video of `episode` (its link poses) up to its end, `dt` seconds a step (the env's `dt`).

    Real time up to 50 frames a second (GIF's fastest), every k-th step beyond it.
    RunError where MuJoCo can make no headless EGL context (`qdrl.viewer.write_video`).
    """
    from qdrl import viewer

    poses = _poses(episode)
    dt = float(dt)
    stride = max(1, math.ceil(round(0.02 / dt, 6)))  # rounded: 0.02 / 0.01 is 2, not 2.0000000004
    try:
        return viewer.write_video(sys, poses.pos, poses.rot, path, fps=1.0 / (dt * stride), stride=stride)
    except RuntimeError as e:  # no EGL: a one-line error, as for any other render
        raise RunError(f"render: {e}") from e


def write_html(sys: Any, episode: Trajectory, path: Path, offline: bool = True) -> Path:
    """An HTML replay of `episode` (its `states`: link poses, (T, ...)) up to its end.

    `offline` (default): one self-contained page, our own viewer (`qdrl.viewer`),
    that fetches nothing; else brax's viewer page, whose scripts come from CDNs.
    """
    from qdrl import viewer

    # Both viewers read only `state.x` (link positions and rotations) of each state.
    poses = _poses(episode)
    path.parent.mkdir(parents=True, exist_ok=True)
    if offline:
        path.write_text(viewer.replay_html(sys, poses.pos, poses.rot))
        return path
    frames = [
        types.SimpleNamespace(x=jax.tree.map(lambda a, t=t: a[t], poses)) for t in range(len(poses.pos))
    ]
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

    return write_paths_png({"path": episode}, path, walls, low, high, goal, goal_half_width, title)


def write_paths_png(
    episodes: Mapping[str, Trajectory],
    path: Path,
    walls: list[Wall],
    low: Any,
    high: Any,
    goal: tuple[float, float] | None = None,
    goal_half_width: float = 0.0,
    title: str = "",
) -> Path:
    """A PNG of the episodes' x-y paths (their state descriptors) over the walls, seen from above:
    one episode in blue, several in one colour each, named by their keys in the legend."""

    if not episodes:
        raise ValueError("episodes: expected at least one episode to draw")
    paths = {name: np.asarray(e.state_descriptors)[: e.length + 1, :2] for name, e in episodes.items()}
    points = np.concatenate(list(paths.values()))
    lo = np.minimum(np.asarray(low, float)[:2], points.min(axis=0))
    hi = np.maximum(np.asarray(high, float)[:2], points.max(axis=0))
    pad = 0.03 * (hi - lo)
    aspect = float(np.clip((hi[1] - lo[1]) / (hi[0] - lo[0]), 0.4, 1.5))
    fig = Figure(figsize=(6.0, 1.0 + 5.0 * aspect), layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    draw_walls(ax, walls)
    if goal is not None:
        w = goal_half_width
        ax.add_patch(Rectangle((goal[0] - w, goal[1] - w), 2 * w, 2 * w, color="tab:red", alpha=0.6, label="goal"))
    if len(paths) == 1:
        (xy,) = paths.values()
        ax.plot(xy[:, 0], xy[:, 1], color="tab:blue", linewidth=1.5, label=next(iter(paths)))
        ax.plot(*xy[0], "o", color="tab:green", label="start")
        ax.plot(*xy[-1], "X", color="tab:blue", markersize=9, label="end")
    else:
        cmap, norm = skill_colours(len(paths))
        for i, (name, xy) in enumerate(paths.items()):
            colour = cmap(norm(i))
            ax.plot(xy[:, 0], xy[:, 1], color=colour, linewidth=1.5, label=name)
            ax.plot(*xy[0], "o", color=colour, markersize=4)
            ax.plot(*xy[-1], "X", color=colour, markersize=8)
    ax.set_xlim(lo[0] - pad[0], hi[0] + pad[0])
    ax.set_ylim(lo[1] - pad[1], hi[1] + pad[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.legend(loc="best", fontsize=8, ncols=1 + (len(paths) - 1) // 12)
    if title:
        ax.set_title(title, fontsize=10)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    return path
