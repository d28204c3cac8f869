"""DOMiNO's diversity reward, losses and per-skill averages against values computed by hand; its
Lagrange multipliers' direction; the update with and without jit; its config's checks."""

from __future__ import annotations

import math

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from known_outputs import zeroed

from qdrl import nets
from qdrl.agents.domino import (
    DOMiNOConfig,
    diversity_reward,
    extrinsic_weight,
    make_domino,
    make_domino_losses,
    nearest_other_skill,
    skill_moving_average,
)
from qdrl.agents.sac import SACConfig, make_sac_networks
from qdrl.envs.skills import append_skill
from qdrl.types import Transition

K, OBS, ACT, D = 3, 3, 2, 2  # skills, observation without the skill code, actions, features
SAC = SACConfig(hidden=(8, 8))
PSI = jnp.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0]])  # nearest other skill: 0 -> 1, 1 -> 0, 2 -> 1


def batch(skills: list[int], reward: list[float] | None = None, seed: int = 0) -> Transition:
    """Transitions of the given skills (one-hot at the end of the observations), random features."""
    n = len(skills)
    k = jax.random.split(jax.random.PRNGKey(seed), 5)
    z = jnp.asarray(skills, jnp.int32)
    obs = append_skill(jax.random.normal(k[0], (n, OBS)), z, K)
    next_obs = append_skill(jax.random.normal(k[1], (n, OBS)), z, K)
    r = jax.random.normal(k[2], (n,)) if reward is None else jnp.asarray(reward, jnp.float32)
    desc, next_desc = jax.random.normal(k[3], (n, D)), jax.random.normal(k[4], (n, D))
    zeros = jnp.zeros((n,))
    return Transition(obs, jnp.zeros((n, ACT)), r, next_obs, zeros.at[0].set(1.0), zeros, desc, next_desc)


def test_nearest_other_skill_never_picks_itself() -> None:
    np.testing.assert_array_equal(nearest_other_skill(PSI), [1, 0, 1])
    # ties, e.g. every psi at its initial 0: the first other skill, never the skill itself
    np.testing.assert_array_equal(nearest_other_skill(jnp.zeros((3, 2))), [1, 0, 0])


def test_diversity_reward_by_hand() -> None:
    phi = jnp.array([[1.0, 2.0], [2.0, 1.0], [0.5, -1.0], [-1.0, 4.0]])
    skills = jnp.array([0, 1, 2, 2])
    # QDAC's settings, purely repulsive: phi . (psi_z - psi_nearest) / D
    diffs = np.array([[-1.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 0.0]])
    want = np.sum(np.asarray(phi) * diffs, axis=-1) / 2
    np.testing.assert_allclose(want, [-0.5, 1.0, 0.5, -1.0])
    np.testing.assert_allclose(diversity_reward(phi, skills, PSI, DOMiNOConfig()), want, rtol=1e-6)
    # the Van der Waals coefficient c(x) = (1 - a) x^p_rep - a x^p_att, x = ||psi_z - psi_n|| / l0
    config = DOMiNOConfig(attractive_coeff=0.5, target_distance=4.0, repulsive_power=1.0, attractive_power=2.0)
    x = np.array([0.25, 0.25, 0.5, 0.5])
    c = 0.5 * x - 0.5 * x**2
    np.testing.assert_allclose(diversity_reward(phi, skills, PSI, config), c * want, rtol=1e-6)


def test_skill_moving_average_updates_only_the_skills_in_the_batch() -> None:
    avg = jnp.array([1.0, 2.0, 3.0])
    new = skill_moving_average(avg, jnp.array([1.0, 3.0, 5.0]), jnp.array([0, 0, 2]), 0.9)
    np.testing.assert_allclose(new, [0.9 * 1 + 0.1 * 2, 2.0, 0.9 * 3 + 0.1 * 5], rtol=1e-6)
    feats = jnp.ones((3, 2))
    new = skill_moving_average(feats, jnp.array([[2.0, 4.0], [0.0, 0.0]]), jnp.array([1, 1]), 0.5)
    np.testing.assert_allclose(new, np.array([[1.0, 1.0], [0.5 + 0.5 * 1, 0.5 + 0.5 * 2], [1.0, 1.0]]), rtol=1e-6)


