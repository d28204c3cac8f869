"""Ant maze and ant trap: brax's ant among static walls, rebuilt on today's brax.

QDax defined both on brax.v1 (gone since brax 0.12.4) by appending frozen capsule
colliders to the ant's protobuf config (`qdax/environments/exploration_wrappers.py`:
`TRAP_CONFIG`, `MAZE_CONFIG`, `TrapWrapper`, `MazeWrapper`; Chalumeau, Lim et al.
2023; the maze follows Pierrot et al. 2022, "Diversity policy gradient for sample
efficient quality-diversity optimization"). Here the same capsules are static geoms
of the MJCF world body, added to brax's `ant.xml` and loaded with `brax.io.mjcf`:

- brax.v1 capsule `length` counts both end caps, so a v1 capsule of length L and
  radius r centred at c along axis u is the MJCF capsule `fromto = c -/+ (L/2 - r) u`.
- v1 collided the walls with the torso and the four lower legs (`collide_include`).
  In brax's MJCF ant only the foot spheres collide (contype 1, with the floor's
  conaffinity 1); the walls get conaffinity 3 and the torso contype 2, so feet and
  torso hit the walls while the torso still does not collide with the floor.
- Both envs prepend the torso x-y, normalised by the arena limits, to the ant's
  observation, as QDax's wrappers do: policies need it to find their way.

AntTrap: a U of three walls in front of the ant, opening towards it: a wall across
the x axis at x = 12 (|y| <= 2.5) and two walls along it at y = +-3 (6.5 <= x <=
12.5). Reward: the ant's own (forward velocity + survival - control cost).
Descriptor bounds in QDax: [0, 30] x [-8, 8].

AntMaze: a square arena [-5, 40]^2 with three inner walls; the target sits at
(35, 0), behind a wall at x = 20 that the ant, starting at the origin, must go
around (up past y = 19.5, then down). Reward: minus the x-y distance to the target
at every step. The ant terminates only when its torso leaves z in [0.2, 5] (QDax
raised brax's upper bound of 1 so that the ant does not end its episode by
jumping). Descriptor bounds in QDax: [-5, 40]^2.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any
from xml.etree import ElementTree

import jax
import jax.numpy as jnp
from brax.envs.ant import Ant
from brax.envs.base import State
from brax.io import mjcf
from etils import epath

from qdrl.types import Array

WALL_HEIGHT = 0.5  # capsule axes lie at z = 0.5 (radius 0.5: walls 1 m high), as in QDax


@dataclasses.dataclass(frozen=True)
class Wall:
    """A capsule lying on the ground: its axis runs from `start` to `end` (x-y) at z = 0.5."""

    start: tuple[float, float]
    end: tuple[float, float]
    radius: float = 0.5


def v1_capsule(center: tuple[float, float], axis: str, length: float, radius: float = 0.5) -> Wall:
    """The wall of a brax.v1 capsule collider: `length` includes the end caps."""
    half = length / 2.0 - radius
    cx, cy = center
    if axis == "x":
        return Wall((cx - half, cy), (cx + half, cy), radius)
    if axis == "y":
        return Wall((cx, cy - half), (cx, cy + half), radius)
    raise ValueError(f"axis: expected 'x' or 'y', got {axis!r}")


# QDax TRAP_CONFIG: v1 rotation {x: 90} lays the capsule along y, {y: 90} along x.
TRAP_WALLS = (
    v1_capsule((12.0, 0.0), "y", 5.0),
    v1_capsule((9.5, 3.0), "x", 6.0),
    v1_capsule((9.5, -3.0), "x", 6.0),
)
TRAP_XY_CENTER = (15.0, 0.0)  # QDax normalises the observed x-y by these
TRAP_XY_SCALE = (15.0, 8.0)

# QDax MAZE_CONFIG: four outer walls, then three inner ones.
MAZE_WALLS = (
    v1_capsule((17.5, -5.0), "x", 46.0),
    v1_capsule((17.5, 40.0), "x", 46.0),
    v1_capsule((-5.0, 17.5), "y", 44.0),
    v1_capsule((40.0, 17.5), "y", 44.0),
    v1_capsule((20.0, 7.5), "y", 24.0),
    v1_capsule((15.0, 7.5), "x", 9.0),
    v1_capsule((10.0, 30.0), "y", 19.5),
)
MAZE_TARGET = (35.0, 0.0)
MAZE_XY_CENTER = (17.5, 17.5)
MAZE_XY_SCALE = (22.5, 22.5)
MAZE_HEALTHY_Z = (0.2, 5.0)


def ant_xml_with_walls(walls: Sequence[Wall], target: tuple[float, float] | None = None) -> str:
    """brax's ant MJCF with `walls` as static capsules (and a visual-only target sphere)."""
    path = epath.resource_path("brax") / "envs/assets/ant.xml"
    root = ElementTree.fromstring(path.read_text())
    world = root.find("worldbody")
    torso_geom = root.find(".//geom[@name='torso_geom']")
    if world is None or torso_geom is None:
        raise RuntimeError("brax's ant.xml has changed: no worldbody or no torso_geom")
    torso_geom.set("contype", "2")
    # after the floor, before the ant: walls are geoms of the world body (link -1)
    position = next(i for i, e in enumerate(world) if e.tag == "body")
    for i, wall in enumerate(walls):
        (x0, y0), (x1, y1) = wall.start, wall.end
        geom = ElementTree.Element(
            "geom",
            name=f"wall_{i}",
            type="capsule",
            fromto=f"{x0} {y0} {WALL_HEIGHT} {x1} {y1} {WALL_HEIGHT}",
            size=f"{wall.radius}",
            contype="0",
            conaffinity="3",
            rgba="0.6 0.6 0.7 1",
        )
        world.insert(position, geom)
        position += 1
    if target is not None:
        geom = ElementTree.Element(
            "geom",
            name="target",
            type="sphere",
            pos=f"{target[0]} {target[1]} 0.5",
            size="0.5",
            contype="0",
            conaffinity="0",
            rgba="0.9 0.1 0.1 1",
        )
        world.insert(position, geom)
    return ElementTree.tostring(root, encoding="unicode")


