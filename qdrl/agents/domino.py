"""DOMiNO: Diversity Optimization Maintaining Near Optimality (Zahavy et al., ICLR 2023; arXiv:2205.13521).

K discrete skills z share one SAC policy pi(a | s, z) that reads z's one-hot code at the end of
the observation (`qdrl.envs.skills.SkillEnv`). Skill 0 maximises the extrinsic reward alone; every
other skill i maximises a diversity reward under the near-optimality constraint

    v_i >= rho v_0,   v_i the average extrinsic reward of skill i, rho the `optimality_ratio`,

through a Lagrange multiplier lambda_i = sigmoid(mu_i) that mixes the two rewards' soft values:

    L_actor = E[alpha log pi(a|s,z) - (lambda_z min_j Q^e_j(s, a, z) + (1 - lambda_z) min_j Q^d_j(s, a, z))],

lambda_0 = 1, Q^e the extrinsic critic (SAC's), Q^d a second twin critic of the diversity reward,
trained by the same soft TD rule. mu descends L_mu = sum_{i>=1} sigmoid(mu_i) (v_i - rho v_0):
lambda_i rises (more reward) while skill i is below rho v_0 and falls (more diversity) above it.

The diversity reward is the Van der Waals reward of the paper over average successor features
psi_i, each skill's moving average of the feature phi(s) (the state descriptor, `desc`):

    r^d(s, z) = c(||psi_z - psi_n|| / l0) phi(s) . (psi_z - psi_n) / D,
    c(x) = (1 - a) x^p_rep - a x^p_att,

psi_n the nearest other skill's, D the feature size; QDAC's settings (a = 0, p_rep = 0, so c = 1)
make it purely repulsive: phi(s) . (psi_z - psi_n) / D. v and psi are moving averages kept in the
state, v_i <- beta_v v_i + (1 - beta_v) mean(r), psi_i <- beta_psi psi_i + (1 - beta_psi) mean(phi),
each over skill i's transitions in the batch.

Facts from the QDAC paper's implementation (`baselines/qdax/baselines/domino.py` of
github.com/adaptive-intelligent-robotics/QDAC): these defaults, lambda_0 = 1, mu clipped to
[-15, 15], the diversity critic's entropy bonus, v the average per-step reward, phi = phi(s).
Departures: one skill-conditioned policy and pair of critics over one mixed replay buffer (that
code trains K independent SAC agents, one buffer each), hence masked per-skill averages; the
nearest other skill excludes the skill itself even on ties; the critics' and the temperature's
losses are qdrl's SAC's (summed over the twins, bootstrapping through truncations; the
temperature reads the actor's sampled actions). With rewards of either sign the
constraint reads as written: rho v_0 is above v_0 when v_0 < 0, as in that code.

All gradients of a step are taken at the parameters before it, and the Lagrange step and the
diversity reward read the averages before this batch updates them, as in that code.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import NamedTuple

import chex
import jax
import jax.numpy as jnp
import optax

from qdrl import nets
from qdrl.agents.base import Agent
from qdrl.agents.common import adam_step, check_size
from qdrl.agents.sac import (
    SACConfig,
    SACNetworks,
    SACState,
    make_sac,
    make_sac_losses,
    make_sac_networks,
    sac_metrics,
    sac_step,
)
from qdrl.config import NonNegativeFloat, PositiveFloat, UnitFloat, check_fields
from qdrl.envs.skills import skill_of
from qdrl.types import Array, Metrics, Params, PRNGKey, Transition


@dataclasses.dataclass(frozen=True)
class DOMiNOConfig:
    """The `[domino]` section: the constraint, its multipliers and the diversity reward.

    Defaults from the QDAC paper's DOMiNO baseline (`configs/algo/domino.yaml` of its code);
    SAC's settings are the `[agent]` section (there: Adam 1e-4, 256x256, alpha learnt from 1).
    """

    # rho: skill i must keep its average extrinsic reward >= rho times skill 0's.
    optimality_ratio: UnitFloat = 0.9
    # beta_v: decay of each skill's moving average of extrinsic reward (QDAC's alpha_d_v_avg).
    value_decay: UnitFloat = 0.9
    # beta_psi: decay of each skill's moving average of the feature phi(s) (QDAC's alpha_d_sfs_avg).
    feature_decay: UnitFloat = 0.99
    # Adam step size of the multipliers' logits mu (QDAC's learning_rate_lagrange).
    lagrange_lr: PositiveFloat = 1e-3
    # mu is clipped to [-lagrange_clip, lagrange_clip] after each step, so lambda never saturates.
    lagrange_clip: PositiveFloat = 15.0
    # a: the Van der Waals reward's attractive share (0: purely repulsive, as QDAC runs it).
    attractive_coeff: UnitFloat = 0.0
    # l0: the distance between successor features the forces balance at when a = 0.5.
    target_distance: PositiveFloat = 1.0
    # p_att: power of the attractive force.
    attractive_power: NonNegativeFloat = 3.0
    # p_rep: power of the repulsive force.
    repulsive_power: NonNegativeFloat = 0.0

    def check(self) -> None:
        """Raises ValueError naming the first `domino.<field>` its declared type refuses."""
        check_fields(self, "domino")


class DOMiNOState(NamedTuple):
    """SAC's state (policy, extrinsic critic, temperature), the diversity critic's, the
    multipliers' and the per-skill moving averages."""

    sac: SACState
    diversity_critic_params: Params  # Q^d, the same twin critic as SAC's, of the diversity reward
    target_diversity_critic_params: Params
    diversity_critic_opt_state: optax.OptState
    lagrange_logits: Array  # (K,) float32 mu; mu_0 unused (lambda_0 = 1) and never moves
    lagrange_opt_state: optax.OptState
    reward_avg: Array  # (K,) float32 v: each skill's moving average of extrinsic reward
    feature_avg: Array  # (K, D) float32 psi: each skill's moving average of phi(s)


