"""QDAC: Quality-Diversity Actor-Critic (Grillotti, Faldor, González León & Cully, ICML 2024; arXiv:2403.09930).

Skills z are targets for the episode's average feature phi-bar in a feature space
(`qdrl.envs.skills.SkillSpace`); the policy pi(a | s, z) reads z's code appended to the
observation (`ContinuousSkillEnv`). For every skill QDAC solves

    max_pi E[sum_t gamma^t r_t]   subject to   ||(1 - gamma) psi(s, a, z) - z|| <= delta,

with a value critic Q(s, a, z) of the reward and a successor-features critic
psi(s, a, z) = E[sum_t gamma^t phi(s_{t+1})], whose (1 - gamma) multiple estimates the
discounted average feature. The constraint enters the actor's loss through a Lagrange
multiplier lambda(s, z) = sigmoid(l(s, z)) in [0, 1] (the paper's eq. 5-7):

    L_actor = E[alpha log pi(a|s,z) - (1 - lambda) mean_i Q_i(s, a, z)
                + c lambda h((1 - gamma) mean_i psi_i(s, a, z) - z)],   a ~ pi(.|s, z),

h the pseudo-Huber norm of scale `huber_delta`, c the `distance_scale`. lambda's network is
a classifier of the violated constraint: the binary cross-entropy of its logit against
[||(1 - gamma) psi(s, a, z) - z|| >= delta], so lambda rises where the constraint is
violated and falls where it holds (as QDAC's code trains it). The critic is SAC's (twin,
min target, entropy bonus; `qdrl.agents.sac`); psi learns by the same TD rule on the
features, y = phi(s') + gamma m mean_i psi'_i(s', a'), a' ~ pi(.|s', z) the value critic's
target action, m the bootstrap mask.

Each batch is joined by `relabel_batches` copies whose skills are redrawn from the prior:
neither the reward nor the features depend on z, so every stored transition teaches every
skill (QDAC's `num_random_skill_batches`). Features and skills are compared in the agent's
view of the feature space (`SkillSpace.normalise`: a box rescaled to [-1, 1]), as QDAC's
code compares them normalised.

The paper's ablations are options: `lagrange = "fixed"` holds lambda at `fixed_lagrange`;
`constraint = "naive"` (No-SF) replaces psi by a critic of the per-step reward
-||phi(s') - z||, whose (1 - gamma) multiple, negated, is the distance the constraint
bounds. UVFA, the third ablation, is SAC on that reward alone (`qdrl.agents.uvfa`).

All gradients of a step are taken at the parameters before it (QDAC's code updates lambda,
alpha, the critic, psi and the actor in turn, each seeing the previous ones' new values):
the five are independent, so XLA may run them together, as in qdrl's SAC.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Literal, NamedTuple

import chex
import haiku as hk
import jax
import jax.numpy as jnp
import optax

from qdrl import nets
from qdrl.agents.base import Agent
from qdrl.agents.common import adam_step
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
from qdrl.config import NonNegativeInt, PositiveFloat, UnitFloat, check_fields
from qdrl.envs.skills import SkillSpace, skill_code, with_skill_code
from qdrl.types import Array, Metrics, Params, PRNGKey, Transition

Constraint = Literal["successor_features", "naive"]


@dataclasses.dataclass(frozen=True)
class QDACConfig:
    """The `[qdac]` section: the constraint and its multiplier (SAC's settings are `[agent]`).

    Defaults from the paper's configuration (`configs/algo/qdac.yaml` of its code).
    """

    # delta: the distance to skill the constraint allows, in the normalised feature space.
    delta: PositiveFloat = 0.01
    # Scale of the pseudo-Huber distance in the actor's loss (QDAC's delta_pseudo_huber_loss).
    huber_delta: PositiveFloat = 1e-3
    # c: weight of the distance term in the actor's loss (QDAC's lambda_).
    distance_scale: PositiveFloat = 1.0
    # "learned": lambda(s, z) from a network; "fixed": lambda = fixed_lagrange everywhere.
    lagrange: Literal["learned", "fixed"] = "learned"
    # lambda of the fixed-lambda ablation.
    fixed_lagrange: UnitFloat = 0.5
    # Adam step size of lambda's network (QDAC uses SAC's learning rate).
    lagrange_lr: PositiveFloat = 3e-4
    # "successor_features" (QDAC) or "naive" (the No-SF ablation: a critic of -||phi - z||).
    constraint: Constraint = "successor_features"
    # Copies of each batch with skills redrawn from the prior, trained on with it.
    relabel_batches: NonNegativeInt = 1

    def check(self) -> None:
        """Raises ValueError naming the first `qdac.<field>` its declared type refuses."""
        check_fields(self, "qdac")


class QDACState(NamedTuple):
    """SAC's state (policy, value critic, temperature), psi's and lambda's."""

    sac: SACState
    feature_params: Params  # psi (or, with constraint "naive", the distance critic)
    target_feature_params: Params
    feature_opt_state: optax.OptState
    lagrange_params: Params  # lambda's logit network l(s, z)
    lagrange_opt_state: optax.OptState


def pseudo_huber(x: Array, scale: float) -> Array:
    """scale (sqrt(1 + ||x||^2 / scale^2) - 1) over the last axis: ~||x|| far from 0, smooth at 0."""
    return scale * (jnp.sqrt(1.0 + jnp.sum(jnp.square(x), axis=-1) / scale**2) - 1.0)


def binary_cross_entropy(logits: Array, labels: Array) -> Array:
    """Mean of -[y log sigmoid(l) + (1 - y) log sigmoid(-l)]."""
    return -jnp.mean(labels * jax.nn.log_sigmoid(logits) + (1.0 - labels) * jax.nn.log_sigmoid(-logits))


class QDACNetworks(NamedTuple):
    """SAC's policy and value critic, the successor-features critic and lambda's network."""

    sac: SACNetworks
    features: hk.Transformed  # (obs, action) -> psi of shape (..., 2, D) (naive: (..., 2, 1))
    lagrange: hk.Transformed  # obs -> the logit l(s, z) of lambda, shape (...,)


class QDACLosses(NamedTuple):
    """QDAC's own losses (the value critic's and the temperature's are SAC's).

    feature(params, policy_params, target_params, transitions, discount, key) -> (loss, mean psi)
    actor(policy_params, critic_params, feature_params, lagrange_params, alpha, obs, discount, key)
        -> (loss, (log pi, estimated distance, lambda))  of the sampled actions
    lagrange(params, obs, distance) -> loss
    """

    feature: Callable[..., tuple[Array, Array]]
    actor: Callable[..., tuple[Array, tuple[Array, Array, Array]]]
    lagrange: Callable[[Params, Array, Array], Array]


def make_qdac_networks(sac: SACConfig, config: QDACConfig, space: SkillSpace, action_size: int) -> QDACNetworks:
    """The networks `sac` and `config` describe, for skills of `space`."""
    size = 1 if config.constraint == "naive" else space.size
    return QDACNetworks(
        sac=make_sac_networks(sac, action_size),
        features=nets.twin_vector_critic(size, sac.hidden, sac.activation),
        lagrange=nets.scalar_head(sac.hidden, sac.activation, "lagrange"),
    )


def feature_targets(transitions: Transition, space: SkillSpace, constraint: Constraint) -> Array:
    """What psi accumulates per step (B, D): phi(s') in the agent's view of the feature space,
    or (naive) the reward -||phi(s') - z|| (B, 1)."""
    phi = space.normalise(transitions.next_desc)
    if constraint == "naive":
        return -jnp.linalg.norm(phi - skill_code(transitions.obs, space.size), axis=-1, keepdims=True)
    return phi


def make_qdac_losses(networks: QDACNetworks, config: QDACConfig, space: SkillSpace) -> QDACLosses:
    """The successor-features (or naive distance) critic's, the actor's and lambda's losses."""
    d = space.size
    naive = config.constraint == "naive"
    policy_net, critic_net, feature_net, lagrange_net = (
        networks.sac.policy, networks.sac.critic, networks.features, networks.lagrange
    )

    def feature_loss(
        params: Params, policy_params: Params, target_params: Params, transitions: Transition,
        discount: Array, key: PRNGKey,
    ) -> tuple[Array, Array]:
        """0.5 (psi_i(s, a) - y)^2 summed over the twin critics, averaged over batch and features;
        y = target + gamma m mean_i psi'_i(s', a'), a' ~ pi(.|s') drawn with `key`."""
        mean, log_std = policy_net.apply(policy_params, transitions.next_obs)
        next_action, _ = nets.sample_tanh_gaussian(mean, log_std, key)
        next_psi = jnp.mean(feature_net.apply(target_params, transitions.next_obs, next_action), axis=-2)
        targets = feature_targets(transitions, space, config.constraint)
        y = jax.lax.stop_gradient(targets + discount * transitions.discount_mask[:, None] * next_psi)
        psi = feature_net.apply(params, transitions.obs, transitions.action)
        return jnp.mean(jnp.sum(0.5 * jnp.square(psi - y[:, None, :]), axis=-2)), jnp.mean(psi)

    def distance(psi: Array, z: Array, discount: Array) -> tuple[Array, Array]:
        """The estimated distance to skill (B,), and the actor's penalty of it (B,)."""
        if naive:
            dist = -(1.0 - discount) * psi[..., 0]
            return dist, dist
        estimate = (1.0 - discount) * psi
        return jnp.linalg.norm(estimate - z, axis=-1), pseudo_huber(estimate - z, config.huber_delta)

    def lagrange(params: Params, obs: Array) -> Array:
        if config.lagrange == "fixed":
            return jnp.full(obs.shape[:-1], config.fixed_lagrange, jnp.float32)
        return jax.nn.sigmoid(lagrange_net.apply(params, obs))

    def actor_loss(
        policy_params: Params, critic_params: Params, feature_params: Params, lagrange_params: Params,
        alpha: Array, obs: Array, discount: Array, key: PRNGKey,
    ) -> tuple[Array, tuple[Array, Array, Array]]:
        """E[alpha log pi - (1 - lambda) mean_i Q_i + c lambda h(distance)]; returns the loss and
        (log pi, the estimated distance, lambda) of the sampled actions."""
        mean, log_std = policy_net.apply(policy_params, obs)
        action, log_prob = nets.sample_tanh_gaussian(mean, log_std, key)
        q = jnp.mean(critic_net.apply(critic_params, obs, action), axis=-1)
        psi = jnp.mean(feature_net.apply(feature_params, obs, action), axis=-2)
        dist, penalty = distance(psi, skill_code(obs, d), discount)
        lam = jax.lax.stop_gradient(lagrange(lagrange_params, obs))
        loss = jnp.mean(alpha * log_prob - (1.0 - lam) * q + config.distance_scale * lam * penalty)
        return loss, (log_prob, dist, lam)

    def lagrange_loss(params: Params, obs: Array, dist: Array) -> Array:
        """Cross-entropy of lambda's logit against the label [distance >= delta]."""
        labels = (dist >= config.delta).astype(jnp.float32)
        return binary_cross_entropy(lagrange_net.apply(params, obs), labels)

    return QDACLosses(feature=feature_loss, actor=actor_loss, lagrange=lagrange_loss)


def make_qdac(
    sac: SACConfig, config: QDACConfig, space: SkillSpace, obs_size: int, action_size: int
) -> Agent:
    """A QDAC agent for observations of size `obs_size` that end with the skill code of `space`.

    Batches are `Transition`s whose `next_desc` is the feature phi(s') in `space`'s raw units.
    SAC's `target_entropy` None means QDAC's -action_size / 2.
    """
    config.check()
    space.check("qdac skill space")
    d = space.size
    base = make_sac(sac, obs_size, action_size)
    networks = make_qdac_networks(sac, config, space, action_size)
    target_entropy = -0.5 * action_size if sac.target_entropy is None else float(sac.target_entropy)
    sac_losses = make_sac_losses(networks.sac, target_entropy)
    losses = make_qdac_losses(networks, config, space)
    adam = optax.scale_by_adam()

    def init(key: PRNGKey) -> QDACState:
        sac_key, feature_key, lagrange_key = jax.random.split(key, 3)
        sac_state: SACState = base.init(sac_key)  # log alpha from sac.init_alpha (QDAC: 1.0)
        obs, action = jnp.zeros((1, obs_size)), jnp.zeros((1, action_size))
        feature_params = networks.features.init(feature_key, obs, action)
        lagrange_params = networks.lagrange.init(lagrange_key, obs)
        return QDACState(
            sac=sac_state,
            feature_params=feature_params,
            target_feature_params=feature_params,
            feature_opt_state=adam.init(feature_params),
            lagrange_params=lagrange_params,
            lagrange_opt_state=adam.init(lagrange_params),
        )

    def relabel(transitions: Transition, key: PRNGKey) -> Transition:
        """The batch followed by `relabel_batches` copies with skills drawn from the prior."""
        if config.relabel_batches == 0:
            return transitions
        n = transitions.obs.shape[0]
        codes = space.normalise(space.sample(key, (config.relabel_batches, n)))
        copies = [
            transitions._replace(obs=with_skill_code(transitions.obs, c), next_obs=with_skill_code(transitions.next_obs, c))
            for c in codes
        ]
        return jax.tree.map(lambda *xs: jnp.concatenate(xs, axis=0), transitions, *copies)

    def update(state: QDACState, transitions: Transition, key: PRNGKey) -> tuple[QDACState, Metrics]:
        chex.assert_shape(transitions.obs, (None, obs_size))
        chex.assert_shape(transitions.next_desc, (None, d))
        # One draw of a' ~ pi(.|s') for both critics' targets: the policy's pass on s' is then the
        # same computation in both losses, which XLA evaluates once.
        relabel_key, critic_key, actor_key = jax.random.split(key, 3)
        tr = relabel(transitions, relabel_key)
        s = state.sac
        hp = s.hparams
        alpha = jnp.exp(s.log_alpha)
        (critic_loss, critic_aux), critic_grads = jax.value_and_grad(sac_losses.critic, has_aux=True)(
            s.critic_params, s.policy_params, s.target_critic_params, alpha, tr, hp["discount"],
            hp["reward_scale"], critic_key,
        )
        (feat_loss, psi_mean), feature_grads = jax.value_and_grad(losses.feature, has_aux=True)(
            state.feature_params, s.policy_params, state.target_feature_params, tr, hp["discount"], critic_key,
        )
        (act_loss, (log_prob, dist, lam)), actor_grads = jax.value_and_grad(losses.actor, has_aux=True)(
            s.policy_params, s.critic_params, state.feature_params, state.lagrange_params, alpha, tr.obs,
            hp["discount"], actor_key,
        )
        dist = jax.lax.stop_gradient(dist)
        lag_loss, lagrange_grads = jax.value_and_grad(losses.lagrange)(state.lagrange_params, tr.obs, dist)
        alpha_loss, alpha_grad = jax.value_and_grad(sac_losses.alpha)(s.log_alpha, log_prob)

        feature_params, feature_opt_state = adam_step(
            state.feature_params, state.feature_opt_state, feature_grads, hp["critic_lr"]
        )
        if config.lagrange == "learned":
            lagrange_params, lagrange_opt_state = adam_step(
                state.lagrange_params, state.lagrange_opt_state, lagrange_grads, config.lagrange_lr
            )
        else:
            lagrange_params, lagrange_opt_state = state.lagrange_params, state.lagrange_opt_state
        new_sac = sac_step(s, critic_grads, actor_grads, alpha_grad, sac.learn_alpha)
        new = QDACState(
            sac=new_sac,
            feature_params=feature_params,
            target_feature_params=optax.incremental_update(feature_params, state.target_feature_params, hp["tau"]),
            feature_opt_state=feature_opt_state,
            lagrange_params=lagrange_params,
            lagrange_opt_state=lagrange_opt_state,
        )
        metrics = {
            **sac_metrics(critic_loss, act_loss, alpha_loss, alpha, log_prob, critic_aux),
            "feature_loss": feat_loss,
            "feature_mean": psi_mean,
            "lagrange_loss": lag_loss,
            "lagrange": jnp.mean(lam),
            "constraint_distance": jnp.mean(dist),
            "constraint_violated": jnp.mean((dist >= config.delta).astype(jnp.float32)),
        }
        return new, metrics

    return Agent(
        init=init,
        act=lambda state, obs, key: base.act(state.sac, obs, key),
        policy=base.policy,
        policy_params=lambda state: state.sac.policy_params,
        update=update,
    )