def test_actor_and_lagrange_losses_by_hand() -> None:
    networks = make_sac_networks(SAC, ACT)
    losses = make_domino_losses(networks, DOMiNOConfig(optimality_ratio=0.9), K)
    tr = batch([0, 1, 2, 2])
    key = jax.random.PRNGKey(2)
    policy = networks.policy.init(key, tr.obs)
    critic = networks.critic.init(key, tr.obs, tr.action)
    q_e, q_d = zeroed(critic, 3.0), zeroed(critic, -1.0)
    # lambda: skill 0 always 1 (its logit unused), sigmoid(log 3) = 0.75, sigmoid(-log 3) = 0.25
    logits = jnp.array([5.0, math.log(3.0), -math.log(3.0)])
    lam = np.array([1.0, 0.75, 0.25, 0.25])
    np.testing.assert_allclose(extrinsic_weight(logits, jnp.array([0, 1, 2, 2])), lam, rtol=1e-6)
    alpha = 0.2
    loss, log_prob = losses.actor(policy, q_e, q_d, logits, alpha, tr.obs, key)
    mean, log_std = networks.policy.apply(policy, tr.obs)
    _, want_log_prob = nets.sample_tanh_gaussian(mean, log_std, key)
    np.testing.assert_allclose(log_prob, want_log_prob, rtol=1e-6)
    want = np.mean(alpha * np.asarray(want_log_prob) - (lam * 3.0 + (1 - lam) * -1.0))
    assert float(loss) == pytest.approx(float(want), rel=1e-5)
    # no gradient reaches the multipliers through the actor's loss
    grad = jax.grad(lambda mu: losses.actor(policy, q_e, q_d, mu, alpha, tr.obs, key)[0])(logits)
    np.testing.assert_array_equal(grad, 0.0)

    # sum_{i>=1} sigmoid(mu_i) (v_i - rho v_0): skill 1 below rho v_0 = 1.8, skill 2 above
    mu, v = jnp.array([0.0, math.log(3.0), 0.0]), jnp.array([2.0, 1.0, 3.0])
    assert float(losses.lagrange(mu, v)) == pytest.approx(0.75 * (1 - 1.8) + 0.5 * (3 - 1.8), rel=1e-6)
    grad = np.asarray(jax.grad(losses.lagrange)(mu, v))
    assert grad[0] == 0.0 and grad[1] < 0.0 < grad[2]  # descent raises lambda_1 and lowers lambda_2
    assert grad[1] == pytest.approx(0.75 * 0.25 * (1 - 1.8), rel=1e-6)


def test_update_losses_and_averages_by_hand() -> None:
    config = DOMiNOConfig(value_decay=0.8, feature_decay=0.5)
    agent = make_domino(SAC, config, K, OBS + K, ACT, D)
    state = agent.init(jax.random.PRNGKey(0))
    s = state.sac
    # Q^e = 1 and its target 0.5, Q^d = -2 and its target 0.25; alpha ~ 0, so targets are r + gamma m Q'
    state = state._replace(
        sac=s._replace(critic_params=zeroed(s.critic_params, 1.0), target_critic_params=zeroed(s.critic_params, 0.5),
                       log_alpha=jnp.asarray(-60.0)),
        diversity_critic_params=zeroed(s.critic_params, -2.0),
        target_diversity_critic_params=zeroed(s.critic_params, 0.25),
        lagrange_logits=jnp.array([0.0, math.log(3.0), 0.0]),
        reward_avg=jnp.array([2.0, 1.0, 3.0]),
        feature_avg=PSI,
    )
    tr = batch([0, 2, 0, 2], reward=[1.0, 2.0, 3.0, 4.0])  # no transition of skill 1
    new, m = jax.jit(agent.update)(state, tr, jax.random.PRNGKey(1))
    gamma, mask = 0.99, 1.0 - np.asarray(tr.terminated)
    r_d = np.asarray(diversity_reward(tr.desc, jnp.array([0, 2, 0, 2]), PSI, config))
    # the twins' 0.5 (Q - y)^2 summed, averaged over the batch
    y_e = np.asarray(tr.reward) + gamma * mask * 0.5
    y_d = r_d + gamma * mask * 0.25
    assert float(m["critic_loss"]) == pytest.approx(float(np.mean((1.0 - y_e) ** 2)), rel=1e-5)
    assert float(m["diversity_critic_loss"]) == pytest.approx(float(np.mean((-2.0 - y_d) ** 2)), rel=1e-5)
    assert float(m["diversity_reward"]) == pytest.approx(float(np.mean(r_d)), rel=1e-5)
    lam = np.array([1.0, 0.5, 1.0, 0.5])  # skills 0, 2, 0, 2
    assert float(m["actor_loss"]) == pytest.approx(float(np.mean(-(lam * 1.0 + (1 - lam) * -2.0))), rel=1e-5)
    assert float(m["lagrange_loss"]) == pytest.approx(0.75 * (1 - 0.9 * 2) + 0.5 * (3 - 0.9 * 2), rel=1e-5)
    assert float(m["lagrange"]) == pytest.approx((0.75 + 0.5) / 2, rel=1e-6)
    assert float(m["constraint_satisfied"]) == 0.5  # v_1 = 1 < 1.8 <= v_2 = 3
    # averages: skill 0 from rewards 1, 3 and its two descriptors; skill 1 untouched; skill 2 from 2, 4
    np.testing.assert_allclose(new.reward_avg, [0.8 * 2 + 0.2 * 2, 1.0, 0.8 * 3 + 0.2 * 3], rtol=1e-6)
    desc = np.asarray(tr.desc)
    want_psi = np.asarray(PSI).copy()
    want_psi[0] = 0.5 * want_psi[0] + 0.5 * desc[[0, 2]].mean(0)
    want_psi[2] = 0.5 * want_psi[2] + 0.5 * desc[[1, 3]].mean(0)
    np.testing.assert_allclose(new.feature_avg, want_psi, rtol=1e-5)


