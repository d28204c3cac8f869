"""Twin Delayed Deep Deterministic policy gradient (TD3).

Fujimoto et al. 2018, "Addressing Function Approximation Error in Actor-Critic
Methods" (arXiv:1802.09477), Algorithm 1: clipped double-Q targets (eq. 10),
target policy smoothing (eq. 14) and delayed actor and target updates.

The agent is a bundle of pure functions over `TD3State` (see
`qdrl.agents.base.Agent`). Every value population-based training may change —
learning rates, discount, tau, reward scale, noise scales — is read from
`state.hparams`. `td3_actor_step` is exposed on its own: the QD-RL emitters
(PGA-ME, QD-PG, ME-PBT) apply it to policies taken from a repertoire.
"""

from __future__ import annotations

import dataclasses
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
from qdrl.config import (
    NonNegativeFloat,
    PositiveFloat,
    PositiveInt,
    PositiveUnitFloat,
    UnitFloat,
    check_fields,
)
from qdrl.types import Array, Metrics, Params, PRNGKey, Transition

# Names of the PBT-tunable scalars held in `TD3State.hparams`.
HPARAM_NAMES = (
    "actor_lr",
    "critic_lr",
    "discount",
    "tau",
    "reward_scale",
    "policy_noise",
    "noise_clip",
    "expl_noise",
)


@dataclasses.dataclass(frozen=True)
class TD3Config:
    """TD3 hyperparameters; defaults from Fujimoto et al. 2018.

    The paper's Table 3 used 1e-3 and (400, 300); the authors' reference code
    (github.com/sfujim/TD3) moved to 3e-4 and (256, 256), which we follow.

    The training batch size is not here: the training loop owns it.
    """

    # Adam step size of the policy.
    actor_lr: PositiveFloat = 3e-4
    # Adam step size of the twin Q critics.
    critic_lr: PositiveFloat = 3e-4
    # gamma: weight of the bootstrapped next-state value in the critic target.
    discount: UnitFloat = 0.99
    # Polyak rate of the target networks: target <- tau * online + (1 - tau) * target.
    tau: PositiveUnitFloat = 0.005
    # Rewards are multiplied by this in the critic target.
    reward_scale: PositiveFloat = 1.0
    # Std of the Gaussian noise added to the target action (target policy smoothing).
    policy_noise: NonNegativeFloat = 0.2
    # That noise is clipped to [-noise_clip, noise_clip].
    noise_clip: NonNegativeFloat = 0.5
    # The actor and the targets are updated once every policy_delay critic updates.
    policy_delay: PositiveInt = 2
    # Std of the Gaussian noise added to actions when exploring (`act`).
    expl_noise: NonNegativeFloat = 0.1
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
        """The PBT-tunable scalars, as stored (as float32 arrays) in `TD3State.hparams`."""
        return {name: float(getattr(self, name)) for name in HPARAM_NAMES}


class TD3Networks(NamedTuple):
    """The two haiku networks of TD3."""

    policy: hk.Transformed  # obs -> action in [-1, 1]
    critic: hk.Transformed  # (obs, action) -> Q-values, shape (..., 2)


class TD3State(NamedTuple):
    """Everything TD3 learns and the tunable scalars it learns with."""

    policy_params: Params
    target_policy_params: Params
    critic_params: Params
    target_critic_params: Params
    policy_opt_state: optax.OptState  # Adam moments (optax.scale_by_adam)
    critic_opt_state: optax.OptState
    steps: Array  # int32 scalar, critic gradient steps taken
    hparams: dict[str, Array]  # float32 scalars, keys HPARAM_NAMES


class TD3Losses(NamedTuple):
    """Pure TD3 losses; each returns a scalar to minimise.

    critic(critic_params, target_policy_params, target_critic_params, transitions,
           discount, reward_scale, policy_noise, noise_clip, key)
           -> (loss, {"q_mean", "target_q_mean"})
    actor(policy_params, critic_params, obs) -> loss
    """

    critic: Callable[..., tuple[Array, dict[str, Array]]]
    actor: Callable[[Params, Params, Array], Array]


