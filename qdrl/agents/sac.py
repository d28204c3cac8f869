"""Soft Actor-Critic with learned temperature.

Haarnoja et al. 2018, "Soft Actor-Critic Algorithms and Applications"
(arXiv:1812.05905): twin soft Q critics with Polyak-averaged targets (eq. 5-6),
a reparameterised tanh-Gaussian actor (eq. 7-8) and automatic entropy
adjustment towards a target entropy (eq. 17-18).

The agent is a bundle of pure functions over `SACState` (see
`qdrl.agents.base.Agent`). Every value population-based training may change —
learning rates, discount, tau, reward scale — is read from `state.hparams`, so a
vmapped population of states can hold a different value per member.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import NamedTuple

import chex
import haiku as hk
import jax
import jax.numpy as jnp
import optax

from qdrl import nets
from qdrl.agents.base import Agent
from qdrl.agents.common import Activation, Hidden, adam_step, check_size, critics_l2_loss
from qdrl.config import PositiveFloat, PositiveUnitFloat, UnitFloat, check_fields
from qdrl.types import Array, Metrics, Params, PRNGKey, Transition

# Names of the PBT-tunable scalars held in `SACState.hparams`.
HPARAM_NAMES = ("actor_lr", "critic_lr", "alpha_lr", "discount", "tau", "reward_scale")


@dataclasses.dataclass(frozen=True)
class SACConfig:
    """SAC hyperparameters; defaults from Haarnoja et al. 2018 (Table 1).

    The training batch size is not here: the training loop owns it.
    """

    # Adam step size of the policy.
    actor_lr: PositiveFloat = 3e-4
    # Adam step size of the twin Q critics.
    critic_lr: PositiveFloat = 3e-4
    # Adam step size of log(alpha), the entropy temperature.
    alpha_lr: PositiveFloat = 3e-4
    # gamma: weight of the bootstrapped next-state value in the critic target.
    discount: UnitFloat = 0.99
    # Polyak rate of the target critics: target <- tau * online + (1 - tau) * target.
    tau: PositiveUnitFloat = 0.005
    # Rewards are multiplied by this in the critic target.
    reward_scale: PositiveFloat = 1.0
    # Entropy temperature alpha at initialisation (and forever if learn_alpha is False).
    init_alpha: PositiveFloat = 1.0
    # Entropy the temperature drives the policy towards; None means -action_size.
    target_entropy: float | None = None
    # Whether alpha is learned (eq. 18) or held at init_alpha.
    learn_alpha: bool = True
    # Hidden layer widths of the policy and of each critic.
    hidden: Hidden = (256, 256)
    # Activation of the hidden layers; a key of `qdrl.nets.ACTIVATIONS`.
    activation: Activation = "relu"

    def __post_init__(self) -> None:
        # TOML and JSON give lists; a tuple keeps the config hashable.
        if isinstance(self.hidden, list):
            object.__setattr__(self, "hidden", tuple(self.hidden))

    def check(self) -> None:
        """Raises ValueError naming the first `agent.<field>` its declared type refuses."""
        check_fields(self, "agent")

    def hparams(self) -> dict[str, float]:
        """The PBT-tunable scalars, as stored (as float32 arrays) in `SACState.hparams`."""
        return {name: float(getattr(self, name)) for name in HPARAM_NAMES}


class SACNetworks(NamedTuple):
    """The two haiku networks of SAC."""

    policy: hk.Transformed  # obs -> (mean, log_std) of the pre-tanh Gaussian
    critic: hk.Transformed  # (obs, action) -> Q-values, shape (..., 2)


class SACState(NamedTuple):
    """Everything SAC learns and the tunable scalars it learns with."""

    policy_params: Params
    critic_params: Params
    target_critic_params: Params
    policy_opt_state: optax.OptState  # Adam moments (optax.scale_by_adam)
    critic_opt_state: optax.OptState
    log_alpha: Array  # float32 scalar, log of the entropy temperature
    alpha_opt_state: optax.OptState
    steps: Array  # int32 scalar, gradient steps taken
    hparams: dict[str, Array]  # float32 scalars, keys HPARAM_NAMES


class SACLosses(NamedTuple):
    """Pure SAC losses; each returns a scalar to minimise (critic and actor with aux metrics).

    critic(critic_params, policy_params, target_critic_params, alpha, transitions,
           discount, reward_scale, key) -> (loss, {"q_mean", "target_q_mean"})
    actor(policy_params, critic_params, alpha, obs, key) -> (loss, log_prob)
    alpha(log_alpha, log_prob) -> loss
    """

    critic: Callable[..., tuple[Array, dict[str, Array]]]
    actor: Callable[..., tuple[Array, Array]]
    alpha: Callable[[Array, Array], Array]


def make_sac_networks(config: SACConfig, action_size: int) -> SACNetworks:
    """The tanh-Gaussian policy and twin Q critic that `config` describes."""
    return SACNetworks(
        policy=nets.gaussian_policy(action_size, config.hidden, config.activation),
        critic=nets.twin_q_critic(config.hidden, config.activation),
    )


def make_sac_losses(networks: SACNetworks, target_entropy: float) -> SACLosses:
    """Builds the SAC critic, actor and temperature losses over `networks`.

    Haarnoja et al. 2018 (arXiv:1812.05905), eq. 5 (critic), eq. 7 (actor),
    eq. 18 (temperature).
    """

    def critic_loss(
        critic_params: Params,
        policy_params: Params,
        target_critic_params: Params,
        alpha: Array,
        transitions: Transition,
        discount: Array,
        reward_scale: Array,
        key: PRNGKey,
    ) -> tuple[Array, dict[str, Array]]:
        """0.5 E[sum_i (Q_i(s, a) - y)^2], y = c r + gamma m (min_j Q'_j(s', a') - alpha log pi(a'|s')).

        a' ~ pi(.|s') is drawn with `key`; m is `transitions.discount_mask`, so the
        target bootstraps through time-limit truncations and not through terminations.
        """
        mean, log_std = networks.policy.apply(policy_params, transitions.next_obs)
        next_action, next_log_prob = nets.sample_tanh_gaussian(mean, log_std, key)
        next_q = networks.critic.apply(target_critic_params, transitions.next_obs, next_action)
        next_v = jnp.min(next_q, axis=-1) - alpha * next_log_prob
        target_q = jax.lax.stop_gradient(
            reward_scale * transitions.reward + discount * transitions.discount_mask * next_v
        )
        q = networks.critic.apply(critic_params, transitions.obs, transitions.action)
        loss = critics_l2_loss(q, target_q)
        return loss, {"q_mean": jnp.mean(q), "target_q_mean": jnp.mean(target_q)}

    def actor_loss(
        policy_params: Params,
        critic_params: Params,
        alpha: Array,
        obs: Array,
        key: PRNGKey,
    ) -> tuple[Array, Array]:
        """E[alpha log pi(a|s) - min_i Q_i(s, a)], a = tanh(mu + sigma eps) drawn with `key`.

        Returns the loss and the log-probabilities of the sampled actions (for the
        temperature loss).
        """
        mean, log_std = networks.policy.apply(policy_params, obs)
        action, log_prob = nets.sample_tanh_gaussian(mean, log_std, key)
        q = jnp.min(networks.critic.apply(critic_params, obs, action), axis=-1)
        return jnp.mean(alpha * log_prob - q), log_prob

    def alpha_loss(log_alpha: Array, log_prob: Array) -> Array:
        """E[-alpha (log pi(a|s) + H_target)], alpha = exp(log_alpha); no gradient to log_prob."""
        log_prob = jax.lax.stop_gradient(log_prob)
        return jnp.mean(jnp.exp(log_alpha) * (-log_prob - target_entropy))

    return SACLosses(critic=critic_loss, actor=actor_loss, alpha=alpha_loss)


def sac_step(
    state: SACState, critic_grads: Params, actor_grads: Params, alpha_grad: Array, learn_alpha: bool = True
) -> SACState:
    """SAC's parameters after one step: Adam on the critics, the actor and (if `learn_alpha`)
    log alpha with the learning rates of `state.hparams`, then the Polyak target update
    (Algorithm 1). Every agent built on SAC's networks (QDAC, DOMiNO) steps them with this."""
    hp = state.hparams
    critic_params, critic_opt_state = adam_step(
        state.critic_params, state.critic_opt_state, critic_grads, hp["critic_lr"]
    )
    policy_params, policy_opt_state = adam_step(
        state.policy_params, state.policy_opt_state, actor_grads, hp["actor_lr"]
    )
    if learn_alpha:
        log_alpha, alpha_opt_state = adam_step(state.log_alpha, state.alpha_opt_state, alpha_grad, hp["alpha_lr"])
    else:
        log_alpha, alpha_opt_state = state.log_alpha, state.alpha_opt_state
    return SACState(
        policy_params=policy_params,
        critic_params=critic_params,
        target_critic_params=optax.incremental_update(critic_params, state.target_critic_params, hp["tau"]),
        policy_opt_state=policy_opt_state,
        critic_opt_state=critic_opt_state,
        log_alpha=log_alpha,
        alpha_opt_state=alpha_opt_state,
        steps=state.steps + 1,
        hparams=state.hparams,
    )


