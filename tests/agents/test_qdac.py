"""QDAC's losses against values computed by hand, its Lagrange multiplier, its options; UVFA's
reward; the continuous skill environment and its skill space."""

from __future__ import annotations

import math

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from known_outputs import zeroed

from qdrl import nets
from qdrl.agents.qdac import (
    QDACConfig,
    binary_cross_entropy,
    make_qdac,
    make_qdac_losses,
    make_qdac_networks,
    pseudo_huber,
)
from qdrl.agents.sac import SACConfig
from qdrl.agents.uvfa import make_uvfa_module
from qdrl.envs.base import auto_reset, reset_batch, step_batch
from qdrl.envs.point import PointEnv
from qdrl.envs.skills import ContinuousSkillEnv, SkillSpace, skill_code, with_skill_code
from qdrl.types import Transition

SPACE = SkillSpace((0.0, -5.0), (1.0, 5.0))  # a box: code = 2 (z - low) / (high - low) - 1
OBS, ACT = 3, 2  # observation of the environment (without z), actions
SAC = SACConfig(hidden=(8, 8))


def batch(n: int = 4, seed: int = 0) -> Transition:
    """n transitions whose observations end with skill codes of SPACE; features in SPACE's units."""
    k = jax.random.split(jax.random.PRNGKey(seed), 5)
    codes = SPACE.normalise(SPACE.sample(k[0], (n,)))
    obs = jnp.concatenate([jax.random.normal(k[1], (n, OBS)), codes], -1)
    next_obs = jnp.concatenate([jax.random.normal(k[2], (n, OBS)), codes], -1)
    phi = SPACE.sample(k[3], (n,))
    reward = jax.random.normal(k[4], (n,))
    zeros = jnp.zeros((n,))
    return Transition(obs, jnp.zeros((n, ACT)), reward, next_obs, zeros.at[0].set(1.0), zeros, phi, phi)


def test_pseudo_huber_and_cross_entropy_by_hand() -> None:
    x = jnp.array([[3.0, 4.0], [0.0, 0.0]])
    np.testing.assert_allclose(pseudo_huber(x, 1e-3), [1e-3 * (math.sqrt(1 + 25 / 1e-6) - 1), 0.0], rtol=1e-6)
    # far from 0 it is the norm, less the scale
    assert float(pseudo_huber(x, 1e-3)[0]) == pytest.approx(5.0 - 1e-3, abs=1e-6)
    logits, labels = jnp.array([0.0, 2.0, -1.0]), jnp.array([1.0, 1.0, 0.0])
    by_hand = -(math.log(0.5) + math.log(1 / (1 + math.exp(-2.0))) + math.log(1 / (1 + math.exp(-1.0)))) / 3
    assert float(binary_cross_entropy(logits, labels)) == pytest.approx(by_hand, rel=1e-6)


@pytest.mark.parametrize("constraint", ["successor_features", "naive"])
def test_feature_loss_by_hand(constraint: str) -> None:
    config = QDACConfig(constraint=constraint)  # type: ignore[arg-type]
    networks = make_qdac_networks(SAC, config, SPACE, ACT)
    losses = make_qdac_losses(networks, config, SPACE)
    tr = batch()
    key = jax.random.PRNGKey(1)
    policy = networks.sac.policy.init(key, tr.obs)
    features = networks.features.init(key, tr.obs, tr.action)
    # online psi = 0 and target psi = 0.5 everywhere: y = phi + gamma m 0.5, loss = mean over
    # batch and features of the twin critics' 0.5 y^2 summed, i.e. mean(y^2)
    loss, _ = losses.feature(zeroed(features), policy, zeroed(features, 0.5), tr, 0.9, key)
    phi = np.asarray(SPACE.normalise(tr.next_desc))
    if constraint == "naive":
        phi = -np.linalg.norm(phi - np.asarray(skill_code(tr.obs, 2)), axis=-1, keepdims=True)
    y = phi + 0.9 * (1.0 - np.asarray(tr.terminated))[:, None] * 0.5
    assert float(loss) == pytest.approx(float(np.mean(y**2)), rel=1e-5)