def make_td3_networks(config: TD3Config, action_size: int) -> TD3Networks:
    """The deterministic tanh policy and twin Q critic that `config` describes."""
    return TD3Networks(
        policy=nets.deterministic_policy(action_size, config.hidden, config.activation),
        critic=nets.twin_q_critic(config.hidden, config.activation),
    )


def make_td3_losses(networks: TD3Networks) -> TD3Losses:
    """Builds the TD3 critic and actor losses over `networks` (Fujimoto et al. 2018, eq. 10, 14)."""

    def critic_loss(
        critic_params: Params,
        target_policy_params: Params,
        target_critic_params: Params,
        transitions: Transition,
        discount: Array,
        reward_scale: Array,
        policy_noise: Array,
        noise_clip: Array,
        key: PRNGKey,
    ) -> tuple[Array, dict[str, Array]]:
        """0.5 E[sum_i (Q_i(s, a) - y)^2], y = c r + gamma m min_j Q'_j(s', a').

        a' = clip(pi'(s') + clip(sigma eps, -noise_clip, noise_clip), -1, 1) with eps
        drawn from `key`; m is `transitions.discount_mask`, so the target bootstraps
        through time-limit truncations and not through terminations.
        """
        next_action = networks.policy.apply(target_policy_params, transitions.next_obs)
        noise = policy_noise * jax.random.normal(key, next_action.shape, next_action.dtype)
        noise = jnp.clip(noise, -noise_clip, noise_clip)
        next_action = jnp.clip(next_action + noise, -1.0, 1.0)
        next_q = networks.critic.apply(target_critic_params, transitions.next_obs, next_action)
        target_q = jax.lax.stop_gradient(
            reward_scale * transitions.reward
            + discount * transitions.discount_mask * jnp.min(next_q, axis=-1)
        )
        q = networks.critic.apply(critic_params, transitions.obs, transitions.action)
        loss = critics_l2_loss(q, target_q)
        return loss, {"q_mean": jnp.mean(q), "target_q_mean": jnp.mean(target_q)}

    def actor_loss(policy_params: Params, critic_params: Params, obs: Array) -> Array:
        """-E[Q_1(s, pi(s))]: the deterministic policy gradient through the first critic."""
        action = networks.policy.apply(policy_params, obs)
        return -jnp.mean(networks.critic.apply(critic_params, obs, action)[..., 0])

    return TD3Losses(critic=critic_loss, actor=actor_loss)


def td3_actor_step(
    networks: TD3Networks,
    policy_params: Params,
    policy_opt_state: optax.OptState,
    critic_params: Params,
    obs: Array,
    lr: Array | float,
) -> tuple[Params, optax.OptState, Array]:
    """One Adam step of the TD3 actor loss -E[Q_1(s, pi(s))] on any policy.

    `policy_opt_state` is `optax.scale_by_adam().init(policy_params)` or the result
    of an earlier call. Returns the new params, the new optimiser state and the
    loss before the step. Used by the agent and by the QD-RL policy-gradient
    emitters (Nilsson and Cully 2021, PGA-ME).
    """
    loss, grads = jax.value_and_grad(make_td3_losses(networks).actor)(
        policy_params, critic_params, obs
    )
    policy_params, policy_opt_state = adam_step(policy_params, policy_opt_state, grads, lr)
    return policy_params, policy_opt_state, loss


