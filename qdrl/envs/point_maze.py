"""Point maze: a pure-JAX point in [-1, 1]^2 that must detour around two walls to a goal.

The deceptive maze of QD-PG (Pierrot et al. 2022, "Diversity policy gradient for
sample efficient quality-diversity optimization") and QDax's `PointMaze`
(`qdax/environments/pointmaze.py`, Flageat et al.), with QDax's geometry:

- arena [-1, 1]^2; the action a in [-1, 1]^2 moves the point by a / 10 (QDax
  `scale_action_space=10`), then the new position is clipped to the arena;
- start: x ~ U(-0.1, 0.1), y ~ U(-1, -0.7) (bottom middle);
- lower wall: the segment y = -0.5, x in [-0.5, 1] (attached to the right side);
- upper wall: the segment y = 0.2, x in [-1, 0.5] (attached to the left side);
- goal: the square zone of side 0.1 centred on (-0.5, 0.8) (top left). The
  episode terminates when the point is inside it (QDax's `done`).

The reward is minus the distance to the goal centre, so heading straight for the
goal leads into the lower wall: the path goes left round the lower wall, right
round the upper wall, then left to the goal. The observation and the state
descriptor are the x-y position.

One difference from QDax: a move whose segment (from the old to the clipped new
position) touches a wall is cancelled and the point stays where it was, instead
of QDax's sliding onto the wall's face. The test is an exact closed segment
intersection (`segments_intersect`), so no step, however placed, crosses a wall,
and the point never rests on one (QDax's walls are 0.01 thick; ours are
segments).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from qdrl.envs.base import Env
from qdrl.types import Array, PRNGKey

Segment = tuple[tuple[float, float], tuple[float, float]]

# QDax PointMaze defaults: wall width 0.75 x arena width, lower wall at y = -0.5
# on the right, upper wall at y = 0.2 on the left.
QDAX_WALLS: tuple[Segment, ...] = (
    ((-0.5, -0.5), (1.0, -0.5)),
    ((-1.0, 0.2), (0.5, 0.2)),
)
QDAX_GOAL = (-0.5, 0.8)
QDAX_START_LOW = (-0.1, -1.0)
QDAX_START_HIGH = (0.1, -0.7)


def _orientation(a: Array, b: Array, c: Array) -> Array:
    """Sign of the cross product (b - a) x (c - a): +1 left turn, -1 right turn, 0 collinear."""
    cross = (b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (
        c[..., 0] - a[..., 0]
    )
    return jnp.sign(cross)


def segments_intersect(p1: Array, p2: Array, q1: Array, q2: Array) -> Array:
    """Whether the closed segments [p1, p2] and [q1, q2] share a point (touching counts).

    Points are (..., 2) arrays and broadcast against each other. Each segment's
    end points must lie on both sides of (or on) the other segment's line, and the
    bounding boxes must overlap; the box test settles the collinear case,
    degenerate (zero-length) segments included.
    """
    o1 = _orientation(p1, p2, q1)
    o2 = _orientation(p1, p2, q2)
    o3 = _orientation(q1, q2, p1)
    o4 = _orientation(q1, q2, p2)
    boxes_overlap = jnp.all(
        (jnp.minimum(p1, p2) <= jnp.maximum(q1, q2)) & (jnp.minimum(q1, q2) <= jnp.maximum(p1, p2)),
        axis=-1,
    )
    return (o1 * o2 <= 0) & (o3 * o4 <= 0) & boxes_overlap


class PointMazeEnv(Env):
    """Point maze of QD-PG / QDax; observation = state descriptor = (x, y)."""

    def __init__(
        self,
        episode_length: int = 100,
        walls: Sequence[Segment] = QDAX_WALLS,
        goal: tuple[float, float] = QDAX_GOAL,
        goal_half_width: float = 0.05,
        step_size: float = 0.1,
        start_low: tuple[float, float] = QDAX_START_LOW,
        start_high: tuple[float, float] = QDAX_START_HIGH,
        terminate_at_goal: bool = True,
    ) -> None:
        if episode_length <= 0:
            raise ValueError(f"episode_length must be a positive integer, got {episode_length}")
        wall_array = (
            np.asarray(walls, np.float32) if len(walls) else np.zeros((0, 2, 2), np.float32)
        )
        if wall_array.ndim != 3 or wall_array.shape[1:] != (2, 2):
            raise ValueError(f"walls: expected a sequence of ((x0, y0), (x1, y1)), got {walls}")
        if not all(lo <= hi for lo, hi in zip(start_low, start_high, strict=True)):
            raise ValueError(f"start_low {start_low} must not exceed start_high {start_high}")
        self.name = "point_maze"
        self.episode_length = episode_length
        self.action_size = 2
        self.walls = jnp.asarray(wall_array)  # (W, 2 ends, 2 coordinates)
        self.goal = jnp.asarray(goal, jnp.float32)
        self.goal_half_width = goal_half_width
        self.step_size = step_size
        self.start_low = jnp.asarray(start_low, jnp.float32)
        self.start_high = jnp.asarray(start_high, jnp.float32)
        self.terminate_at_goal = terminate_at_goal

    def blocked(self, old: Array, new: Array) -> Array:
        """Whether the move from `old` to `new` (each (2,)) touches any wall."""
        hits = segments_intersect(old, new, self.walls[:, 0], self.walls[:, 1])
        return jnp.any(hits)

    def in_goal(self, pos: Array) -> Array:
        """Whether `pos` lies in the goal zone (a square of half-width `goal_half_width`)."""
        return jnp.all(jnp.abs(pos - self.goal) <= self.goal_half_width)

    def _reset(self, key: PRNGKey) -> tuple[Any, Array, Array]:
        pos = jax.random.uniform(key, (2,), minval=self.start_low, maxval=self.start_high)
        return pos, pos, pos

    def _step(self, inner: Any, action: Array) -> tuple[Any, Array, Array, Array, Array]:
        old = inner
        new = jnp.clip(old + self.step_size * action, -1.0, 1.0)
        pos = jnp.where(self.blocked(old, new), old, new)
        reward = -jnp.linalg.norm(pos - self.goal)
        terminated = jnp.logical_and(self.terminate_at_goal, self.in_goal(pos))
        return pos, pos, reward, terminated.astype(jnp.float32), pos