class DOMiNOLosses(NamedTuple):
    """DOMiNO's own losses (both critics' and the temperature's are SAC's).

    actor(policy_params, critic_params, diversity_critic_params, lagrange_logits, alpha, obs, key)
        -> (loss, log pi of the sampled actions)
    lagrange(lagrange_logits, reward_avg) -> loss
    """

    actor: Callable[..., tuple[Array, Array]]
    lagrange: Callable[[Array, Array], Array]


def extrinsic_weight(lagrange_logits: Array, skills: Array) -> Array:
    """lambda_z per transition (B,): sigmoid(mu_z), and 1 for skill 0 (reward only)."""
    return jnp.where(skills == 0, 1.0, jax.nn.sigmoid(lagrange_logits[skills]))


def nearest_other_skill(feature_avg: Array) -> Array:
    """For each skill (K,), the other skill whose psi is nearest in L2 (itself only when K = 1)."""
    k = feature_avg.shape[0]
    dists = jnp.linalg.norm(feature_avg[:, None, :] - feature_avg[None, :, :], axis=-1)
    return jnp.argmin(jnp.where(jnp.eye(k, dtype=bool), jnp.inf, dists), axis=-1)


def diversity_reward(phi: Array, skills: Array, feature_avg: Array, config: DOMiNOConfig) -> Array:
    """The Van der Waals reward (B,) c(||psi_z - psi_n|| / l0) phi . (psi_z - psi_n) / D.

    phi (B, D) the features phi(s); skills (B,) int; feature_avg (K, D) the psi of every skill.
    """
    chex.assert_rank([phi, skills, feature_avg], [2, 1, 2])
    diff = feature_avg[skills] - feature_avg[nearest_other_skill(feature_avg)[skills]]
    x = jnp.linalg.norm(diff, axis=-1) / config.target_distance
    a = config.attractive_coeff
    # x^0 = 1 at x = 0 too (jnp.power): with QDAC's p_rep = 0 the repulsive term is 1 - a everywhere.
    c = (1.0 - a) * jnp.power(x, config.repulsive_power) - a * jnp.power(x, config.attractive_power)
    return c * jnp.sum(phi * diff, axis=-1) / phi.shape[-1]