def make_td3(
    config: TD3Config, obs_size: int, action_size: int, networks: TD3Networks | None = None
) -> Agent:
    """A TD3 agent (Fujimoto et al. 2018) for flat observations and actions in [-1, 1].

    `networks` defaults to `make_td3_networks(config, action_size)`; the QD-RL
    emitters pass their own, so that the actor has the genotypes' architecture
    (e.g. a 64x64 tanh policy) while the critic keeps TD3's.
    """
    config.check()
    check_size("obs_size", obs_size)
    check_size("action_size", action_size)
    if networks is None:
        networks = make_td3_networks(config, action_size)
    losses = make_td3_losses(networks)
    adam = optax.scale_by_adam()

    def init(key: PRNGKey) -> TD3State:
        policy_key, critic_key = jax.random.split(key)
        obs = jnp.zeros((1, obs_size))
        action = jnp.zeros((1, action_size))
        policy_params = networks.policy.init(policy_key, obs)
        critic_params = networks.critic.init(critic_key, obs, action)
        return TD3State(
            policy_params=policy_params,
            target_policy_params=policy_params,
            critic_params=critic_params,
            target_critic_params=critic_params,
            policy_opt_state=adam.init(policy_params),
            critic_opt_state=adam.init(critic_params),
            steps=jnp.zeros((), jnp.int32),
            hparams={k: jnp.asarray(v, jnp.float32) for k, v in config.hparams().items()},
        )

    def act(state: TD3State, obs: Array, key: PRNGKey) -> Array:
        action = networks.policy.apply(state.policy_params, obs)
        noise = state.hparams["expl_noise"] * jax.random.normal(key, action.shape, action.dtype)
        return jnp.clip(action + noise, -1.0, 1.0)

    def policy(policy_params: Params, obs: Array) -> Array:
        return networks.policy.apply(policy_params, obs)

    def policy_params(state: TD3State) -> Params:
        return state.policy_params

    def update(state: TD3State, transitions: Transition, key: PRNGKey) -> tuple[TD3State, Metrics]:
        """A critic step; every `policy_delay`-th call also an actor step and the target updates."""
        chex.assert_shape(transitions.obs, (None, obs_size))
        chex.assert_shape(transitions.action, (None, action_size))
        chex.assert_equal_shape([transitions.reward, transitions.terminated, transitions.truncated])
        hp = state.hparams
        (critic_loss, critic_aux), critic_grads = jax.value_and_grad(losses.critic, has_aux=True)(
            state.critic_params,
            state.target_policy_params,
            state.target_critic_params,
            transitions,
            hp["discount"],
            hp["reward_scale"],
            hp["policy_noise"],
            hp["noise_clip"],
            key,
        )
        critic_params, critic_opt_state = adam_step(
            state.critic_params, state.critic_opt_state, critic_grads, hp["critic_lr"]
        )

        def delayed(_: None) -> tuple[Params, Params, Params, optax.OptState, Array]:
            policy_params, policy_opt_state, actor_loss = td3_actor_step(
                networks,
                state.policy_params,
                state.policy_opt_state,
                critic_params,
                transitions.obs,
                hp["actor_lr"],
            )
            target_policy_params = optax.incremental_update(
                policy_params, state.target_policy_params, hp["tau"]
            )
            target_critic_params = optax.incremental_update(
                critic_params, state.target_critic_params, hp["tau"]
            )
            return (
                policy_params,
                target_policy_params,
                target_critic_params,
                policy_opt_state,
                actor_loss,
            )

        def skipped(_: None) -> tuple[Params, Params, Params, optax.OptState, Array]:
            # The loss is still reported, so logged actor losses have no gaps.
            actor_loss = losses.actor(state.policy_params, critic_params, transitions.obs)
            return (
                state.policy_params,
                state.target_policy_params,
                state.target_critic_params,
                state.policy_opt_state,
                actor_loss,
            )

        steps = state.steps + 1
        policy_params, target_policy_params, target_critic_params, policy_opt_state, actor_loss = (
            jax.lax.cond(steps % config.policy_delay == 0, delayed, skipped, None)
        )
        new_state = TD3State(
            policy_params=policy_params,
            target_policy_params=target_policy_params,
            critic_params=critic_params,
            target_critic_params=target_critic_params,
            policy_opt_state=policy_opt_state,
            critic_opt_state=critic_opt_state,
            steps=steps,
            hparams=state.hparams,
        )
        metrics = {"critic_loss": critic_loss, "actor_loss": actor_loss, **critic_aux}
        return new_state, metrics

    return Agent(init=init, act=act, policy=policy, policy_params=policy_params, update=update)
