"""Point maze: exact wall collisions, the detour to the goal, and the QD task on policies."""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.envs.base import reset_batch, step_batch
from qdrl.envs.point_maze import QDAX_GOAL, PointMazeEnv, segments_intersect
from qdrl.qd.emitters.ga import isoline_emitter
from qdrl.qd.map_elites import MapElites
from qdrl.qd.repertoires import grid_repertoire
from qdrl.rollout import run_episodes
from qdrl.tasks.point_maze import point_maze

ENV = PointMazeEnv(episode_length=100)
LOWER_Y, UPPER_Y = -0.5, 0.2


@pytest.mark.parametrize(
    ("p1", "p2", "q1", "q2", "expected"),
    [
        ((0, -1), (0, 1), (-1, 0), (1, 0), True),  # proper crossing
        ((0, -1), (0, 0), (-1, 0), (1, 0), True),  # ends on the segment
        ((1, -1), (1, 1), (-1, 0), (1, 0), True),  # through its end point
        ((1.01, -1), (1.01, 1), (-1, 0), (1, 0), False),  # just past its end
        ((-1, 0.1), (1, 0.1), (-1, 0), (1, 0), False),  # parallel
        ((0.5, 0), (2, 0), (-1, 0), (1, 0), True),  # collinear, overlapping
        ((1.5, 0), (2, 0), (-1, 0), (1, 0), False),  # collinear, disjoint
        ((0.3, 0), (0.3, 0), (-1, 0), (1, 0), True),  # a point on it
        ((0.3, 0.01), (0.3, 0.01), (-1, 0), (1, 0), False),  # a point off it
        ((0, 0.5), (0.5, 0.0), (0, 0), (1, 1), True),  # crossing a diagonal
    ],
)
def test_segments_intersect(p1, p2, q1, q2, expected: bool) -> None:  # type: ignore[no-untyped-def]
    args = [jnp.asarray(p, jnp.float32) for p in (p1, p2, q1, q2)]
    assert bool(segments_intersect(*args)) is expected
    # symmetric in the two segments and in their end points
    assert bool(segments_intersect(args[3], args[2], args[1], args[0])) is expected


def test_straight_up_is_stopped_by_the_lower_wall() -> None:
    state = jax.jit(lambda k: reset_batch(ENV, k, 16))(jax.random.PRNGKey(0))
    start = np.asarray(state.desc)
    assert np.all((np.abs(start[:, 0]) <= 0.1) & (start[:, 1] >= -1.0) & (start[:, 1] <= -0.7))
    step = jax.jit(lambda s: step_batch(ENV, s, jnp.tile(jnp.array([0.0, 1.0]), (16, 1))))
    ys = []
    for _ in range(15):
        state = step(state)
        ys.append(np.asarray(state.desc[:, 1]))
    ys_arr = np.stack(ys)
    assert np.all(ys_arr < LOWER_Y)  # never on or past the wall
    assert np.all(ys_arr[-1] > LOWER_Y - 0.1)  # it got right under it
    np.testing.assert_allclose(np.asarray(state.desc[:, 0]), start[:, 0])  # x never moved
    np.testing.assert_allclose(
        np.asarray(state.reward),
        -np.linalg.norm(state.desc - np.asarray(QDAX_GOAL), axis=1),
        rtol=1e-6,
    )


def test_random_moves_cross_walls_only_beyond_their_ends() -> None:
    def policy(obs: jax.Array, key: jax.Array) -> jax.Array:
        return jax.random.uniform(key, obs.shape, minval=-1.0, maxval=1.0)

    # starting anywhere, so that every side of both walls gets visited
    env = PointMazeEnv(episode_length=100, start_low=(-1.0, -1.0), start_high=(1.0, 1.0))
    episodes = jax.jit(lambda k: run_episodes(env, policy, k, 256))(jax.random.PRNGKey(1))
    old = np.asarray(episodes.transitions.desc).reshape(-1, 2)
    new = np.asarray(episodes.transitions.next_desc).reshape(-1, 2)
    assert np.all(np.abs(new) <= 1.0)
    for wall_y, blocked in ((LOWER_Y, lambda x: x >= -0.5), (UPPER_Y, lambda x: x <= 0.5)):
        crosses = (old[:, 1] - wall_y) * (new[:, 1] - wall_y) <= 0
        moved = np.any(old != new, axis=1)
        idx = crosses & moved & (old[:, 1] != new[:, 1])
        t = (wall_y - old[idx, 1]) / (new[idx, 1] - old[idx, 1])
        x_at_wall = old[idx, 0] + t * (new[idx, 0] - old[idx, 0])
        assert idx.sum() > 10  # random walks do go past both wall heights
        assert not np.any(blocked(x_at_wall))
    # and some moves were cancelled by the walls
    assert np.sum(np.all(old == new, axis=1)) > 10


def detour_policy(obs: jax.Array, key: jax.Array) -> jax.Array:
    """Left round the lower wall, right round the upper one, then straight to the goal."""
    del key
    x, y = obs[:, 0], obs[:, 1]
    below = y < LOWER_Y
    between = (y >= LOWER_Y) & (y < UPPER_Y)
    left_or_up = jnp.where(x[:, None] > -0.7, jnp.array([-1.0, 0.0]), jnp.array([0.0, 1.0]))
    right_or_up = jnp.where(x[:, None] < 0.7, jnp.array([1.0, 0.0]), jnp.array([0.0, 1.0]))
    to_goal = jnp.clip((jnp.asarray(QDAX_GOAL) - obs) / 0.1, -1.0, 1.0)
    return jnp.where(below[:, None], left_or_up, jnp.where(between[:, None], right_or_up, to_goal))


