"""METRA: Metric-Aware Abstraction (Park, Rybkin and Levine, ICLR 2024, arXiv:2310.08887).

A representation phi: S -> R^d is trained so that a skill z moves the agent in
direction z of the latent space, as far as the temporal distance allows: METRA
maximises E[(phi(s') - phi(s))^T z] subject to ||phi(s') - phi(s)||^2 <= 1 for
every transition, by dual gradient descent on lambda = exp(log lambda) with a
slack eps (the paper's Algorithm 1; the authors' `iod/metra.py`):

    representation loss  -E[(phi(s') - phi(s))^T z + sg(lambda) min(eps, 1 - ||phi(s') - phi(s)||^2)]
    dual loss            log lambda * E[sg(min(eps, 1 - ||phi(s') - phi(s)||^2))]

so lambda rises while the constraint is violated and falls while it holds with
slack. The policy (SAC, unchanged) is rewarded r = (phi(s') - phi(s))^T z.
Continuous skills are unit vectors (z ~ N(0, I) normalised, `sample_unit_skill`);
discrete ones are one-hot codes of K skills, centred and rescaled as the
authors' code does (`centred_skill`), so that each skill pushes phi towards its
own axis and away from the others. phi reads the state descriptor or the full
observation (without the skill code), and is trained with its own Adam on the
same batch in the same update step (`qdrl.agents.intrinsic`).

LSD (Park et al., ICLR 2022, "Lipschitz-constrained Unsupervised Skill
Discovery"), METRA's code with `--dual_reg 0 --spectral_normalization 1`, has
the same reward and no dual: phi's layers are spectrally normalised, so phi is
1-Lipschitz in the input's Euclidean distance, and phi maximises E[r] alone
(`lsd = True`; the loss above with lambda = 0).
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
from qdrl.agents.common import Activation, Hidden, check_size
from qdrl.agents.intrinsic import (
    Gate,
    Info,
    RewardModule,
    SkillInput,
    SkillModelConfig,
    check_field,
    with_skill_model,
)
from qdrl.config import NonNegativeFloat, PositiveFloat, PositiveInt
from qdrl.envs.skills import strip_skill
from qdrl.types import Array, Metrics, Params, PRNGKey, Transition


@dataclasses.dataclass(frozen=True)
class METRAConfig(SkillModelConfig):
    """METRA's (or LSD's) own settings (the `[skills]` section); SAC's are the `[agent]` section.

    Defaults from Park et al. 2024 (appendix) and their code (`tests/main.py`): state-based
    Ant's 2-D continuous skills, phi of two hidden layers of 1024 ReLU units reading the
    full state, Adam 1e-4 for phi and for log lambda, lambda initialised to 30, slack 1e-3;
    pure skill discovery (no task reward).
    """

    # d, the skill dimension (continuous skills), or K, the number of skills (`discrete`);
    # phi maps a state to R^num_skills.
    num_skills: PositiveInt = 2
    # What phi reads of a state: "full" (the observation without the skill code, as in the
    # paper) or "descriptor" (the env's state descriptor, e.g. x-y).
    model_input: SkillInput = "full"
    # Hidden layer widths of phi.
    hidden: Hidden = (1024, 1024)
    # Activation of phi's hidden layers; a key of `qdrl.nets.ACTIVATIONS`.
    activation: Activation = "relu"
    # Adam step size of phi.
    learning_rate: PositiveFloat = 1e-4
    # Discrete skills: a one-hot code of K skills (centred in the reward) instead of a unit
    # vector of R^d.
    discrete: bool = False
    # Initial value of the dual variable lambda (log lambda is what is trained).
    dual_init: PositiveFloat = 30.0
    # eps: the constraint's penalty is min(eps, 1 - ||phi(s') - phi(s)||^2).
    dual_slack: NonNegativeFloat = 1e-3
    # Adam step size of log lambda.
    dual_learning_rate: PositiveFloat = 1e-4
    # Measure the step ||phi(s') - phi(s)||^2 by its mean over the d dimensions, as the
    # authors' code does (`.mean(dim=1)`): the constraint becomes ||phi(s') - phi(s)||^2 <= d.
    # False: the paper's ||phi(s') - phi(s)||^2 <= 1.
    mean_over_dims: bool = False
    # LSD instead of METRA: spectrally normalised phi (1-Lipschitz), no dual variable.
    lsd: bool = False

    def check(self) -> None:
        """Raises ValueError naming the first `skills.<field>` out of range."""
        super().check()
        check_field(
            not self.discrete or self.num_skills >= 2,
            "skills",
            "num_skills",
            "at least 2 discrete skills (one centred skill is the zero vector)",
            self.num_skills,
        )


class METRAState(NamedTuple):
    """phi's parameters, its spectral-norm state (LSD; empty otherwise), the dual variable,
    and the Adam moments of both."""

    params: Params
    net_state: hk.State  # per layer, the power iteration's vector u0 and the estimated sigma
    opt_state: optax.OptState
    log_lambda: Array  # () float32
    dual_opt_state: optax.OptState


def representation_network(
    out_size: int,
    hidden: tuple[int, ...] = (1024, 1024),
    act: str = "relu",
    spectral_norm: bool = False,
) -> hk.TransformedWithState:
    """x -> phi(x), shape (..., out_size): an MLP, each layer's weight divided by its spectral
    norm when `spectral_norm` (LSD; Miyato et al. 2018).

    The spectral norm is estimated by one power-iteration step per forward pass from a vector
    kept in the haiku state, as torch's `spectral_norm` that METRA's code uses: phi is
    1-Lipschitz up to that estimate, which lags the weights by a few steps while they move.
    Biases are not normalised. Weights start Xavier-uniform, biases zero, as there.
    """
    w_init = hk.initializers.VarianceScaling(1.0, "fan_avg", "uniform")
    activation = nets.activation(act)

    def forward(x: Array) -> Array:
        # One matrix of rows: XLA's CPU backend differentiates a product of a (2, B, n) stack
        # through a slower kernel than the same rows as (2B, n) (its weight gradient sums over
        # two axes): 1.46 against 2.12 ms per step of phi at B = 256, 256x256.
        lead = x.shape[:-1]
        x = x.reshape((-1, x.shape[-1]))
        sizes = (*hidden, out_size)
        for i, size in enumerate(sizes):
            with hk.name_scope(f"linear_{i}"):
                w = hk.get_parameter("w", (x.shape[-1], size), x.dtype, init=w_init)
                b = hk.get_parameter("b", (size,), x.dtype, init=jnp.zeros)
                if spectral_norm:
                    w = hk.SpectralNorm(eps=1e-12, name="spectral_norm")(w)
            x = x @ w + b
            if i < len(hidden):
                x = activation(x)
        return x.reshape((*lead, out_size))

    return hk.without_apply_rng(hk.transform_with_state(forward))


def sample_unit_skill(key: PRNGKey, shape_prefix: tuple[int, ...], dim: int) -> Array:
    """Continuous skills of shape `shape_prefix + (dim,)`: z ~ N(0, I) normalised to unit length."""
    z = jax.random.normal(key, (*shape_prefix, dim))
    return z / jnp.maximum(jnp.linalg.norm(z, axis=-1, keepdims=True), 1e-12)


def centred_skill(one_hot: Array) -> Array:
    """A discrete skill's direction in phi-space: (z - mean(z)) K / (K - 1) for a one-hot z of K
    skills (METRA's code, `_update_rewards`): 1 on the skill's own axis, -1 / (K - 1) on the others."""
    k = one_hot.shape[-1]
    return (one_hot - jnp.mean(one_hot, axis=-1, keepdims=True)) * k / max(k - 1, 1)


def metra_reward(phi_s: Array, phi_next: Array, z: Array) -> Array:
    """r = (phi(s') - phi(s))^T z, shape (B,) for (B, d) inputs."""
    return jnp.sum((phi_next - phi_s) * z, axis=-1)


def squared_step(phi_s: Array, phi_next: Array, mean_over_dims: bool = False) -> Array:
    """||phi(s') - phi(s)||^2, or its mean over the d dimensions (`mean_over_dims`)."""
    sq = jnp.square(phi_next - phi_s)
    return jnp.mean(sq, axis=-1) if mean_over_dims else jnp.sum(sq, axis=-1)


def constraint_penalty(
    phi_s: Array, phi_next: Array, slack: float, mean_over_dims: bool = False
) -> Array:
    """min(eps, 1 - ||phi(s') - phi(s)||^2): negative where the constraint is violated."""
    return jnp.minimum(slack, 1.0 - squared_step(phi_s, phi_next, mean_over_dims))


def representation_loss(
    phi_s: Array,
    phi_next: Array,
    z: Array,
    dual_lambda: Array | float,
    slack: float,
    mean_over_dims: bool = False,
) -> Array:
    """-E[(phi(s') - phi(s))^T z + sg(lambda) min(eps, 1 - ||phi(s') - phi(s)||^2)] (METRA,
    Algorithm 1); with lambda = 0, LSD's -E[(phi(s') - phi(s))^T z].

    Args:
      phi_s, phi_next: (B, d) representations of the states and the next states.
      z: (B, d) skill directions (unit vectors, or centred one-hots).
      dual_lambda: lambda, not differentiated.
      slack: eps.
      mean_over_dims: measure the step by its mean square over the d dimensions.
    """
    penalty = constraint_penalty(phi_s, phi_next, slack, mean_over_dims)
    objective = metra_reward(phi_s, phi_next, z) + jax.lax.stop_gradient(dual_lambda) * penalty
    return -jnp.mean(objective)


def dual_loss(log_lambda: Array, penalty: Array) -> Array:
    """log lambda * E[sg(min(eps, 1 - ||phi(s') - phi(s)||^2))]: its gradient descent raises
    lambda while the mean penalty is negative (violated) and lowers it while it is positive."""
    return log_lambda * jnp.mean(jax.lax.stop_gradient(penalty))


def make_metra_module(config: METRAConfig, obs_size: int, descriptor_size: int) -> RewardModule:
    """METRA's (or LSD's) representation phi and reward as a `RewardModule`.

    Transitions' observations are `concat(env_obs, z)` with z their last `num_skills`
    entries: a one-hot (`discrete`, as `qdrl.envs.skills.SkillEnv` appends it) or a unit
    vector.

    Args:
      config: METRA settings.
      obs_size: size of the environment's own observation (without the skill code).
      descriptor_size: size of its state descriptor.
    """
    config.check()
    check_size("obs_size", obs_size)
    check_size("descriptor_size", descriptor_size)
    d = config.num_skills
    network = representation_network(d, config.hidden, config.activation, spectral_norm=config.lsd)
    in_size = descriptor_size if config.model_input == "descriptor" else obs_size
    adam = optax.adam(config.learning_rate)
    dual_adam = optax.adam(config.dual_learning_rate)
    slack, per_dim = config.dual_slack, config.mean_over_dims

    def skill_direction(obs: Array) -> Array:
        if obs.shape[-1] != obs_size + d:
            raise ValueError(
                f"transitions.obs: expected {obs_size + d} entries (the environment's {obs_size} "
                f"and the skill's {d}), got shape {obs.shape}"
            )
        z = obs[..., -d:]
        return centred_skill(z) if config.discrete else z

    def states(transitions: Transition) -> Array:
        """(2, B, in_size): s and s' as phi reads them, stacked for one forward pass."""
        if config.model_input == "descriptor":
            return jnp.stack([transitions.desc, transitions.next_desc])
        return jnp.stack([strip_skill(transitions.obs, d), strip_skill(transitions.next_obs, d)])

    def init(key: PRNGKey) -> METRAState:
        params, net_state = network.init(key, jnp.zeros((1, in_size), jnp.float32))
        log_lambda = jnp.asarray(math.log(config.dual_init), jnp.float32)
        return METRAState(
            params, net_state, adam.init(params), log_lambda, dual_adam.init(log_lambda)
        )

    def reward_of(phi: Array, z: Array) -> tuple[Array, Info]:
        return metra_reward(phi[0], phi[1], z), {"phi_step_sq": squared_step(phi[0], phi[1])}

    def reward(state: METRAState, transitions: Transition, key: PRNGKey) -> tuple[Array, Info]:
        del key
        z = skill_direction(transitions.obs)
        phi, _ = network.apply(state.params, state.net_state, states(transitions))
        return reward_of(phi, z)

    def reward_and_update(
        state: METRAState, transitions: Transition, reward_key: PRNGKey, update_key: PRNGKey
    ) -> tuple[Array, Info, METRAState, Metrics]:
        """`reward` and `update` with one forward pass of phi on s and s'; phi and log lambda
        both step from the values of this pass, as in METRA's code."""
        del reward_key, update_key
        z = skill_direction(transitions.obs)
        x = states(transitions)
        dual_lambda = jnp.exp(state.log_lambda)
        weight = 0.0 if config.lsd else dual_lambda

        def loss_fn(params: Params) -> tuple[Array, tuple[Array, hk.State]]:
            phi, net_state = network.apply(params, state.net_state, x)
            return representation_loss(phi[0], phi[1], z, weight, slack, per_dim), (phi, net_state)

        (loss, (phi, net_state)), grads = jax.value_and_grad(loss_fn, has_aux=True)(state.params)
        updates, opt_state = adam.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        phi = jax.lax.stop_gradient(phi)
        r_div, info = reward_of(phi, z)
        metrics = {
            "representation_loss": loss,
            "phi_delta_dot_z": jnp.mean(r_div),
            "phi_step_sq_max": jnp.max(info["phi_step_sq"]),
        }
        log_lambda, dual_opt_state = state.log_lambda, state.dual_opt_state
        if not config.lsd:
            penalty = constraint_penalty(phi[0], phi[1], slack, per_dim)
            loss_dual, grad = jax.value_and_grad(dual_loss)(log_lambda, penalty)
            dual_updates, dual_opt_state = dual_adam.update(grad, dual_opt_state, log_lambda)
            log_lambda = optax.apply_updates(log_lambda, dual_updates)
            metrics.update({"dual_loss": loss_dual, "dual_lambda": dual_lambda})
        new_state = METRAState(params, net_state, opt_state, log_lambda, dual_opt_state)
        return r_div, info, new_state, metrics

    def update(
        state: METRAState, transitions: Transition, key: PRNGKey
    ) -> tuple[METRAState, Metrics]:
        _, _, state, metrics = reward_and_update(state, transitions, key, key)
        return state, metrics

    return RewardModule(
        init=init, reward=reward, update=update, reward_and_update=reward_and_update
    )


def make_metra(
    agent: Agent,
    config: METRAConfig,
    obs_size: int,
    descriptor_size: int,
    gate: Gate | None = None,
) -> Agent:
    """METRA (or LSD): `agent` (SAC on obs + skill) trained on (phi(s') - phi(s))^T z.

    `gate` (SMERL, `qdrl.agents.smerl`) opens the diversity reward per transition.
    """
    module = make_metra_module(config, obs_size, descriptor_size)
    return with_skill_model(agent, module, config, gate)
