"""Tests for qdrl.agents.td3: losses against hand-computed values, delayed updates,
hparams read from the state, one compilation, and learning a one-step task."""

from __future__ import annotations

import dataclasses
from typing import Any

import chex
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from qdrl.agents import AGENTS, TD3Config, TD3State, make_td3, make_td3_losses, td3_actor_step
from qdrl.agents.td3 import make_td3_networks
from qdrl.types import Transition

OBS, ACT = 3, 2
CONFIG = TD3Config(hidden=(8,))
NETWORKS = make_td3_networks(CONFIG, ACT)
LOSSES = make_td3_losses(NETWORKS)


def make_batch(
    key: jax.Array, n: int = 6, terminated: float = 0.0, truncated: float = 0.0
) -> Transition:
    k = jax.random.split(key, 4)
    return Transition(
        obs=jax.random.normal(k[0], (n, OBS)),
        action=jax.random.uniform(k[1], (n, ACT), minval=-1.0, maxval=1.0),
        reward=jax.random.normal(k[2], (n,)),
        next_obs=jax.random.normal(k[3], (n, OBS)),
        terminated=jnp.full((n,), terminated),
        truncated=jnp.full((n,), truncated),
        desc=jnp.zeros((n, 2)),
        next_desc=jnp.zeros((n, 2)),
    )


def make_params(seed: int) -> tuple[dict, dict]:
    """Policy and critic params; different seeds give online and target networks that differ."""
    k1, k2 = jax.random.split(jax.random.PRNGKey(seed))
    policy = NETWORKS.policy.init(k1, jnp.zeros((1, OBS)))
    critic = NETWORKS.critic.init(k2, jnp.zeros((1, OBS)), jnp.zeros((1, ACT)))
    return policy, critic


def hand_critic_target(
    batch: Transition,
    target_policy: dict,
    target_critic: dict,
    discount: float,
    reward_scale: float,
    noise: np.ndarray,
) -> np.ndarray:
    next_action = np.asarray(NETWORKS.policy.apply(target_policy, batch.next_obs))
    next_action = np.clip(next_action + noise, -1.0, 1.0)
    next_q = np.asarray(NETWORKS.critic.apply(target_critic, batch.next_obs, next_action))
    mask = 1.0 - np.asarray(batch.terminated)
    return reward_scale * np.asarray(batch.reward) + discount * mask * next_q.min(axis=-1)


def hand_critic_loss(batch: Transition, critic: dict, target: np.ndarray) -> float:
    q = np.asarray(NETWORKS.critic.apply(critic, batch.obs, batch.action))
    return float(np.mean(np.sum(0.5 * (q - target[:, None]) ** 2, axis=-1)))


@pytest.mark.parametrize("jit", [False, True])
def test_critic_loss_without_noise_matches_hand_computation(jit: bool) -> None:
    batch = make_batch(jax.random.PRNGKey(0))
    _, critic = make_params(1)
    target_policy, target_critic = make_params(2)
    loss_fn = jax.jit(LOSSES.critic) if jit else LOSSES.critic
    loss, aux = loss_fn(
        critic, target_policy, target_critic, batch, 0.9, 2.0, 0.0, 0.5, jax.random.PRNGKey(3)
    )
    target = hand_critic_target(batch, target_policy, target_critic, 0.9, 2.0, np.zeros((6, ACT)))
    np.testing.assert_allclose(loss, hand_critic_loss(batch, critic, target), rtol=1e-5)
    np.testing.assert_allclose(aux["target_q_mean"], target.mean(), rtol=1e-5, atol=1e-6)


def test_critic_loss_smooths_target_with_clipped_noise() -> None:
    batch = make_batch(jax.random.PRNGKey(0))
    _, critic = make_params(1)
    target_policy, target_critic = make_params(2)
    key = jax.random.PRNGKey(3)
    sigma, clip = 0.7, 0.5
    loss, _ = LOSSES.critic(critic, target_policy, target_critic, batch, 0.9, 1.0, sigma, clip, key)
    noise = np.clip(sigma * np.asarray(jax.random.normal(key, (6, ACT))), -clip, clip)
    assert np.abs(noise).max() == pytest.approx(clip)  # the clip is exercised
    target = hand_critic_target(batch, target_policy, target_critic, 0.9, 1.0, noise)
    np.testing.assert_allclose(loss, hand_critic_loss(batch, critic, target), rtol=1e-5)


