"""DADS: Dynamics-Aware Discovery of Skills (Sharma et al. 2020, arXiv:1907.01657).

A skill-dynamics model q_phi(delta | s, z) predicts the change of the state
descriptor delta = d(s') - d(s) under skill z; the policy (SAC, unchanged) is
rewarded for transitions that its own skill predicts well and other skills do not
(eq. 6 of the paper, with L alternative skills z_i drawn from the prior p(z)):

    r = log q(delta | s, z) - log( (1/L) sum_{i=1..L} q(delta | s, z_i) ).

With discrete uniform skills `num_alt_skills = 0` uses all K skills instead of
samples (the exact marginal of the uniform prior). The model is a mixture of
Gaussians over the normalised delta (targets standardised with running moments),
diagonal, with fixed unit variance by default (the paper's `fix_variance`); its
inputs may leave out some dimensions of s (`omit_input_dims`: the paper's "x-y
prior" removes the x-y coordinates from the model's input). It is trained by
maximum likelihood with its own Adam inside the agent's update, on one update in
`model_update_every` (8: the authors' code trains it 8 steps per 64 SAC steps).

The reward needs the model at every state of the batch for every skill compared;
`skill_dynamics_outputs` evaluates them in one batched pass whose first layer is
shared by all skills of a state (see there).
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import haiku as hk
import jax
import jax.numpy as jnp
import numpy as np
import optax

from qdrl import nets
from qdrl.agents.base import Agent
from qdrl.agents.common import Hidden
from qdrl.agents.intrinsic import (
    Gate,
    Info,
    RewardModule,
    SkillModelConfig,
    check_field,
    with_skill_model,
)
from qdrl.config import NonNegativeInt, PositiveInt
from qdrl.envs.skills import skill_of, strip_skill
from qdrl.types import Array, Metrics, Params, PRNGKey, Transition

# Bounds of the learned log standard deviation (when `learn_variance`).
LOG_STD_MIN, LOG_STD_MAX = -5.0, 2.0


@dataclasses.dataclass(frozen=True)
class DADSConfig(SkillModelConfig):
    """DADS's own settings (the `[skills]` section); SAC's are the `[agent]` section.

    Defaults from Sharma et al. 2020 (appendix): a skill-dynamics network of two
    hidden layers of 512 units, a mixture of 4 experts with fixed variance,
    Adam 3e-4, normalised targets; pure skill discovery (no task reward). The model
    takes one step per 8 agent updates, as in the authors' code (8 skill-dynamics
    steps per 64 SAC steps for Ant, 16 per 128 for Humanoid).
    """

    num_skills: PositiveInt = 10
    hidden: Hidden = (512, 512)
    model_update_every: PositiveInt = 8
    # Mixture components ("experts") of the Gaussian mixture over delta.
    num_components: PositiveInt = 4
    # L, alternative skills drawn from the prior per transition; 0: all K skills.
    num_alt_skills: NonNegativeInt = 0
    # Input dimensions of s the model does not see (e.g. [0, 1]: the x-y prior).
    omit_input_dims: tuple[NonNegativeInt, ...] = ()
    # Standardise delta with running moments before the likelihood.
    normalize_targets: bool = True
    # Learn a per-component diagonal variance instead of fixing it to 1.
    learn_variance: bool = False

    def check(self) -> None:
        """Raises ValueError naming the first `skills.<field>` out of range."""
        super().check()
        dims = self.omit_input_dims
        check_field(len(set(dims)) == len(dims), "skills", "omit_input_dims",
                    "a list of distinct integers >= 0", dims)


class RunningMoments(NamedTuple):
    """Running mean and variance of the targets (Chan et al.'s parallel update)."""

    mean: Array  # (D,)
    var: Array  # (D,)
    num_samples: Array  # () float32, samples seen


class SkillDynamicsState(NamedTuple):
    """Parameters of q_phi(delta | s, z), their Adam moments and the target statistics."""

    params: Params
    opt_state: optax.OptState
    moments: RunningMoments


def update_moments(moments: RunningMoments, x: Array) -> RunningMoments:
    """The moments after also seeing the batch `x` (N, D)."""
    n = jnp.asarray(x.shape[0], jnp.float32)
    batch_mean = jnp.mean(x, axis=0)
    batch_var = jnp.var(x, axis=0)
    total = moments.num_samples + n
    delta = batch_mean - moments.mean
    mean = moments.mean + delta * n / total
    m2 = moments.var * moments.num_samples + batch_var * n + delta**2 * moments.num_samples * n / total
    return RunningMoments(mean, m2 / total, total)


def normalize(moments: RunningMoments, x: Array, eps: float = 1e-6) -> Array:
    """(x - mean) / std; the identity before any sample has been seen."""
    seen = moments.num_samples > 0
    mean = jnp.where(seen, moments.mean, 0.0)
    std = jnp.where(seen, jnp.sqrt(moments.var + eps), 1.0)
    return (x - mean) / std


def mixture_log_prob(logits: Array, means: Array, log_std: Array, x: Array) -> Array:
    """log sum_m pi_m N(x; mu_m, diag(sigma_m^2)), pi = softmax(logits).

    Args:
      logits: (..., M) mixture weights before the softmax.
      means: (..., M, D).
      log_std: (..., M, D) (broadcastable; zeros for unit variance).
      x: (..., D) the point.
    """
    z = (x[..., None, :] - means) * jnp.exp(-log_std)
    log_n = -0.5 * jnp.sum(z**2 + 2.0 * log_std + math.log(2.0 * math.pi), axis=-1)
    return jax.nn.logsumexp(jax.nn.log_softmax(logits, axis=-1) + log_n, axis=-1)


def dads_reward(log_q: Array, log_q_alt: Array) -> Array:
    """r = log q(delta|s,z) - log((1/L) sum_i q(delta|s,z_i)) (Sharma et al. 2020, eq. 6).

    Args:
      log_q: (B,) log-likelihood under the skill played.
      log_q_alt: (B, L) log-likelihoods under the L alternative skills.
    """
    num_alt = log_q_alt.shape[-1]
    return log_q - jax.nn.logsumexp(log_q_alt, axis=-1) + math.log(num_alt)


def _bounded_log_std(raw: Array) -> Array:
    """Squashes a raw output into [LOG_STD_MIN, LOG_STD_MAX] (the learned log standard deviation)."""
    return LOG_STD_MIN + 0.5 * (LOG_STD_MAX - LOG_STD_MIN) * (jnp.tanh(raw) + 1.0)


def skill_dynamics_network(
    descriptor_size: int,
    num_components: int,
    hidden: tuple[int, ...],
    act: str,
    learn_variance: bool,
) -> hk.Transformed:
    """(s, one_hot z) -> (logits (..., M), means (..., M, D), log_std (..., M, D)).

    The definition of the model (and its parameters); `skill_dynamics_outputs` evaluates
    the same function for many skills per state at a lower cost.
    """
    d, m = descriptor_size, num_components

    def forward(s: Array, z: Array) -> tuple[Array, Array, Array]:
        h = hk.nets.MLP(hidden, activation=nets.activation(act), activate_final=True)(
            jnp.concatenate([s, z], axis=-1)
        )
        logits = hk.Linear(m, name="logits")(h)
        means = hk.Linear(m * d, name="means")(h).reshape((*h.shape[:-1], m, d))
        if learn_variance:
            raw = hk.Linear(m * d, name="log_std")(h).reshape((*h.shape[:-1], m, d))
            log_std = _bounded_log_std(raw)
        else:
            log_std = jnp.zeros_like(means)
        return logits, means, log_std

    return hk.without_apply_rng(hk.transform(forward))


def skill_dynamics_outputs(
    params: Params, s: Array, skills: Array | None, act: str = "relu"
) -> tuple[Array, Array, Array]:
    """`skill_dynamics_network`'s outputs at the states `s` for L skills each, in one batched pass.

    The first layer maps [s; one_hot(z)] to W_s s + W_z[z] + b: a one-hot code times a
    matrix is one of its rows. The state part is computed once per state and each skill
    adds its row, so L skills cost one matmul of the states plus L row additions instead
    of L concatenations and matmuls; the other layers run on the (B, L) batch at once.

    Args:
      params: parameters of `skill_dynamics_network` (its sizes are read from them).
      s: (B, S) model inputs.
      skills: (B, L) int skills to evaluate at each state, or None for all K skills in
        order (L = K).
      act: the network's hidden activation (a key of `qdrl.nets.ACTIVATIONS`).

    Returns:
      logits (B, L, M), means (B, L, M, D) and log_std (B, L, M, D) of the mixtures.
    """
    activation = nets.activation(act)
    first = params["mlp/~/linear_0"]
    state_size = s.shape[-1]
    w_state, w_skill = first["w"][:state_size], first["w"][state_size:]
    rows = w_skill if skills is None else w_skill[skills]  # (K, H) or (B, L, H)
    h = activation((s @ w_state + first["b"])[..., None, :] + rows)
    layer = 1
    while f"mlp/~/linear_{layer}" in params:
        dense = params[f"mlp/~/linear_{layer}"]
        h = activation(h @ dense["w"] + dense["b"])
        layer += 1
    # The heads as one matmul: a few output columns each are cheaper read together.
    heads = ("logits", "means", "log_std") if "log_std" in params else ("logits", "means")
    w = jnp.concatenate([params[name]["w"] for name in heads], axis=-1)
    b = jnp.concatenate([params[name]["b"] for name in heads], axis=-1)
    out = h @ w + b
    m = params["logits"]["w"].shape[-1]
    md = params["means"]["w"].shape[-1]
    logits = out[..., :m]
    means = out[..., m : m + md].reshape((*h.shape[:-1], m, md // m))
    if "log_std" in params:
        log_std = _bounded_log_std(out[..., m + md :].reshape(means.shape))
    else:
        log_std = jnp.zeros_like(means)
    return logits, means, log_std


def make_dads_module(config: DADSConfig, obs_size: int, descriptor_size: int) -> RewardModule:
    """DADS's skill-dynamics model and reward as a `RewardModule`.

    Args:
      config: DADS settings.
      obs_size: size of the environment's own observation (without the skill code).
      descriptor_size: size of its state descriptor (the model predicts its change).
    """
    config.check()
    k = config.num_skills
    full_size = descriptor_size if config.model_input == "descriptor" else obs_size
    if any(d >= full_size for d in config.omit_input_dims):
        raise ValueError(
            f"skills.omit_input_dims: expected dimensions below {full_size} (the size of the "
            f"model input {config.model_input!r}), got {list(config.omit_input_dims)}"
        )
    keep = np.array([i for i in range(full_size) if i not in config.omit_input_dims], np.int32)
    if keep.size == 0:
        raise ValueError("skills.omit_input_dims: leaves the model no input dimension")
    network = skill_dynamics_network(
        descriptor_size, config.num_components, config.hidden, config.activation,
        config.learn_variance,
    )
    adam = optax.adam(config.learning_rate)

    def state_input(transitions: Transition) -> Array:
        s = (
            transitions.desc
            if config.model_input == "descriptor"
            else strip_skill(transitions.obs, k)
        )
        return s[..., keep]

    def target(moments: RunningMoments, transitions: Transition) -> Array:
        delta = transitions.next_desc - transitions.desc
        return normalize(moments, delta) if config.normalize_targets else delta

    def log_prob(params: Params, s: Array, skills: Array | None, x: Array) -> Array:
        """log q(x | s, z) for the (B, L) skills z of each of the B states (None: all K): (B, L)."""
        logits, means, log_std = skill_dynamics_outputs(params, s, skills, config.activation)
        return mixture_log_prob(logits, means, log_std, x[..., None, :])

    def init(key: PRNGKey) -> SkillDynamicsState:
        params = network.init(key, jnp.zeros((1, keep.size)), jnp.zeros((1, k)))
        zeros = jnp.zeros((descriptor_size,), jnp.float32)
        moments = RunningMoments(zeros, jnp.ones_like(zeros), jnp.zeros((), jnp.float32))
        return SkillDynamicsState(params, adam.init(params), moments)

    def reward(
        state: SkillDynamicsState, transitions: Transition, key: PRNGKey
    ) -> tuple[Array, Info]:
        skills = skill_of(transitions.obs, k)
        s, x = state_input(transitions), target(state.moments, transitions)
        batch = skills.shape[0]
        if config.num_alt_skills == 0:
            # Every skill once: the played one is among them, its likelihood is read off.
            log_q_alt = log_prob(state.params, s, None, x)
            log_q = jnp.take_along_axis(log_q_alt, skills[:, None], axis=1)[:, 0]
        else:
            alt = jax.random.randint(key, (batch, config.num_alt_skills), 0, k, jnp.int32)
            # The played skill and the L alternatives in one batched pass of the model.
            log_q_all = log_prob(state.params, s, jnp.concatenate([skills[:, None], alt], 1), x)
            log_q, log_q_alt = log_q_all[:, 0], log_q_all[:, 1:]
        return dads_reward(log_q, log_q_alt), {"dynamics_log_likelihood": log_q}

    def update(
        state: SkillDynamicsState, transitions: Transition, key: PRNGKey
    ) -> tuple[SkillDynamicsState, Metrics]:
        del key
        delta = transitions.next_desc - transitions.desc
        moments = update_moments(state.moments, delta)
        skills = skill_of(transitions.obs, k)
        s, x = state_input(transitions), target(moments, transitions)

        def loss_fn(params: Params) -> Array:
            # The definition itself: one skill per state gains nothing from the factored pass,
            # and the gradient of a one-hot matmul is cheaper than that of a row gather.
            logits, means, log_std = network.apply(params, s, jax.nn.one_hot(skills, k))
            return -jnp.mean(mixture_log_prob(logits, means, log_std, x))

        loss, grads = jax.value_and_grad(loss_fn)(state.params)
        updates, opt_state = adam.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        return SkillDynamicsState(params, opt_state, moments), {"dynamics_loss": loss}

    return RewardModule(init=init, reward=reward, update=update)


def make_dads(
    agent: Agent,
    config: DADSConfig,
    obs_size: int,
    descriptor_size: int,
    gate: Gate | None = None,
) -> Agent:
    """DADS: `agent` (SAC on obs + one-hot skill) trained on the skill-dynamics reward.

    `gate` (SMERL, `qdrl.agents.smerl`) opens the diversity reward per transition.
    """
    module = make_dads_module(config, obs_size, descriptor_size)
    return with_skill_model(agent, module, config, gate)
