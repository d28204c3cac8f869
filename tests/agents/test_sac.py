"""Tests for qdrl.agents.sac: losses against hand-computed values, Polyak targets,
hparams read from the state, one compilation, and learning a one-step task."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from qdrl.agents import AGENTS, SACConfig, SACState, make_sac, make_sac_losses, make_sac_networks
from qdrl.types import Transition

OBS, ACT = 3, 2
CONFIG = SACConfig(hidden=(8,))
NETWORKS = make_sac_networks(CONFIG, ACT)
TARGET_ENTROPY = -2.0
LOSSES = make_sac_losses(NETWORKS, TARGET_ENTROPY)


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
    """Policy and critic params; different seeds give online and target critics that differ."""
    k1, k2 = jax.random.split(jax.random.PRNGKey(seed))
    policy = NETWORKS.policy.init(k1, jnp.zeros((1, OBS)))
    critic = NETWORKS.critic.init(k2, jnp.zeros((1, OBS)), jnp.zeros((1, ACT)))
    return policy, critic


def hand_sample(policy: dict, obs: jax.Array, key: jax.Array) -> tuple[np.ndarray, np.ndarray]:
    """tanh(mu + sigma eps) and its log-density, the textbook way, in float64."""
    mean, log_std = (np.asarray(x, np.float64) for x in NETWORKS.policy.apply(policy, obs))
    eps = np.asarray(jax.random.normal(key, mean.shape), np.float64)
    std = np.exp(log_std)
    u = mean + std * eps
    gaussian = -0.5 * ((u - mean) / std) ** 2 - np.log(std) - 0.5 * np.log(2 * np.pi)
    log_prob = np.sum(gaussian - np.log(1.0 - np.tanh(u) ** 2), axis=-1)
    return np.tanh(u), log_prob


def hand_critic_target(
    batch: Transition,
    policy: dict,
    target_critic: dict,
    alpha: float,
    discount: float,
    reward_scale: float,
    key: jax.Array,
) -> np.ndarray:
    next_action, next_log_prob = hand_sample(policy, batch.next_obs, key)
    next_q = np.asarray(
        NETWORKS.critic.apply(target_critic, batch.next_obs, next_action.astype(np.float32))
    )
    next_v = next_q.min(axis=-1) - alpha * next_log_prob
    mask = 1.0 - np.asarray(batch.terminated)
    return reward_scale * np.asarray(batch.reward) + discount * mask * next_v


@pytest.mark.parametrize("jit", [False, True])
def test_critic_loss_matches_hand_computation(jit: bool) -> None:
    batch = make_batch(jax.random.PRNGKey(0))
    policy, critic = make_params(1)
    _, target_critic = make_params(2)
    key = jax.random.PRNGKey(3)
    loss_fn = jax.jit(LOSSES.critic) if jit else LOSSES.critic
    loss, aux = loss_fn(critic, policy, target_critic, 0.3, batch, 0.9, 2.0, key)

    target = hand_critic_target(batch, policy, target_critic, 0.3, 0.9, 2.0, key)
    q = np.asarray(NETWORKS.critic.apply(critic, batch.obs, batch.action))
    expected = np.mean(np.sum(0.5 * (q - target[:, None]) ** 2, axis=-1))
    np.testing.assert_allclose(loss, expected, rtol=1e-4)
    np.testing.assert_allclose(aux["target_q_mean"], target.mean(), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(aux["q_mean"], q.mean(), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize(
    ("terminated", "truncated", "bootstraps"), [(1.0, 0.0, False), (0.0, 1.0, True)]
)
def test_target_bootstraps_through_truncation_only(
    terminated: float, truncated: float, bootstraps: bool
) -> None:
    batch = make_batch(jax.random.PRNGKey(4), n=1, terminated=terminated, truncated=truncated)
    policy, critic = make_params(1)
    _, target_critic = make_params(2)
    key = jax.random.PRNGKey(5)
    _, aux = LOSSES.critic(critic, policy, target_critic, 0.3, batch, 0.9, 2.0, key)
    reward_only = 2.0 * float(batch.reward[0])
    if bootstraps:
        full = hand_critic_target(batch, policy, target_critic, 0.3, 0.9, 2.0, key)
        np.testing.assert_allclose(aux["target_q_mean"], full[0], rtol=1e-4)
        assert abs(float(aux["target_q_mean"]) - reward_only) > 1e-3
    else:
        np.testing.assert_allclose(aux["target_q_mean"], reward_only, rtol=1e-6)


@pytest.mark.parametrize("jit", [False, True])
def test_actor_loss_matches_hand_computation(jit: bool) -> None:
    batch = make_batch(jax.random.PRNGKey(0))
    policy, critic = make_params(1)
    key = jax.random.PRNGKey(6)
    loss_fn = jax.jit(LOSSES.actor) if jit else LOSSES.actor
    loss, log_prob = loss_fn(policy, critic, 0.3, batch.obs, key)

    action, hand_log_prob = hand_sample(policy, batch.obs, key)
    q = np.asarray(NETWORKS.critic.apply(critic, batch.obs, action.astype(np.float32)))
    np.testing.assert_allclose(log_prob, hand_log_prob, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(loss, np.mean(0.3 * hand_log_prob - q.min(axis=-1)), rtol=1e-4)


def test_alpha_loss_and_gradient_by_hand() -> None:
    log_alpha = jnp.float32(math.log(0.5))
    log_prob = jnp.array([-1.0, 0.5, 3.0])
    # 0.5 * mean(-log_prob + 2) = 0.5 * mean([3.0, 1.5, -1.0]) = 0.5833...
    expected = 0.5 * np.mean([3.0, 1.5, -1.0])
    loss, (grad_alpha, grad_log_prob) = jax.value_and_grad(LOSSES.alpha, argnums=(0, 1))(
        log_alpha, log_prob
    )
    np.testing.assert_allclose(loss, expected, rtol=1e-6)
    # d/dlog_alpha of exp(log_alpha) * c is the loss itself; log_prob gets no gradient.
    np.testing.assert_allclose(grad_alpha, expected, rtol=1e-6)
    np.testing.assert_array_equal(grad_log_prob, np.zeros(3))


def test_update_moves_every_part_and_polyak_targets() -> None:
    agent = make_sac(dataclasses.replace(CONFIG, tau=0.1), OBS, ACT)
    s0: SACState = agent.init(jax.random.PRNGKey(0))
    s1, metrics = jax.jit(agent.update)(
        s0, make_batch(jax.random.PRNGKey(1)), jax.random.PRNGKey(2)
    )
    assert int(s1.steps) == 1
    for name in ("policy_params", "critic_params", "log_alpha"):
        with pytest.raises(AssertionError):
            chex.assert_trees_all_close(getattr(s1, name), getattr(s0, name))
    chex.assert_trees_all_close(
        s1.target_critic_params,
        jax.tree.map(
            lambda new, old: 0.1 * new + 0.9 * old, s1.critic_params, s0.target_critic_params
        ),
        rtol=1e-6,
    )
    assert set(metrics) >= {"critic_loss", "actor_loss", "alpha_loss", "alpha", "q_mean"}
    for value in metrics.values():
        chex.assert_shape(value, ())
        assert np.isfinite(value)
    np.testing.assert_allclose(metrics["alpha"], CONFIG.init_alpha)


def test_fixed_alpha_stays_put() -> None:
    agent = make_sac(dataclasses.replace(CONFIG, learn_alpha=False, init_alpha=0.2), OBS, ACT)
    s0 = agent.init(jax.random.PRNGKey(0))
    s1, _ = jax.jit(agent.update)(s0, make_batch(jax.random.PRNGKey(1)), jax.random.PRNGKey(2))
    np.testing.assert_allclose(jnp.exp(s1.log_alpha), 0.2, rtol=1e-6)


def test_update_reads_learning_rate_from_hparams_and_vmaps() -> None:
    agent = make_sac(CONFIG, OBS, ACT)
    update = jax.jit(agent.update)
    state = agent.init(jax.random.PRNGKey(0))
    frozen = state._replace(hparams={**state.hparams, "critic_lr": jnp.float32(0.0)})
    batch, key = make_batch(jax.random.PRNGKey(1)), jax.random.PRNGKey(2)

    frozen_next, _ = update(frozen, batch, key)
    moving_next, _ = update(state, batch, key)
    chex.assert_trees_all_equal(frozen_next.critic_params, state.critic_params)
    with pytest.raises(AssertionError):
        chex.assert_trees_all_close(moving_next.critic_params, state.critic_params)

    population = jax.tree.map(lambda a, b: jnp.stack([a, b]), frozen, state)
    pop_next, metrics = jax.jit(jax.vmap(agent.update, in_axes=(0, None, None)))(
        population, batch, key
    )
    chex.assert_shape(metrics["critic_loss"], (2,))
    for i, single in enumerate([frozen_next, moving_next]):
        member = jax.tree.map(lambda x, i=i: x[i], pop_next)
        chex.assert_trees_all_close(member, single, rtol=1e-5, atol=1e-6)


def test_act_samples_and_policy_is_tanh_mean() -> None:
    agent = make_sac(CONFIG, OBS, ACT)
    state = agent.init(jax.random.PRNGKey(0))
    obs = 10.0 * jax.random.normal(jax.random.PRNGKey(1), (64, OBS))
    mean, _ = NETWORKS.policy.apply(state.policy_params, obs)
    greedy = agent.policy(agent.policy_params(state), obs)
    np.testing.assert_allclose(greedy, jnp.tanh(mean), rtol=1e-6)
    sampled = agent.act(state, obs, jax.random.PRNGKey(2))
    chex.assert_shape(sampled, (64, ACT))
    assert float(jnp.abs(sampled).max()) <= 1.0
    assert float(jnp.abs(sampled - greedy).max()) > 1e-3


def test_update_compiles_once() -> None:
    agent = make_sac(CONFIG, OBS, ACT)
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
    config = SACConfig(
        hidden=(32, 32), actor_lr=1e-3, critic_lr=3e-3, alpha_lr=3e-3, init_alpha=0.1
    )
    agent = make_sac(config, OBS, ACT)

    @jax.jit
    def train(key: jax.Array) -> tuple[jax.Array, jax.Array]:
        init_key, key = jax.random.split(key)
        state = agent.init(init_key)

        def step(state: SACState, key: jax.Array) -> tuple[SACState, None]:
            batch_key, update_key = jax.random.split(key)
            return agent.update(state, bandit_batch(batch_key, 64), update_key)[0], None

        def greedy_reward(state: SACState) -> jax.Array:
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
        ("critic_lr", float("inf")),
        ("alpha_lr", -1.0),
        ("discount", -0.1),
        ("tau", 1.5),
        ("reward_scale", 0.0),
        ("init_alpha", 0.0),
        ("target_entropy", "auto"),
        ("learn_alpha", 1),
        ("hidden", (8, -2)),
        ("hidden", 8),
        ("activation", "sigmoid"),
    ],
)
def test_bad_config_raises_naming_the_field(field: str, value: Any) -> None:
    config = dataclasses.replace(CONFIG, **{field: value})
    with pytest.raises(ValueError, match=rf"^agent\.{field}: expected"):
        config.check()
    with pytest.raises(ValueError, match=rf"agent\.{field}"):
        make_sac(config, OBS, ACT)


@pytest.mark.parametrize(("obs_size", "action_size"), [(0, 2), (3, -1), (3.0, 2), (3, True)])
def test_bad_sizes_raise(obs_size: object, action_size: object) -> None:
    with pytest.raises(ValueError, match="_size: expected a positive int"):
        make_sac(CONFIG, obs_size, action_size)  # type: ignore[arg-type]


def test_defaults_and_registry() -> None:
    config = SACConfig()
    config.check()
    assert AGENTS["sac"] == (SACConfig, make_sac)
    assert SACConfig(hidden=[4, 4]).hidden == (4, 4)  # type: ignore[arg-type]
    assert config.hparams() == {
        "actor_lr": 3e-4,
        "critic_lr": 3e-4,
        "alpha_lr": 3e-4,
        "discount": 0.99,
        "tau": 0.005,
        "reward_scale": 1.0,
    }
    state = make_sac(CONFIG, OBS, ACT).init(jax.random.PRNGKey(0))
    assert set(state.hparams) == set(config.hparams())
    for value in state.hparams.values():
        chex.assert_shape(value, ())
        chex.assert_type(value, jnp.float32)
    chex.assert_type(state.steps, jnp.int32)
    np.testing.assert_allclose(jnp.exp(state.log_alpha), 1.0)


def test_target_entropy_defaults_to_minus_action_size() -> None:
    agent = make_sac(dataclasses.replace(CONFIG, alpha_lr=1.0), OBS, ACT)
    state = agent.init(jax.random.PRNGKey(0))
    _, metrics = jax.jit(agent.update)(
        state, make_batch(jax.random.PRNGKey(1)), jax.random.PRNGKey(2)
    )
    # alpha = 1: alpha_loss = mean(-log_prob) - target_entropy = entropy + ACT.
    np.testing.assert_allclose(metrics["alpha_loss"], metrics["entropy"] + ACT, rtol=1e-5)