def test_noise_clip_zero_removes_smoothing() -> None:
    batch = make_batch(jax.random.PRNGKey(0))
    _, critic = make_params(1)
    target_policy, target_critic = make_params(2)
    key = jax.random.PRNGKey(3)
    noisy, _ = LOSSES.critic(critic, target_policy, target_critic, batch, 0.9, 1.0, 5.0, 0.0, key)
    clean, _ = LOSSES.critic(critic, target_policy, target_critic, batch, 0.9, 1.0, 0.0, 0.5, key)
    np.testing.assert_allclose(noisy, clean, rtol=1e-6)


@pytest.mark.parametrize(
    ("terminated", "truncated", "bootstraps"), [(1.0, 0.0, False), (0.0, 1.0, True)]
)
def test_target_bootstraps_through_truncation_only(
    terminated: float, truncated: float, bootstraps: bool
) -> None:
    batch = make_batch(jax.random.PRNGKey(4), n=1, terminated=terminated, truncated=truncated)
    _, critic = make_params(1)
    target_policy, target_critic = make_params(2)
    _, aux = LOSSES.critic(
        critic, target_policy, target_critic, batch, 0.9, 2.0, 0.0, 0.5, jax.random.PRNGKey(0)
    )
    reward_only = 2.0 * float(batch.reward[0])
    if bootstraps:
        full = hand_critic_target(batch, target_policy, target_critic, 0.9, 2.0, np.zeros((1, ACT)))
        np.testing.assert_allclose(aux["target_q_mean"], full[0], rtol=1e-5)
        assert abs(float(aux["target_q_mean"]) - reward_only) > 1e-4
    else:
        np.testing.assert_allclose(aux["target_q_mean"], reward_only, rtol=1e-6)


@pytest.mark.parametrize("jit", [False, True])
def test_actor_loss_is_minus_first_critic(jit: bool) -> None:
    batch = make_batch(jax.random.PRNGKey(0))
    policy, critic = make_params(1)
    loss_fn = jax.jit(LOSSES.actor) if jit else LOSSES.actor
    action = np.asarray(NETWORKS.policy.apply(policy, batch.obs))
    q = np.asarray(NETWORKS.critic.apply(critic, batch.obs, action))
    np.testing.assert_allclose(loss_fn(policy, critic, batch.obs), -q[:, 0].mean(), rtol=1e-5)


def test_actor_step_increases_q() -> None:
    batch = make_batch(jax.random.PRNGKey(0), n=32)
    policy, critic = make_params(5)

    def mean_q1(p: dict) -> float:
        action = NETWORKS.policy.apply(p, batch.obs)
        return float(jnp.mean(NETWORKS.critic.apply(critic, batch.obs, action)[:, 0]))

    opt_state = optax.scale_by_adam().init(policy)
    step = jax.jit(td3_actor_step, static_argnums=0)
    new_policy, opt_state, loss = step(NETWORKS, policy, opt_state, critic, batch.obs, 1e-3)
    np.testing.assert_allclose(loss, -mean_q1(policy), rtol=1e-5)
    assert mean_q1(new_policy) > mean_q1(policy)
    assert int(opt_state.count) == 1
    # Further steps keep climbing.
    for _ in range(5):
        newer, opt_state, _ = step(NETWORKS, new_policy, opt_state, critic, batch.obs, 1e-3)
        assert mean_q1(newer) > mean_q1(new_policy)
        new_policy = newer


def assert_trees_equal(a: object, b: object) -> None:
    chex.assert_trees_all_equal(a, b)


def assert_trees_differ(a: object, b: object) -> None:
    with pytest.raises(AssertionError):
        chex.assert_trees_all_close(a, b)