def test_actor_and_lagrange_losses_by_hand() -> None:
    config = QDACConfig(distance_scale=2.0, delta=0.5)
    networks = make_qdac_networks(SAC, config, SPACE, ACT)
    losses = make_qdac_losses(networks, config, SPACE)
    tr = batch()
    key = jax.random.PRNGKey(2)
    policy = networks.sac.policy.init(key, tr.obs)
    critic = zeroed(networks.sac.critic.init(key, tr.obs, tr.action), 3.0)  # Q = 3
    features = zeroed(networks.features.init(key, tr.obs, tr.action), 10.0)  # psi = 10 per feature
    lagrange = zeroed(networks.lagrange.init(key, tr.obs), math.log(3.0))  # lambda = sigmoid(log 3) = 0.75
    gamma, alpha = 0.95, 0.2
    loss, (log_prob, dist, lam) = losses.actor(policy, critic, features, lagrange, alpha, tr.obs, gamma, key)
    mean, log_std = networks.sac.policy.apply(policy, tr.obs)
    _, want_log_prob = nets.sample_tanh_gaussian(mean, log_std, key)
    np.testing.assert_allclose(log_prob, want_log_prob, rtol=1e-6)
    z = np.asarray(skill_code(tr.obs, 2))
    estimate = (1 - gamma) * 10.0  # (1 - gamma) psi, the same in both features
    want_dist = np.linalg.norm(estimate - z, axis=-1)
    want_penalty = 1e-3 * (np.sqrt(1 + want_dist**2 / 1e-6) - 1)
    np.testing.assert_allclose(lam, 0.75, rtol=1e-6)
    np.testing.assert_allclose(dist, want_dist, rtol=1e-5)
    want = np.mean(alpha * np.asarray(want_log_prob) - 0.25 * 3.0 + 2.0 * 0.75 * want_penalty)
    assert float(loss) == pytest.approx(float(want), rel=1e-5)
    # lambda's loss: cross-entropy of its logit log 3 against [distance >= delta]
    dists = jnp.array([0.1, 0.7, 0.5, 0.2])
    labels = np.array([0.0, 1.0, 1.0, 0.0])
    p = 0.75
    want_bce = -np.mean(labels * math.log(p) + (1 - labels) * math.log(1 - p))
    assert float(losses.lagrange(lagrange, tr.obs, dists)) == pytest.approx(want_bce, rel=1e-6)


def test_fixed_lagrange_is_held_and_naive_distance_is_the_negated_value() -> None:
    config = QDACConfig(lagrange="fixed", fixed_lagrange=0.3, constraint="naive")
    networks = make_qdac_networks(SAC, config, SPACE, ACT)
    losses = make_qdac_losses(networks, config, SPACE)
    tr = batch()
    key = jax.random.PRNGKey(3)
    features = zeroed(networks.features.init(key, tr.obs, tr.action), -4.0)  # value of -||phi - z||
    _, (_, dist, lam) = losses.actor(
        networks.sac.policy.init(key, tr.obs), networks.sac.critic.init(key, tr.obs, tr.action),
        features, networks.lagrange.init(key, tr.obs), 0.1, tr.obs, 0.9, key,
    )
    np.testing.assert_allclose(lam, 0.3)
    np.testing.assert_allclose(dist, 0.1 * 4.0, rtol=1e-6)  # -(1 - gamma) psi


@pytest.mark.parametrize("violated", [True, False])
def test_lagrange_multiplier_rises_when_violated_and_falls_when_it_holds(violated: bool) -> None:
    # no relabelled copies: every skill of the batch is the one set here
    agent = make_qdac(SAC, QDACConfig(delta=0.1, lagrange_lr=1e-2, relabel_batches=0), SPACE, OBS + 2, ACT)
    state = agent.init(jax.random.PRNGKey(0))
    tr = batch(32)
    if not violated:
        # psi's estimate of the average feature is the skill itself: (1 - gamma) psi = code = 0.5
        code = jnp.full((32, 2), 0.5)
        tr = tr._replace(obs=with_skill_code(tr.obs, code), next_obs=with_skill_code(tr.next_obs, code))
        state = state._replace(feature_params=zeroed(state.feature_params, 0.5 / (1 - 0.99)))
    update = jax.jit(agent.update)
    lams = []
    for i in range(20):
        state, metrics = update(state, tr, jax.random.PRNGKey(i))
        lams.append(float(metrics["lagrange"]))
        assert float(metrics["constraint_violated"]) == (1.0 if violated else 0.0)
    assert (lams[-1] > lams[0] + 0.05) if violated else (lams[-1] < lams[0] - 0.05), lams