def test_a_detour_reaches_the_goal_and_beats_going_straight_up() -> None:
    def straight_up(obs: jax.Array, key: jax.Array) -> jax.Array:
        return jnp.tile(jnp.array([0.0, 1.0]), (obs.shape[0], 1))

    key = jax.random.PRNGKey(2)
    detour = jax.jit(lambda k: run_episodes(ENV, detour_policy, k, 8))(key)
    up = jax.jit(lambda k: run_episodes(ENV, straight_up, k, 8))(key)
    assert np.all(np.asarray(detour.lengths) < 100)  # terminated in the goal zone
    final = np.asarray(detour.final_desc)
    assert np.all(np.abs(final - np.asarray(QDAX_GOAL)) <= 0.05 + 1e-6)
    last = np.asarray(detour.lengths) - 1
    assert np.all(np.asarray(detour.transitions.terminated)[last, np.arange(8)] == 1.0)
    assert np.all(np.asarray(up.lengths) == 100)
    assert np.all(np.asarray(up.final_desc)[:, 1] < LOWER_Y)
    assert np.all(np.asarray(detour.returns) > np.asarray(up.returns) + 50.0)


def test_point_maze_task_scores_policies_and_runs_map_elites() -> None:
    task = point_maze(episode_length=50, policy_hidden=(16,))
    assert task.qd_offset == pytest.approx(-2 * math.sqrt(2) * 50)
    assert (task.descriptor_low, task.descriptor_high) == ((-1.0, -1.0), (1.0, 1.0))
    genotypes = task.init_genotypes(jax.random.PRNGKey(0), 32)
    assert task.genotype_size == 2 * 16 + 16 + 16 * 2 + 2
    repertoire = grid_repertoire(task.example_genotype(), (8, 8), -1.0, 1.0)
    me = MapElites(task.scoring_fn, isoline_emitter(32, 0.005, 0.05), repertoire, task.qd_offset)

    @jax.jit
    def init_and_run(genotypes, key):  # type: ignore[no-untyped-def]
        start = me.init(genotypes, key)
        return start.repertoire.num_filled, *me.run(start, 10)

    start_filled, state, metrics = init_and_run(genotypes, jax.random.PRNGKey(1))
    assert 0 < int(state.env_steps) <= 32 * 11 * 50  # episodes may end at the goal
    assert np.all(np.diff(np.asarray(metrics["qd_score"])) >= 0)
    assert int(state.repertoire.num_filled) > int(start_filled)
    filled = np.asarray(state.repertoire.filled)
    fit = np.asarray(state.repertoire.fitnesses)[filled]
    desc = np.asarray(state.repertoire.descriptors)[filled]
    assert np.all((fit <= 0.0) & (fit >= task.qd_offset))
    assert np.all(np.abs(desc) <= 1.0)


def test_argument_checks_and_an_open_arena() -> None:
    with pytest.raises(ValueError, match="episode_length"):
        PointMazeEnv(episode_length=0)
    with pytest.raises(ValueError, match="walls"):
        PointMazeEnv(walls=(((0.0, 0.0, 1.0), (1.0, 1.0, 1.0)),))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="start_low"):
        PointMazeEnv(start_low=(0.5, 0.0), start_high=(0.0, 0.0))
    # without walls nor termination, heading for the goal parks the point on it
    env = PointMazeEnv(episode_length=30, walls=(), terminate_at_goal=False)
    to_goal = lambda obs, key: jnp.clip((jnp.asarray(QDAX_GOAL) - obs) / 0.1, -1, 1)  # noqa: E731
    episodes = jax.jit(lambda k: run_episodes(env, to_goal, k, 4))(jax.random.PRNGKey(0))
    np.testing.assert_array_equal(np.asarray(episodes.lengths), 30)
    np.testing.assert_allclose(
        np.asarray(episodes.final_desc), np.tile(QDAX_GOAL, (4, 1)), atol=1e-6
    )


def test_a_task_traces_its_rollout_once_per_block_shape(monkeypatch: pytest.MonkeyPatch) -> None:
    """A run's step reuses the trace of the initial evaluation's rollout (same block shape):
    two separately jitted evaluations trace the environment loop once, and give equal scores."""
    import qdrl.tasks.policy as policy

    calls: list[int] = []
    real = policy.run_episodes

    def counting(*args: Any, **kwargs: Any) -> Any:
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(policy, "run_episodes", counting)
    task = point_maze(episode_length=5, policy_hidden=(4,), eval_batch=4)
    genotypes = task.init_genotypes(jax.random.PRNGKey(0), 8)  # two blocks of 4
    key = jax.random.PRNGKey(1)
    first = jax.jit(lambda g, k: task.scoring_fn(g, k))(genotypes, key)
    second = jax.jit(lambda g, k: task.scoring_fn(g, k).fitnesses)(genotypes, key)
    assert len(calls) == 1
    np.testing.assert_array_equal(np.asarray(first.fitnesses), np.asarray(second))