def test_actor_and_targets_update_every_policy_delay_steps() -> None:
    config = dataclasses.replace(CONFIG, tau=0.1, policy_delay=2)
    agent = make_td3(config, OBS, ACT)
    update = jax.jit(agent.update)
    s0: TD3State = agent.init(jax.random.PRNGKey(0))
    s1, m1 = update(s0, make_batch(jax.random.PRNGKey(1)), jax.random.PRNGKey(2))
    assert int(s1.steps) == 1
    assert_trees_differ(s1.critic_params, s0.critic_params)
    assert_trees_equal(s1.policy_params, s0.policy_params)
    assert_trees_equal(s1.target_policy_params, s0.target_policy_params)
    assert_trees_equal(s1.target_critic_params, s0.target_critic_params)
    assert np.isfinite(m1["actor_loss"])

    s2, _ = update(s1, make_batch(jax.random.PRNGKey(3)), jax.random.PRNGKey(4))
    assert int(s2.steps) == 2
    assert_trees_differ(s2.policy_params, s1.policy_params)
    polyak = lambda new, old: 0.1 * new + 0.9 * old  # noqa: E731
    chex.assert_trees_all_close(
        s2.target_critic_params,
        jax.tree.map(polyak, s2.critic_params, s1.target_critic_params),
        rtol=1e-6,
    )
    chex.assert_trees_all_close(
        s2.target_policy_params,
        jax.tree.map(polyak, s2.policy_params, s1.target_policy_params),
        rtol=1e-6,
    )


def test_update_reads_learning_rate_from_hparams_and_vmaps() -> None:
    agent = make_td3(CONFIG, OBS, ACT)
    update = jax.jit(agent.update)
    state = agent.init(jax.random.PRNGKey(0))
    frozen = state._replace(hparams={**state.hparams, "critic_lr": jnp.float32(0.0)})
    batch, key = make_batch(jax.random.PRNGKey(1)), jax.random.PRNGKey(2)

    frozen_next, _ = update(frozen, batch, key)
    moving_next, _ = update(state, batch, key)
    assert_trees_equal(frozen_next.critic_params, state.critic_params)
    assert_trees_differ(moving_next.critic_params, state.critic_params)

    population = jax.tree.map(lambda a, b: jnp.stack([a, b]), frozen, state)
    pop_next, metrics = jax.jit(jax.vmap(agent.update, in_axes=(0, None, None)))(
        population, batch, key
    )
    chex.assert_shape(metrics["critic_loss"], (2,))
    for i, single in enumerate([frozen_next, moving_next]):
        member = jax.tree.map(lambda x, i=i: x[i], pop_next)
        chex.assert_trees_all_close(member, single, rtol=1e-5, atol=1e-6)


def test_act_adds_clipped_exploration_noise() -> None:
    agent = make_td3(CONFIG, OBS, ACT)
    state = agent.init(jax.random.PRNGKey(0))
    obs = 10.0 * jax.random.normal(jax.random.PRNGKey(1), (64, OBS))
    greedy = agent.policy(agent.policy_params(state), obs)
    noisy = agent.act(state, obs, jax.random.PRNGKey(2))
    chex.assert_shape(noisy, (64, ACT))
    assert float(jnp.abs(noisy).max()) <= 1.0
    assert float(jnp.abs(noisy - greedy).max()) > 0.0
    quiet = state._replace(hparams={**state.hparams, "expl_noise": jnp.float32(0.0)})
    np.testing.assert_allclose(agent.act(quiet, obs, jax.random.PRNGKey(2)), greedy)


def test_update_compiles_once() -> None:
    agent = make_td3(CONFIG, OBS, ACT)
    traces: list[None] = []

    def counted(state, batch, key):  # type: ignore[no-untyped-def]
        traces.append(None)
        return agent.update(state, batch, key)

    update = jax.jit(counted)
    state = agent.init(jax.random.PRNGKey(0))
    for i in range(4):
        state, _ = update(state, make_batch(jax.random.PRNGKey(i)), jax.random.PRNGKey(10 + i))
    assert len(traces) == 1
    assert int(state.steps) == 4