@pytest.mark.parametrize("jit", [True, False])
def test_update_runs_the_same_with_and_without_jit(jit: bool) -> None:
    agent = make_qdac(SAC, QDACConfig(relabel_batches=2), SPACE, OBS + 2, ACT)
    state = agent.init(jax.random.PRNGKey(0))
    update = jax.jit(agent.update) if jit else agent.update
    new, metrics = update(state, batch(8), jax.random.PRNGKey(1))
    assert all(np.isfinite(float(v)) for v in metrics.values())
    assert int(new.sac.steps) == 1
    other, _ = (agent.update if jit else jax.jit(agent.update))(state, batch(8), jax.random.PRNGKey(1))
    chex.assert_trees_all_close(new, other, rtol=1e-4, atol=1e-6)
    for name in ("feature_loss", "lagrange_loss", "lagrange", "constraint_distance", "critic_loss"):
        assert name in metrics
    with pytest.raises(ValueError, match=r"qdac\.delta"):
        make_qdac(SAC, QDACConfig(delta=-1.0), SPACE, OBS + 2, ACT)
    with pytest.raises(ValueError, match=r"qdac\.lagrange"):
        make_qdac(SAC, QDACConfig(lagrange="learnt"), SPACE, OBS + 2, ACT)  # type: ignore[arg-type]


def test_uvfa_reward_is_minus_the_distance_in_the_agents_view() -> None:
    tr = batch()
    module = make_uvfa_module(SPACE)
    r, info = module.reward(module.init(jax.random.PRNGKey(0)), tr, jax.random.PRNGKey(0))
    phi = np.asarray(SPACE.normalise(tr.next_desc))
    want = -np.linalg.norm(phi - np.asarray(tr.obs[:, -2:]), axis=-1)
    np.testing.assert_allclose(r, want, rtol=1e-6)
    np.testing.assert_allclose(info["feature_distance"], -want, rtol=1e-6)


def test_skill_spaces_sample_their_prior_and_normalise() -> None:
    z = SPACE.sample(jax.random.PRNGKey(0), (1000,))
    assert z.shape == (1000, 2) and float(z[:, 0].min()) >= 0.0 and float(z[:, 1].max()) <= 5.0
    np.testing.assert_allclose(SPACE.normalise(jnp.array([[0.0, -5.0], [1.0, 5.0], [0.5, 0.0]])),
                               [[-1, -1], [1, 1], [0, 0]])
    unit = SkillSpace((-1.0,) * 3, (1.0,) * 3, "unit").sample(jax.random.PRNGKey(1), (50,))
    np.testing.assert_allclose(jnp.linalg.norm(unit, axis=-1), 1.0, rtol=1e-5)
    angle = SkillSpace((-1.0, -1.0), (1.0, 1.0), "angular")
    a = angle.sample(jax.random.PRNGKey(2), (50,))
    np.testing.assert_allclose(jnp.linalg.norm(a, axis=-1), 1.0, rtol=1e-5)
    np.testing.assert_array_equal(angle.normalise(a), a)
    for bad, match in [(SkillSpace((0.0,), (0.0,)), "below"), (SkillSpace((0.0,), (1.0,), "angular"), "2 dimensions"),
                       (SkillSpace((0.0,), (1.0,), "cube"), "kind")]:
        with pytest.raises(ValueError, match=match):
            bad.check("x")


def test_continuous_skill_env_keeps_the_episodes_skill_and_redraws_at_reset() -> None:
    env = ContinuousSkillEnv(PointEnv(episode_length=3), SkillSpace((-1.0, -1.0), (1.0, 1.0)))
    assert env.observation_size == 4 + 2
    s = reset_batch(env, jax.random.PRNGKey(0), 4)
    codes = [np.asarray(skill_code(s.obs, 2))]
    for _ in range(3):  # the 3rd step truncates: the reset after it draws new skills
        s = auto_reset(env, step_batch(env, s, jnp.zeros((4, 2))))
        codes.append(np.asarray(skill_code(s.obs, 2)))
    for c in codes[1:3]:
        np.testing.assert_array_equal(c, codes[0])
    assert not np.allclose(codes[3], codes[0])