def walled_system(ant_sys: Any, walls: Sequence[Wall], target: tuple[float, float] | None) -> Any:
    """The brax system of the ant among `walls`, with the solver options and actuators of `ant_sys`.

    brax's `Ant` tunes its system per backend (time step, mjx solver, positional
    gears); copying `opt` and `actuator` from the system it built keeps that tuning.
    """
    sys = mjcf.loads(ant_xml_with_walls(walls, target))
    return sys.replace(opt=ant_sys.opt, actuator=ant_sys.actuator)


class _WalledAnt(Ant):
    """brax's ant among walls, observing its normalised torso x-y first."""

    walls: tuple[Wall, ...] = ()
    target: tuple[float, float] | None = None
    xy_center: tuple[float, float] = (0.0, 0.0)
    xy_scale: tuple[float, float] = (1.0, 1.0)

    def __init__(self, backend: str = "spring", **kwargs: Any) -> None:
        super().__init__(backend=backend, **kwargs)
        ant_sys: Any = self.sys  # type: ignore[has-type]  # brax's ant system, tuned for `backend`
        self.sys = walled_system(ant_sys, self.walls, self.target)

    def _with_xy(self, state: State) -> State:
        xy = state.pipeline_state.x.pos[0, :2]
        xy = (xy - jnp.asarray(self.xy_center)) / jnp.asarray(self.xy_scale)
        return state.replace(obs=jnp.concatenate([xy, state.obs]))

    def reset(self, rng: jax.Array) -> State:
        return self._with_xy(super().reset(rng))

    def step(self, state: State, action: jax.Array) -> State:
        return self._with_xy(super().step(state, action))


class AntTrap(_WalledAnt):
    """QDax's AntTrap: a U-shaped trap in front of the ant; the ant's own reward."""

    walls = TRAP_WALLS
    xy_center = TRAP_XY_CENTER
    xy_scale = TRAP_XY_SCALE


class AntMaze(_WalledAnt):
    """QDax's AntMaze: a walled arena and a target; reward = -distance to the target."""

    walls = MAZE_WALLS
    target = MAZE_TARGET
    xy_center = MAZE_XY_CENTER
    xy_scale = MAZE_XY_SCALE

    def __init__(
        self,
        backend: str = "spring",
        healthy_z_range: tuple[float, float] = MAZE_HEALTHY_Z,
        **kwargs: Any,
    ) -> None:
        super().__init__(backend=backend, healthy_z_range=healthy_z_range, **kwargs)

    def _distance(self, state: State) -> Array:
        xy = state.pipeline_state.x.pos[0, :2]
        return jnp.linalg.norm(xy - jnp.asarray(MAZE_TARGET))

    def reset(self, rng: jax.Array) -> State:
        state = super().reset(rng)
        distance = self._distance(state)
        state.metrics["distance_to_target"] = distance
        return state.replace(reward=-distance)

    def step(self, state: State, action: jax.Array) -> State:
        state = super().step(state, action)
        distance = self._distance(state)
        state.metrics["distance_to_target"] = distance
        return state.replace(reward=-distance)