def bandit_batch(key: jax.Array, n: int) -> Transition:
    """A one-step contextual bandit: reward = -||a - 0.9 obs[:2]||^2, always terminal."""
    obs_key, action_key = jax.random.split(key)
    obs = jax.random.uniform(obs_key, (n, OBS), minval=-1.0, maxval=1.0)
    action = jax.random.uniform(action_key, (n, ACT), minval=-1.0, maxval=1.0)
    return Transition(
        obs=obs,
        action=action,
        reward=bandit_reward(obs, action),
        next_obs=obs,
        terminated=jnp.ones((n,)),
        truncated=jnp.zeros((n,)),
        desc=jnp.zeros((n, 2)),
        next_desc=jnp.zeros((n, 2)),
    )


def bandit_reward(obs: jax.Array, action: jax.Array) -> jax.Array:
    return -jnp.sum((action - 0.9 * obs[:, :ACT]) ** 2, axis=-1)


def test_learns_contextual_bandit() -> None:
    config = TD3Config(hidden=(32, 32), actor_lr=1e-3, critic_lr=3e-3)
    agent = make_td3(config, OBS, ACT)

    @jax.jit
    def train(key: jax.Array) -> tuple[jax.Array, jax.Array]:
        init_key, key = jax.random.split(key)
        state = agent.init(init_key)

        def step(state: TD3State, key: jax.Array) -> tuple[TD3State, None]:
            batch_key, update_key = jax.random.split(key)
            return agent.update(state, bandit_batch(batch_key, 64), update_key)[0], None

        def greedy_reward(state: TD3State) -> jax.Array:
            obs = bandit_batch(jax.random.PRNGKey(123), 256).obs
            return jnp.mean(bandit_reward(obs, agent.policy(agent.policy_params(state), obs)))

        before = greedy_reward(state)
        state, _ = jax.lax.scan(step, state, jax.random.split(key, 600))
        return before, greedy_reward(state)

    before, after = train(jax.random.PRNGKey(0))
    assert float(before) < -0.3
    assert float(after) > -0.05


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("actor_lr", 0.0),
        ("critic_lr", -1e-3),
        ("discount", 1.5),
        ("tau", 0.0),
        ("tau", 1.5),
        ("reward_scale", float("nan")),
        ("policy_noise", -0.1),
        ("noise_clip", -1.0),
        ("expl_noise", "0.1"),
        ("policy_delay", 0),
        ("policy_delay", 2.0),
        ("hidden", (8, 0)),
        ("activation", "sigmoid"),
    ],
)
def test_bad_config_raises_naming_the_field(field: str, value: Any) -> None:
    config = dataclasses.replace(CONFIG, **{field: value})
    with pytest.raises(ValueError, match=rf"^agent\.{field}: expected"):
        config.check()
    with pytest.raises(ValueError, match=rf"agent\.{field}"):
        make_td3(config, OBS, ACT)


@pytest.mark.parametrize(("obs_size", "action_size"), [(0, 2), (3, -1), (3.0, 2), (3, True)])
def test_bad_sizes_raise(obs_size: object, action_size: object) -> None:
    with pytest.raises(ValueError, match="_size: expected a positive int"):
        make_td3(CONFIG, obs_size, action_size)  # type: ignore[arg-type]


def test_defaults_and_registry() -> None:
    config = TD3Config()
    config.check()
    assert AGENTS["td3"] == (TD3Config, make_td3)
    assert config.hparams() == {
        "actor_lr": 3e-4,
        "critic_lr": 3e-4,
        "discount": 0.99,
        "tau": 0.005,
        "reward_scale": 1.0,
        "policy_noise": 0.2,
        "noise_clip": 0.5,
        "expl_noise": 0.1,
    }
    state = make_td3(CONFIG, OBS, ACT).init(jax.random.PRNGKey(0))
    assert set(state.hparams) == set(config.hparams())
    for value in state.hparams.values():
        chex.assert_shape(value, ())
        chex.assert_type(value, jnp.float32)
    chex.assert_type(state.steps, jnp.int32)