def skill_moving_average(avg: Array, x: Array, skills: Array, decay: float) -> Array:
    """avg_k <- decay avg_k + (1 - decay) mean of x over skill k's rows, for every skill k with
    rows in the batch; the others unchanged. avg (K, ...), x (B, ...), skills (B,) int."""
    k = avg.shape[0]
    one_hot = jax.nn.one_hot(skills, k, dtype=x.dtype)  # (B, K)
    counts = jnp.sum(one_hot, axis=0).reshape((k,) + (1,) * (avg.ndim - 1))
    means = jnp.tensordot(one_hot, x, axes=(0, 0)) / jnp.maximum(counts, 1.0)
    return jnp.where(counts > 0, decay * avg + (1.0 - decay) * means, avg)


def make_domino_losses(networks: SACNetworks, config: DOMiNOConfig, num_skills: int) -> DOMiNOLosses:
    """The actor's loss (the two critics mixed by lambda) and the multipliers' loss."""
    policy_net, critic_net = networks.policy, networks.critic

    def actor_loss(
        policy_params: Params, critic_params: Params, diversity_critic_params: Params, lagrange_logits: Array,
        alpha: Array, obs: Array, key: PRNGKey,
    ) -> tuple[Array, Array]:
        """E[alpha log pi - (lambda_z min_j Q^e_j + (1 - lambda_z) min_j Q^d_j)], a ~ pi(.|s, z) drawn
        with `key`; returns the loss and log pi of the sampled actions."""
        mean, log_std = policy_net.apply(policy_params, obs)
        action, log_prob = nets.sample_tanh_gaussian(mean, log_std, key)
        q_e = jnp.min(critic_net.apply(critic_params, obs, action), axis=-1)
        q_d = jnp.min(critic_net.apply(diversity_critic_params, obs, action), axis=-1)
        lam = extrinsic_weight(jax.lax.stop_gradient(lagrange_logits), skill_of(obs, num_skills))
        return jnp.mean(alpha * log_prob - (lam * q_e + (1.0 - lam) * q_d)), log_prob

    def lagrange_loss(lagrange_logits: Array, reward_avg: Array) -> Array:
        """sum_{i>=1} sigmoid(mu_i) (v_i - rho v_0); v carries no gradient."""
        v = jax.lax.stop_gradient(reward_avg)
        return jnp.sum(jax.nn.sigmoid(lagrange_logits[1:]) * (v[1:] - config.optimality_ratio * v[0]))

    return DOMiNOLosses(actor=actor_loss, lagrange=lagrange_loss)