def sac_metrics(
    critic_loss: Array, actor_loss: Array, alpha_loss: Array, alpha: Array, log_prob: Array,
    critic_aux: dict[str, Array],
) -> dict[str, Array]:
    """The metrics of one SAC step, which every agent built on SAC's losses also logs."""
    return {
        "critic_loss": critic_loss,
        "actor_loss": actor_loss,
        "alpha_loss": alpha_loss,
        "alpha": alpha,
        "entropy": -jnp.mean(log_prob),
        **critic_aux,
    }


def make_sac(config: SACConfig, obs_size: int, action_size: int) -> Agent:
    """A SAC agent (Haarnoja et al. 2018) for flat observations and actions in [-1, 1]."""
    config.check()
    check_size("obs_size", obs_size)
    check_size("action_size", action_size)
    networks = make_sac_networks(config, action_size)
    target_entropy = (
        -float(action_size) if config.target_entropy is None else float(config.target_entropy)
    )
    losses = make_sac_losses(networks, target_entropy)
    adam = optax.scale_by_adam()

    def init(key: PRNGKey) -> SACState:
        policy_key, critic_key = jax.random.split(key)
        obs = jnp.zeros((1, obs_size))
        action = jnp.zeros((1, action_size))
        policy_params = networks.policy.init(policy_key, obs)
        critic_params = networks.critic.init(critic_key, obs, action)
        log_alpha = jnp.asarray(math.log(config.init_alpha), jnp.float32)
        return SACState(
            policy_params=policy_params,
            critic_params=critic_params,
            target_critic_params=critic_params,
            policy_opt_state=adam.init(policy_params),
            critic_opt_state=adam.init(critic_params),
            log_alpha=log_alpha,
            alpha_opt_state=adam.init(log_alpha),
            steps=jnp.zeros((), jnp.int32),
            hparams={k: jnp.asarray(v, jnp.float32) for k, v in config.hparams().items()},
        )

    def act(state: SACState, obs: Array, key: PRNGKey) -> Array:
        mean, log_std = networks.policy.apply(state.policy_params, obs)
        action, _ = nets.sample_tanh_gaussian(mean, log_std, key)
        return action

    def policy(policy_params: Params, obs: Array) -> Array:
        mean, _ = networks.policy.apply(policy_params, obs)
        return jnp.tanh(mean)

    def policy_params(state: SACState) -> Params:
        return state.policy_params

    def update(state: SACState, transitions: Transition, key: PRNGKey) -> tuple[SACState, Metrics]:
        """Critic, actor and temperature steps, then the Polyak target update (Algorithm 1)."""
        chex.assert_shape(transitions.obs, (None, obs_size))
        chex.assert_shape(transitions.action, (None, action_size))
        chex.assert_equal_shape([transitions.reward, transitions.terminated, transitions.truncated])
        hp = state.hparams
        critic_key, actor_key = jax.random.split(key)
        alpha = jnp.exp(state.log_alpha)

        (critic_loss, critic_aux), critic_grads = jax.value_and_grad(losses.critic, has_aux=True)(
            state.critic_params,
            state.policy_params,
            state.target_critic_params,
            alpha,
            transitions,
            hp["discount"],
            hp["reward_scale"],
            critic_key,
        )
        # The actor's gradient is taken against the critic of before this step, like
        # the critic's and the temperature's: the three gradients are independent,
        # which lets XLA run them concurrently (Haarnoja et al.'s implementation also
        # computes all gradients from the same parameters).
        (actor_loss, log_prob), actor_grads = jax.value_and_grad(losses.actor, has_aux=True)(
            state.policy_params, state.critic_params, alpha, transitions.obs, actor_key
        )
        alpha_loss, alpha_grad = jax.value_and_grad(losses.alpha)(state.log_alpha, log_prob)
        new_state = sac_step(state, critic_grads, actor_grads, alpha_grad, config.learn_alpha)
        return new_state, sac_metrics(critic_loss, actor_loss, alpha_loss, alpha, log_prob, critic_aux)

    return Agent(init=init, act=act, policy=policy, policy_params=policy_params, update=update)
