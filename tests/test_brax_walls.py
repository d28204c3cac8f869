"""The walled ants: QDax's trap and maze geometry, and walls that stop a thrown ant (spring)."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.envs.brax import brax_env_names, make_brax_env
from qdrl.envs.brax_walls import (
    MAZE_WALLS,
    TRAP_WALLS,
    Wall,
    ant_xml_with_walls,
    v1_capsule,
)

FAST_COMPILE: dict[str, Any] = {
    "xla_backend_optimization_level": 0,
    "xla_llvm_disable_expensive_passes": True,
}


def test_walls_follow_qdax_v1_capsules() -> None:
    # v1 capsule lengths include both end caps of radius 0.5
    assert v1_capsule((12.0, 0.0), "y", 5.0) == Wall((12.0, -2.0), (12.0, 2.0), 0.5)
    assert v1_capsule((9.5, 3.0), "x", 6.0) == Wall((7.0, 3.0), (12.0, 3.0), 0.5)
    with pytest.raises(ValueError, match="axis"):
        v1_capsule((0.0, 0.0), "z", 1.0)
    # the trap: a U opening towards the ant (at the origin), its back wall across x = 12
    back, left, right = TRAP_WALLS
    assert back.start[0] == back.end[0] == 12.0
    assert left.start[1] == left.end[1] == 3.0 and right.start[1] == right.end[1] == -3.0
    assert max(left.end[0], right.end[0]) == 12.0 and min(left.start[0], right.start[0]) == 7.0
    # the maze: its outer walls close the square [-5, 40]^2
    xs = [c for w in MAZE_WALLS[:4] for c in (w.start[0], w.end[0])]
    ys = [c for w in MAZE_WALLS[:4] for c in (w.start[1], w.end[1])]
    assert (min(xs), max(xs), min(ys), max(ys)) == (-5.0, 40.0, -5.0, 40.0)
    xml = ant_xml_with_walls(TRAP_WALLS, target=(1.0, 2.0))
    assert xml.count('name="wall_') == 3 and 'name="target"' in xml


@pytest.mark.filterwarnings("ignore:Accessing `ncon`:DeprecationWarning")
def test_walled_systems_keep_the_ant_and_add_wall_contacts() -> None:
    from brax import envs
    from mujoco import mjx

    assert {"antmaze", "anttrap"} <= set(brax_env_names())
    ant = envs.get_environment("ant", backend="spring")
    for name, walls in (("anttrap", TRAP_WALLS), ("antmaze", MAZE_WALLS)):
        env = make_brax_env(name, "spring")
        assert list(env.sys.link_names) == list(ant.sys.link_names)
        assert env.action_size == ant.action_size == 8
        assert float(env.sys.opt.timestep) == float(ant.sys.opt.timestep)
        np.testing.assert_array_equal(env.sys.actuator.gear, ant.sys.actuator.gear)
        # 4 foot-floor pairs, then 4 feet and the torso against every wall
        assert mjx.make_data(env.sys).ncon == 4 + 5 * len(walls)


def _throw(name: str, starts: list[tuple[float, float]]) -> np.ndarray:
    """Torso x of ants thrown along +x at 10 m/s from 0.9 m high, zero action, 40 steps."""
    env = make_brax_env(name, "spring")

    def run(start: jax.Array) -> jax.Array:
        q = env.sys.init_q.at[:2].set(start).at[2].set(0.9)
        qd = jnp.zeros(env.sys.qd_size()).at[0].set(10.0)

        def body(ps, _):  # type: ignore[no-untyped-def]
            ps = env.pipeline_step(ps, jnp.zeros(env.action_size))
            return ps, ps.x.pos[0, 0]

        return jax.lax.scan(body, env.pipeline_init(q, qd), None, 40)[1]

    starts_array = jnp.asarray(starts)
    compiled = jax.jit(jax.vmap(run)).lower(starts_array).compile(FAST_COMPILE)
    return np.asarray(compiled(starts_array))


def test_the_trap_stops_an_ant_thrown_into_it() -> None:
    # into the trap, towards its back wall (x = 12 - 0.5), and past it at y = 6
    x = _throw("anttrap", [(9.0, 0.0), (9.0, 6.0)])
    assert x[0].max() < 11.5
    assert x[1].max() > 12.5


@pytest.mark.slow  # the same walls as the trap's (ant_xml_with_walls), another program to compile
def test_the_maze_stops_an_ant_thrown_at_a_wall() -> None:
    # towards the inner wall x = 20 (|y| <= 19.5), and past its end at y = 22
    x = _throw("antmaze", [(17.0, 0.0), (17.0, 22.0)])
    assert x[0].max() < 19.5
    assert x[1].max() > 20.5
