"""DIAYN: Diversity Is All You Need (Eysenbach et al. 2018, arXiv:1802.06070).

Skills z are one-hot codes appended to the observation (`qdrl.envs.skills`); a
discriminator q_phi(z | s) learns to tell the skill from the state it leads to,
and the policy (SAC, unchanged) maximises the pseudo-reward of Algorithm 1,

    r_div = log q_phi(z | s_{t+1}) - log p(z),   p(z) uniform over K skills,

so r_div = log q_phi(z | s') + log K: 0 at chance, log K when the discriminator
is sure. The discriminator reads the state descriptor (e.g. the x-y position,
the "x-y prior" of the paper's appendix) or the full observation (without the
skill code), as configured, and is trained with its own Adam on the same batch,
by cross-entropy, in the same update step (`qdrl.agents.intrinsic`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import haiku as hk
import jax
import jax.numpy as jnp
import optax

from qdrl import nets
from qdrl.agents.base import Agent
from qdrl.agents.common import Hidden
from qdrl.agents.intrinsic import (
    Gate,
    Info,
    RewardModule,
    SkillInput,
    SkillModelConfig,
    with_skill_model,
)
from qdrl.config import PositiveInt
from qdrl.envs.skills import skill_of, strip_skill
from qdrl.types import Array, Metrics, Params, PRNGKey, Transition


@dataclasses.dataclass(frozen=True)
class DIAYNConfig(SkillModelConfig):
    """DIAYN's own settings (the `[skills]` section); SAC's are the `[agent]` section.

    Defaults from Eysenbach et al. 2018 (appendix): 50 skills, a discriminator q(z|s')
    of two hidden layers of 300 units, Adam 3e-4; pure skill discovery (no task reward).
    """

    num_skills: PositiveInt = 50
    hidden: Hidden = (300, 300)
    # Continuous skills: z ~ U[-1, 1]^num_skills (the observation's last num_skills entries) and a
    # Gaussian discriminator q(z | s') = N(mu(s'), diag sigma(s')^2), the continuous DIAYN the QDAC
    # paper's SMERL baselines use; False: K one-hot skills and a softmax discriminator.
    continuous: bool = False


class DiscriminatorState(NamedTuple):
    """Parameters of q_phi(z | s) and their Adam moments."""

    params: Params
    opt_state: optax.OptState


def discriminator_network(
    num_skills: int, hidden: tuple[int, ...] = (300, 300), act: str = "relu"
) -> hk.Transformed:
    """x -> logits of q(z | x), shape (..., num_skills)."""

    def forward(x: Array) -> Array:
        return hk.nets.MLP([*hidden, num_skills], activation=nets.activation(act))(x)

    return hk.without_apply_rng(hk.transform(forward))


def diayn_reward(logits: Array, skills: Array) -> Array:
    """r = log q(z | s') - log p(z) = log_softmax(logits)[z] + log K (Eysenbach et al., Alg. 1).

    Args:
      logits: (B, K) discriminator logits at the next states.
      skills: (B,) int skills that produced them.
    """
    num_skills = logits.shape[-1]
    log_q = jnp.take_along_axis(jax.nn.log_softmax(logits), skills[..., None], axis=-1)[..., 0]
    return log_q + math.log(num_skills)


def gaussian_diayn_reward(out: Array, skills: Array) -> Array:
    """Continuous skills: r = log N(z; mu(s'), diag sigma(s')^2) - log p(z), p uniform on [-1, 1]^d
    (log p(z) = -d log 2); `out` (B, 2d) the discriminator's mean and unbounded log std, the
    latter mapped into [LOG_STD_MIN, LOG_STD_MAX] as the policy's."""
    d = skills.shape[-1]
    mean, raw = jnp.split(out, 2, axis=-1)
    log_std = nets.LOG_STD_MIN + 0.5 * (nets.LOG_STD_MAX - nets.LOG_STD_MIN) * (jnp.tanh(raw) + 1.0)
    z = (skills - mean) / jnp.exp(log_std)
    log_q = -0.5 * jnp.sum(z**2 + 2.0 * log_std + math.log(2.0 * math.pi), axis=-1)
    return log_q + d * math.log(2.0)


def discriminator_loss(logits: Array, skills: Array) -> Array:
    """Cross-entropy -E[log q(z | s')]: maximum likelihood of the skills that were played."""
    return jnp.mean(optax.softmax_cross_entropy_with_integer_labels(logits, skills))


def model_inputs(transitions: Transition, model_input: SkillInput, num_skills: int) -> Array:
    """The next state as a skill model reads it: the descriptor, or the obs without skill code."""
    if model_input == "descriptor":
        return transitions.next_desc
    return strip_skill(transitions.next_obs, num_skills)


def make_diayn_module(config: DIAYNConfig, obs_size: int, descriptor_size: int) -> RewardModule:
    """DIAYN's discriminator and reward as a `RewardModule`.

    Args:
      config: DIAYN settings.
      obs_size: size of the environment's own observation (without the skill code).
      descriptor_size: size of its state descriptor.
    """
    config.check()
    k = config.num_skills
    continuous = config.continuous
    network = discriminator_network(2 * k if continuous else k, config.hidden, config.activation)
    in_size = descriptor_size if config.model_input == "descriptor" else obs_size
    adam = optax.adam(config.learning_rate)

    def init(key: PRNGKey) -> DiscriminatorState:
        params = network.init(key, jnp.zeros((1, in_size), jnp.float32))
        return DiscriminatorState(params, adam.init(params))

    def skills_of(obs: Array) -> Array:
        """The played skills: (B,) indices, or (B, d) continuous skills."""
        return obs[..., -k:] if continuous else skill_of(obs, k)

    def reward_of(logits: Array, skills: Array) -> tuple[Array, Info]:
        if continuous:
            r = gaussian_diayn_reward(logits, skills)
            return r, {"discriminator_log_likelihood": r - k * math.log(2.0)}
        correct = (jnp.argmax(logits, axis=-1) == skills).astype(jnp.float32)
        return diayn_reward(logits, skills), {"discriminator_accuracy": correct}

    def loss_of(logits: Array, skills: Array) -> Array:
        if continuous:  # maximum likelihood of the skills that were played
            return -jnp.mean(gaussian_diayn_reward(logits, skills) - k * math.log(2.0))
        return discriminator_loss(logits, skills)

    def reward(
        state: DiscriminatorState, transitions: Transition, key: PRNGKey
    ) -> tuple[Array, Info]:
        del key
        skills = skills_of(transitions.obs)
        return reward_of(network.apply(state.params, model_inputs(transitions, config.model_input, k)), skills)

    def reward_and_update(
        state: DiscriminatorState, transitions: Transition, reward_key: PRNGKey, update_key: PRNGKey
    ) -> tuple[Array, Info, DiscriminatorState, Metrics]:
        """`reward` and `update` with one forward pass: the logits of the loss are the reward's."""
        del reward_key, update_key
        skills = skills_of(transitions.obs)
        x = model_inputs(transitions, config.model_input, k)

        def loss_fn(params: Params) -> tuple[Array, Array]:
            logits = network.apply(params, x)
            return loss_of(logits, skills), logits

        (loss, logits), grads = jax.value_and_grad(loss_fn, has_aux=True)(state.params)
        updates, opt_state = adam.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        r_div, info = reward_of(jax.lax.stop_gradient(logits), skills)
        return r_div, info, DiscriminatorState(params, opt_state), {"discriminator_loss": loss}

    def update(
        state: DiscriminatorState, transitions: Transition, key: PRNGKey
    ) -> tuple[DiscriminatorState, Metrics]:
        _, _, state, metrics = reward_and_update(state, transitions, key, key)
        return state, metrics

    return RewardModule(init=init, reward=reward, update=update, reward_and_update=reward_and_update)


def make_diayn(
    agent: Agent,
    config: DIAYNConfig,
    obs_size: int,
    descriptor_size: int,
    gate: Gate | None = None,
) -> Agent:
    """DIAYN: `agent` (SAC on obs + one-hot skill) trained on the discriminator's reward.

    `gate` (SMERL, `qdrl.agents.smerl`) opens the diversity reward per transition.
    """
    module = make_diayn_module(config, obs_size, descriptor_size)
    return with_skill_model(agent, module, config, gate)
