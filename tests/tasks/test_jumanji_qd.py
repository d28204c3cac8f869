"""Jumanji adapter and Snake QD task: batched stepping, fitness = fruits eaten, MAP-Elites."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.envs.base import auto_reset, reset_batch, step_batch
from qdrl.envs.jumanji import JumanjiEnv, action_frequencies, masked_argmax, snake_env
from qdrl.qd.emitters.ga import isoline_emitter
from qdrl.qd.map_elites import MapElites
from qdrl.qd.repertoires import grid_repertoire
from qdrl.rollout import run_episodes
from qdrl.tasks.jumanji_qd import jumanji_task, snake

ROWS = COLS = 12
ENV = snake_env(episode_length=100)
UP = jnp.array([1.0, 0.0, 0.0, 0.0])  # up, right, down, left


def board(obs: jax.Array) -> jax.Array:
    """(..., rows, cols, 5) feature maps: body, head, tail, fruit, body order."""
    return obs[..., : ROWS * COLS * 5].reshape(*obs.shape[:-1], ROWS, COLS, 5)


def cell(plane: jax.Array) -> jax.Array:
    """(row, col) of the cell set in a (..., rows, cols) one-hot plane."""
    flat = jnp.argmax(plane.reshape(*plane.shape[:-2], -1), axis=-1)
    return jnp.stack([flat // COLS, flat % COLS], axis=-1)


def greedy(obs: jax.Array, key: jax.Array) -> jax.Array:
    """Prefers the move that brings the head closest (Manhattan) to the fruit."""
    del key
    grid = board(obs)
    head, fruit = cell(grid[..., 1]), cell(grid[..., 3])
    moves = jnp.array([[-1, 0], [0, 1], [1, 0], [0, -1]])  # up, right, down, left
    dist = jnp.abs(head[..., None, :] + moves - fruit[..., None, :]).sum(-1)
    return -dist / (ROWS + COLS)


def fruits_eaten(episodes) -> np.ndarray:  # type: ignore[no-untyped-def]
    """Counted from the boards alone: steps whose new head cell held the fruit."""
    tr = episodes.transitions
    head_after = cell(board(tr.next_obs)[..., 1])
    fruit_before = cell(board(tr.obs)[..., 3])
    ate = jnp.all(head_after == fruit_before, axis=-1) & (tr.terminated == 0)
    return np.asarray(jnp.sum(ate * episodes.mask, axis=0))


def test_sizes_and_argument_checks() -> None:
    assert (ENV.observation_size, ENV.action_size, ENV.descriptor_size) == (724, 4, 2)
    assert ENV.jumanji_env.time_limit > ENV.episode_length
    with pytest.raises(ValueError, match="time_limit"):
        JumanjiEnv("Snake-v1", episode_length=4000)
    with pytest.raises(ValueError, match="unknown jumanji environment"):
        JumanjiEnv("Snake-v9")
    with pytest.raises(ValueError, match="only DiscreteArray"):
        JumanjiEnv("Cleaner-v0")
    with pytest.raises(ValueError, match="only used with an environment id"):
        JumanjiEnv(ENV.jumanji_env, time_limit=10)


def test_a_start_seed_fixes_the_starting_board() -> None:
    fixed = snake_env(start_seed=3)
    reset = jax.jit(lambda env_key: reset_batch(fixed, env_key, 4))
    boards = np.asarray(reset(jax.random.PRNGKey(0)).obs)
    np.testing.assert_array_equal(boards, np.asarray(reset(jax.random.PRNGKey(1)).obs))
    assert np.all(boards == boards[0])
    free = np.asarray(jax.jit(lambda k: reset_batch(ENV, k, 4))(jax.random.PRNGKey(0)).obs)
    assert len({row.tobytes() for row in free}) == 4


def test_masked_argmax() -> None:
    a = jnp.array([0.9, 0.5, -0.2, 0.7])
    assert int(masked_argmax(a, None)) == 0
    assert int(masked_argmax(a, jnp.array([False, True, True, True]))) == 3
    assert int(masked_argmax(a, jnp.array([False, False, True, False]))) == 2
    assert int(masked_argmax(a, jnp.zeros(4, bool))) == 0


def test_batched_steps_under_jit_with_auto_reset() -> None:
    n = 32

    @jax.jit
    def run(key: jax.Array):  # type: ignore[no-untyped-def]
        state = reset_batch(ENV, key, n)

        def body(s, k):  # type: ignore[no-untyped-def]
            s = step_batch(ENV, s, jax.random.uniform(k, (n, 4), minval=-1.0, maxval=1.0))
            return auto_reset(ENV, s), (s.desc, s.reward, s.done)

        return jax.lax.scan(body, state, jax.random.split(key, 150))

    state, (desc, reward, done) = run(jax.random.PRNGKey(0))
    desc, reward = np.asarray(desc), np.asarray(reward)
    assert desc.shape == (150, n, 2) and np.all((desc >= 0.0) & (desc <= 1.0))
    assert set(np.unique(reward)) <= {0.0, 1.0} and reward.sum() > 0
    # every env hit the 100-step limit once: it was reset and its episode recorded
    assert np.all(np.asarray(done).sum(axis=0) >= 1)
    assert np.all(np.asarray(state.last_length) >= 1) and np.all(np.isfinite(state.last_return))
    obs = np.asarray(state.obs)
    assert obs.shape == (n, 724) and np.all((obs >= 0.0) & (obs <= 1.0))


GREEDY, RANDOM, ALWAYS_UP = slice(0, 16), slice(16, 32), slice(32, 48)


def mixed_policy(obs: jax.Array, key: jax.Array) -> jax.Array:
    """16 greedy snakes, 16 random ones, 16 that always prefer to go up (one compilation)."""
    uniform = jax.random.uniform(key, (16, 4), minval=-1.0, maxval=1.0)
    return jnp.concatenate([greedy(obs[GREEDY], key), uniform, jnp.tile(UP, (16, 1))])


@pytest.fixture(scope="module")
def mixed():  # type: ignore[no-untyped-def]
    return jax.jit(lambda k: run_episodes(ENV, mixed_policy, k, 48))(jax.random.PRNGKey(1))


def test_return_counts_fruits_and_a_greedy_snake_beats_a_random_one(mixed) -> None:  # type: ignore[no-untyped-def]
    returns = np.asarray(mixed.returns)
    np.testing.assert_array_equal(returns, fruits_eaten(mixed))
    # the fatal step never eats: the reward of terminal steps is 0
    assert float(jnp.sum(mixed.transitions.reward * mixed.transitions.terminated)) == 0
    assert returns[GREEDY].mean() > 5.0
    assert returns[GREEDY].mean() > 3 * returns[RANDOM].mean()
    # a surviving snake is one cell longer per fruit it ate
    alive = np.asarray(mixed.lengths) == 100
    body_cells = np.asarray(board(mixed.transitions.next_obs[-1])[..., 0].sum((-1, -2)))
    np.testing.assert_array_equal(body_cells[alive], 1 + returns[alive])
    assert alive[GREEDY].mean() > 0.5


def test_without_the_mask_a_snake_that_only_goes_up_dies_at_the_wall(mixed) -> None:  # type: ignore[no-untyped-def]
    env = snake_env(episode_length=100, use_action_mask=False)
    policy = lambda obs, key: jnp.tile(UP, (obs.shape[0], 1))  # noqa: E731
    dead = jax.jit(lambda k: run_episodes(env, policy, k, 16))(jax.random.PRNGKey(2))
    rows = np.asarray(cell(board(dead.transitions.obs[0])[..., 1]))[:, 0]
    np.testing.assert_array_equal(np.asarray(dead.lengths), rows + 1)  # row r: r moves, then death
    assert np.all((np.asarray(dead.transitions.terminated) * np.asarray(dead.mask)).sum(0) == 1)
    np.testing.assert_array_equal(np.asarray(dead.returns), fruits_eaten(dead))
    # with the mask the same policy turns at the top wall instead, and lives on
    assert np.all(np.asarray(mixed.lengths)[ALWAYS_UP] > ROWS)


def test_snake_task_and_map_elites() -> None:
    task = snake(episode_length=50, policy_hidden=(16,))
    assert task.qd_offset == 0.0 and task.descriptor_size == 2
    assert task.genotype_size == 724 * 16 + 16 + 16 * 4 + 4
    genotypes = task.init_genotypes(jax.random.PRNGKey(0), 32)
    repertoire = grid_repertoire(task.example_genotype(), (8, 8), (0.0, 0.0), (1.0, 1.0))
    me = MapElites(task.scoring_fn, isoline_emitter(32, 0.005, 0.05), repertoire, task.qd_offset)

    @jax.jit
    def init_and_run(genotypes, key):  # type: ignore[no-untyped-def]
        start = me.init(genotypes, key)
        return start.repertoire.num_filled, *me.run(start, 5)

    start_filled, state, metrics = init_and_run(genotypes, jax.random.PRNGKey(1))
    assert int(state.iteration) == 5 and int(state.evaluations) == 32 * 6
    assert 0 < int(state.env_steps) <= 32 * 6 * 50
    assert np.all(np.diff(np.asarray(metrics["qd_score"])) >= 0)
    assert int(state.repertoire.num_filled) > int(start_filled)
    filled = np.asarray(state.repertoire.filled)
    fit = np.asarray(state.repertoire.fitnesses)[filled]
    desc = np.asarray(state.repertoire.descriptors)[filled]
    assert np.all(fit >= 0.0) and np.all(fit == np.round(fit))  # fruits eaten
    assert np.all((desc >= 0.0) & (desc <= 1.0))


def test_generic_env_with_action_shares() -> None:
    env = JumanjiEnv("Game2048-v1", episode_length=20, descriptor_fn=action_frequencies(4))
    assert (env.observation_size, env.action_size, env.descriptor_size) == (20, 4, 4)

    def uniform(obs: jax.Array, key: jax.Array) -> jax.Array:
        return jax.random.uniform(key, (obs.shape[0], 4), minval=-1.0, maxval=1.0)

    episodes = jax.jit(lambda k: run_episodes(env, uniform, k, 8))(jax.random.PRNGKey(0))
    shares = np.asarray(episodes.mean_desc)
    assert np.all(shares >= 0.0) and np.allclose(shares.sum(-1), 1.0, atol=1e-5)
    assert np.all(np.asarray(episodes.returns) >= 0.0)
    # every action taken was allowed by the mask of the observation it was taken from
    mask = np.asarray(episodes.transitions.obs)[..., -4:]
    taken = np.argmax(np.asarray(episodes.transitions.next_desc), axis=-1)
    valid = np.asarray(episodes.mask) > 0
    assert np.all(np.take_along_axis(mask, taken[..., None], -1)[..., 0][valid] == 1.0)

    task = jumanji_task(env, (0.0,) * 4, (1.0,) * 4, policy_hidden=(8,), name="2048")
    assert (task.name, task.genotype_size) == ("2048", 20 * 8 + 8 + 8 * 4 + 4)
    with pytest.raises(ValueError, match="for a state descriptor of size 4"):
        jumanji_task(env, (0.0,), (1.0,))
