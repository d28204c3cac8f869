"""The env protocol: bookkeeping, truncation vs termination, auto-reset, brax adapter."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl import envs
from qdrl.envs.base import auto_reset, reset_batch, step_batch
from qdrl.envs.point import PointEnv
from qdrl.rollout import run_episodes, unroll


def test_point_env_sizes_and_reward() -> None:
    env = PointEnv(episode_length=5, goal=(0.5, 0.5), max_speed=0.1, start_noise=0.0)
    assert (env.observation_size, env.action_size, env.descriptor_size) == (4, 2, 2)
    s = env.reset(jax.random.PRNGKey(0))
    s = env.step(s, jnp.array([1.0, 1.0]))
    np.testing.assert_allclose(s.desc, [0.1, 0.1], atol=1e-6)
    np.testing.assert_allclose(s.reward, -np.hypot(0.4, 0.4), rtol=1e-6)
    # actions outside [-1, 1] are clipped
    s2 = env.step(s, jnp.array([5.0, -5.0]))
    np.testing.assert_allclose(s2.desc, [0.2, 0.0], atol=1e-6)


def test_truncation_is_kept_apart_from_termination() -> None:
    env = PointEnv(episode_length=3)
    s = env.reset(jax.random.PRNGKey(0))
    flags = []
    for _ in range(3):
        s = env.step(s, jnp.zeros(2))
        flags.append((float(s.terminated), float(s.truncated), int(s.step)))
    assert flags == [(0.0, 0.0, 1), (0.0, 0.0, 2), (0.0, 1.0, 3)]
    assert float(s.done) == 1.0
    assert int(s.last_length) == 3
    np.testing.assert_allclose(s.last_return, s.episode_return)


def test_auto_reset_resets_only_finished_envs_and_keeps_metrics() -> None:
    env = PointEnv(episode_length=3, start_noise=0.5)
    s = reset_batch(env, jax.random.PRNGKey(1), 3)
    s = step_batch(env, s, jnp.ones((3, 2)))
    # finish env 1 only, by making it look one step older
    s = s._replace(step=s.step.at[1].set(2))
    s = step_batch(env, s, jnp.ones((3, 2)))
    np.testing.assert_array_equal(np.asarray(s.done), [0.0, 1.0, 0.0])
    before = s
    s = auto_reset(env, s)
    np.testing.assert_array_equal(np.asarray(s.step), [2, 0, 2])
    np.testing.assert_array_equal(np.asarray(s.done), [0.0, 0.0, 0.0])
    np.testing.assert_allclose(np.asarray(s.obs)[[0, 2]], np.asarray(before.obs)[[0, 2]])
    assert not np.allclose(s.obs[1], before.obs[1])
    np.testing.assert_allclose(s.last_return[1], before.episode_return[1])
    assert float(s.episode_return[1]) == 0.0
    # a second reset of the same env starts elsewhere: its key moved on
    assert not np.array_equal(np.asarray(s.key[1]), np.asarray(before.key[1]))


def test_unroll_collects_transitions_across_resets() -> None:
    env = PointEnv(episode_length=4)
    s = reset_batch(env, jax.random.PRNGKey(0), 2)
    policy = lambda obs, k: jnp.ones((obs.shape[0], 2))  # noqa: E731
    s, tr = jax.jit(lambda s, k: unroll(env, s, policy, k, 10))(s, jax.random.PRNGKey(1))
    assert tr.obs.shape == (10, 2, 4)
    np.testing.assert_array_equal(np.asarray(tr.truncated[:, 0]), [0, 0, 0, 1, 0, 0, 0, 1, 0, 0])
    # the recorded next_obs of the last step of an episode is the true one, not the reset one
    np.testing.assert_allclose(tr.next_obs[3, :, :2], tr.next_desc[3])
    assert int(s.step[0]) == 2


def test_run_episodes_masks_after_the_end() -> None:
    env = PointEnv(episode_length=5, start_noise=0.0)
    ep = run_episodes(env, lambda obs, k: jnp.ones((obs.shape[0], 2)), jax.random.PRNGKey(0), 3, num_steps=8)
    np.testing.assert_array_equal(np.asarray(ep.lengths), [5, 5, 5])
    assert ep.mask.shape == (8, 3)
    np.testing.assert_allclose(ep.final_desc, np.full((3, 2), 0.5), atol=1e-6)
    expected = -sum(np.hypot(0.5 - 0.1 * i, 0.5 - 0.1 * i) for i in range(1, 6))
    np.testing.assert_allclose(ep.returns, expected, rtol=1e-5)
    np.testing.assert_allclose(ep.mean_desc, np.full((3, 2), 0.3), atol=1e-6)


def test_make_rejects_unknown_names() -> None:
    with pytest.raises(ValueError, match="unknown brax environment 'cheetah'"):
        envs.make("cheetah")
    with pytest.raises(ValueError, match="unknown brax backend 'warp'"):
        envs.make("hopper", backend="warp")
    with pytest.raises(ValueError, match="episode_length"):
        envs.make("point", episode_length=0)
    assert "point" in envs.env_names() and "halfcheetah" in envs.env_names()


# brax's done flag becomes `terminated`, never `truncated`; auto-reset restarts the finished
# envs. The pendulum (a small program) in the default run; the hopper (feet contacts) -m slow.
@pytest.mark.parametrize(
    ("name", "sizes"),
    [("inverted_pendulum", (4, 1, 2)), pytest.param("hopper", (11, 3, 2), marks=pytest.mark.slow)],
)
def test_brax_batched_rollout_terminates_and_resets(name: str, sizes: tuple[int, int, int]) -> None:
    env = envs.make(name, backend="spring", episode_length=1000)
    assert (env.observation_size, env.action_size, env.descriptor_size) == sizes

    @jax.jit
    def go(key: jax.Array):  # type: ignore[no-untyped-def]
        s = reset_batch(env, key, 4)
        policy = lambda obs, k: jax.random.uniform(k, (4, env.action_size), minval=-1, maxval=1)  # noqa: E731
        return unroll(env, s, policy, key, 150)

    s, tr = go(jax.random.PRNGKey(0))
    # a random policy falls over: terminations, never truncations, within 150 steps
    assert float(tr.terminated.sum()) > 0
    assert float(tr.truncated.sum()) == 0
    assert np.all(np.isfinite(np.asarray(tr.reward)))
    finished = np.asarray(s.last_length) > 0
    assert finished.any()
    assert np.all(np.isfinite(np.asarray(s.last_return)[finished]))
    # envs that finished restarted: their step counters are below 150
    assert np.all(np.asarray(s.step)[finished] < 150)
    # the descriptor chain continues across steps, except where an episode restarted
    done = np.asarray(tr.terminated[:-1]) > 0
    same = np.isclose(np.asarray(tr.next_desc[:-1]), np.asarray(tr.desc[1:]), atol=1e-6).all(-1)
    assert np.all(same[~done]) and not np.all(same[done])