def make_domino(
    sac: SACConfig, config: DOMiNOConfig, num_skills: int, obs_size: int, action_size: int, feature_size: int
) -> Agent:
    """A DOMiNO agent for observations of size `obs_size` that end with a one-hot of `num_skills`.

    Batches are `Transition`s whose `desc` is the feature phi(s), of size `feature_size`, and may
    mix every skill. SAC's `target_entropy` None means -action_size / 2, as in QDAC's code.
    """
    config.check()
    check_size("num_skills", num_skills)
    check_size("feature_size", feature_size)
    if obs_size <= num_skills:
        raise ValueError(f"obs_size: expected more than num_skills={num_skills} (obs + one-hot), got {obs_size}")
    k, d = num_skills, feature_size
    base = make_sac(sac, obs_size, action_size)
    networks = make_sac_networks(sac, action_size)
    target_entropy = -0.5 * action_size if sac.target_entropy is None else float(sac.target_entropy)
    sac_losses = make_sac_losses(networks, target_entropy)
    losses = make_domino_losses(networks, config, k)
    adam = optax.scale_by_adam()

    def init(key: PRNGKey) -> DOMiNOState:
        sac_key, critic_key = jax.random.split(key)
        sac_state: SACState = base.init(sac_key)
        diversity_params = networks.critic.init(critic_key, jnp.zeros((1, obs_size)), jnp.zeros((1, action_size)))
        logits = jnp.zeros((k,), jnp.float32)  # lambda = 1/2, as QDAC's code starts
        return DOMiNOState(
            sac=sac_state,
            diversity_critic_params=diversity_params,
            target_diversity_critic_params=diversity_params,
            diversity_critic_opt_state=adam.init(diversity_params),
            lagrange_logits=logits,
            lagrange_opt_state=adam.init(logits),
            reward_avg=jnp.zeros((k,), jnp.float32),
            feature_avg=jnp.zeros((k, d), jnp.float32),
        )

    def update(state: DOMiNOState, transitions: Transition, key: PRNGKey) -> tuple[DOMiNOState, Metrics]:
        chex.assert_shape(transitions.obs, (None, obs_size))
        chex.assert_shape(transitions.action, (None, action_size))
        chex.assert_shape(transitions.desc, (None, d))
        critic_key, actor_key = jax.random.split(key)
        s = state.sac
        hp = s.hparams
        alpha = jnp.exp(s.log_alpha)
        skills = skill_of(transitions.obs, k)
        r_d = diversity_reward(transitions.desc, skills, state.feature_avg, config)

        # One key for both critics: their targets bootstrap from the same a' ~ pi(.|s'), as in QDAC's code.
        (critic_loss, critic_aux), critic_grads = jax.value_and_grad(sac_losses.critic, has_aux=True)(
            s.critic_params, s.policy_params, s.target_critic_params, alpha, transitions, hp["discount"],
            hp["reward_scale"], critic_key,
        )
        (div_loss, div_aux), div_grads = jax.value_and_grad(sac_losses.critic, has_aux=True)(
            state.diversity_critic_params, s.policy_params, state.target_diversity_critic_params, alpha,
            transitions._replace(reward=r_d), hp["discount"], hp["reward_scale"], critic_key,
        )
        (act_loss, log_prob), actor_grads = jax.value_and_grad(losses.actor, has_aux=True)(
            s.policy_params, s.critic_params, state.diversity_critic_params, state.lagrange_logits, alpha,
            transitions.obs, actor_key,
        )
        alpha_loss, alpha_grad = jax.value_and_grad(sac_losses.alpha)(s.log_alpha, log_prob)
        lag_loss, lagrange_grad = jax.value_and_grad(losses.lagrange)(state.lagrange_logits, state.reward_avg)

        div_params, div_opt_state = adam_step(
            state.diversity_critic_params, state.diversity_critic_opt_state, div_grads, hp["critic_lr"]
        )
        logits, lagrange_opt_state = adam_step(
            state.lagrange_logits, state.lagrange_opt_state, lagrange_grad, config.lagrange_lr
        )
        logits = jnp.clip(logits, -config.lagrange_clip, config.lagrange_clip)
        new_sac = sac_step(s, critic_grads, actor_grads, alpha_grad, sac.learn_alpha)
        new = DOMiNOState(
            sac=new_sac,
            diversity_critic_params=div_params,
            target_diversity_critic_params=optax.incremental_update(
                div_params, state.target_diversity_critic_params, hp["tau"]
            ),
            diversity_critic_opt_state=div_opt_state,
            lagrange_logits=logits,
            lagrange_opt_state=lagrange_opt_state,
            reward_avg=skill_moving_average(state.reward_avg, transitions.reward, skills, config.value_decay),
            feature_avg=skill_moving_average(state.feature_avg, transitions.desc, skills, config.feature_decay),
        )
        # The multipliers and the constraint of skills 1..K-1, as the step saw them.
        lam = jax.nn.sigmoid(state.lagrange_logits[1:])
        satisfied = (state.reward_avg[1:] >= config.optimality_ratio * state.reward_avg[0]).astype(jnp.float32)
        metrics = {
            **sac_metrics(critic_loss, act_loss, alpha_loss, alpha, log_prob, critic_aux),
            "diversity_critic_loss": div_loss,
            "diversity_q_mean": div_aux["q_mean"],
            "diversity_reward": jnp.mean(r_d),
            "lagrange_loss": lag_loss,
            "lagrange": jnp.mean(lam) if k > 1 else jnp.ones(()),
            "constraint_satisfied": jnp.mean(satisfied) if k > 1 else jnp.ones(()),
        }
        return new, metrics

    return Agent(
        init=init,
        act=lambda state, obs, key: base.act(state.sac, obs, key),
        policy=base.policy,
        policy_params=lambda state: state.sac.policy_params,
        update=update,
    )