def test_lagrange_multipliers_rise_below_the_constraint_and_fall_above() -> None:
    agent = make_domino(SAC, DOMiNOConfig(optimality_ratio=0.9, lagrange_lr=1e-2), K, OBS + K, ACT, D)
    # each skill's rewards equal its average: v = (1, 0.5, 1) throughout; skill 1 < 0.9 <= skill 2
    state = agent.init(jax.random.PRNGKey(0))._replace(reward_avg=jnp.array([1.0, 0.5, 1.0]))
    tr = batch([0, 1, 2] * 4, reward=[1.0, 0.5, 1.0] * 4)
    update = jax.jit(agent.update)
    for i in range(20):
        state, metrics = update(state, tr, jax.random.PRNGKey(i))
        assert float(metrics["constraint_satisfied"]) == 0.5
    np.testing.assert_allclose(state.reward_avg, [1.0, 0.5, 1.0], rtol=1e-6)
    lam = np.asarray(jax.nn.sigmoid(state.lagrange_logits))
    assert float(state.lagrange_logits[0]) == 0.0  # skill 0 has no constraint
    assert lam[1] > 0.5 + 0.04 and lam[2] < 0.5 - 0.04, lam


@pytest.mark.parametrize("jit", [True, False])
def test_update_runs_the_same_with_and_without_jit(jit: bool) -> None:
    agent = make_domino(SAC, DOMiNOConfig(), K, OBS + K, ACT, D)
    state = agent.init(jax.random.PRNGKey(0))
    tr = batch([0, 1, 2, 1, 0, 2])
    update = jax.jit(agent.update) if jit else agent.update
    new, metrics = update(state, tr, jax.random.PRNGKey(1))
    assert all(np.isfinite(float(v)) for v in metrics.values())
    assert int(new.sac.steps) == 1
    other, _ = (agent.update if jit else jax.jit(agent.update))(state, tr, jax.random.PRNGKey(1))
    chex.assert_trees_all_close(new, other, rtol=1e-4, atol=1e-6)
    for name in ("critic_loss", "diversity_critic_loss", "actor_loss", "alpha_loss", "lagrange_loss",
                 "lagrange", "constraint_satisfied", "diversity_reward"):
        assert name in metrics
    assert agent.act(new, tr.obs, jax.random.PRNGKey(2)).shape == (6, ACT)
    assert agent.policy(agent.policy_params(new), tr.obs).shape == (6, ACT)


@pytest.mark.parametrize(
    ("field", "value"),
    [("optimality_ratio", 1.5), ("value_decay", -0.1), ("feature_decay", 2.0), ("lagrange_lr", 0.0),
     ("lagrange_clip", -1.0), ("attractive_coeff", 1.1), ("target_distance", 0.0), ("repulsive_power", -1.0)],
)
def test_bad_config_values_are_refused(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=rf"domino\.{field}"):
        make_domino(SAC, DOMiNOConfig(**{field: value}), K, OBS + K, ACT, D)


def test_bad_sizes_are_refused() -> None:
    with pytest.raises(ValueError, match="num_skills"):
        make_domino(SAC, DOMiNOConfig(), 0, OBS + K, ACT, D)
    with pytest.raises(ValueError, match="feature_size"):
        make_domino(SAC, DOMiNOConfig(), K, OBS + K, ACT, 0)
    with pytest.raises(ValueError, match="obs_size"):
        make_domino(SAC, DOMiNOConfig(), K, K, ACT, D)
