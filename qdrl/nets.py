"""Haiku networks: deterministic tanh policy, tanh-Gaussian policy, twin Q critic.

Each builder returns an `hk.Transformed` without apply-rng, so `init(key, *inputs)`
and `apply(params, *inputs)` are the whole interface.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import haiku as hk
import jax
import jax.numpy as jnp

from qdrl.types import Array

ACTIVATIONS: dict[str, Callable[[Array], Array]] = {
    "relu": jax.nn.relu,
    "tanh": jnp.tanh,
    "elu": jax.nn.elu,
    "swish": jax.nn.swish,
    "gelu": jax.nn.gelu,
}

# Bounds of log(std) for the tanh-Gaussian policy, as in SAC implementations.
LOG_STD_MIN = -5.0
LOG_STD_MAX = 2.0


def activation(name: str) -> Callable[[Array], Array]:
    """The activation function called `name`; raises ValueError on an unknown name."""
    if name not in ACTIVATIONS:
        raise ValueError(f"unknown activation {name!r}; expected one of {sorted(ACTIVATIONS)}")
    return ACTIVATIONS[name]


def _mlp(
    hidden: Sequence[int], out: int, act: str, name: str, fan: str = "fan_avg"
) -> hk.nets.MLP:
    return hk.nets.MLP(
        [*hidden, out],
        activation=activation(act),
        w_init=hk.initializers.VarianceScaling(1.0, fan, "uniform"),
        name=name,
    )


def deterministic_policy(
    action_size: int,
    hidden: Sequence[int] = (256, 256),
    act: str = "relu",
    init: str = "glorot_uniform",
) -> hk.Transformed:
    """obs -> action in [-1, 1]^action_size through a final tanh (TD3, QD-RL genotypes).

    `init`: "glorot_uniform" (variance 2 / (fan_in + fan_out)) or "lecun_uniform"
    (variance 1 / fan_in, what QDax's QD-RL policies use).
    """
    if init not in ("glorot_uniform", "lecun_uniform"):
        raise ValueError(f"init: expected 'glorot_uniform' or 'lecun_uniform', got {init!r}")
    fan = "fan_avg" if init == "glorot_uniform" else "fan_in"

    def forward(obs: Array) -> Array:
        return jnp.tanh(_mlp(hidden, action_size, act, "policy", fan)(obs))

    return hk.without_apply_rng(hk.transform(forward))


def gaussian_policy(
    action_size: int, hidden: Sequence[int] = (256, 256), act: str = "relu"
) -> hk.Transformed:
    """obs -> (mean, log_std) of a Gaussian whose samples are squashed by tanh (SAC).

    log_std is mapped smoothly into [LOG_STD_MIN, LOG_STD_MAX].
    """

    def forward(obs: Array) -> tuple[Array, Array]:
        out = _mlp(hidden, 2 * action_size, act, "policy")(obs)
        mean, raw_log_std = jnp.split(out, 2, axis=-1)
        log_std = LOG_STD_MIN + 0.5 * (LOG_STD_MAX - LOG_STD_MIN) * (jnp.tanh(raw_log_std) + 1.0)
        return mean, log_std

    return hk.without_apply_rng(hk.transform(forward))


def sample_tanh_gaussian(
    mean: Array, log_std: Array, key: Array
) -> tuple[Array, Array]:
    """A reparameterised sample tanh(mean + std * eps) and its log-probability.

    The log-probability includes the tanh change of variables, computed in the
    numerically stable form log(1 - tanh(u)^2) = 2 (log 2 - u - softplus(-2u)).
    """
    std = jnp.exp(log_std)
    eps = jax.random.normal(key, mean.shape, mean.dtype)
    pre_tanh = mean + std * eps
    gaussian_log_prob = -0.5 * (eps**2 + 2.0 * log_std + jnp.log(2.0 * jnp.pi))
    log_det = 2.0 * (jnp.log(2.0) - pre_tanh - jax.nn.softplus(-2.0 * pre_tanh))
    log_prob = jnp.sum(gaussian_log_prob - log_det, axis=-1)
    return jnp.tanh(pre_tanh), log_prob


def twin_q_critic(
    hidden: Sequence[int] = (256, 256), act: str = "relu", num_critics: int = 2
) -> hk.Transformed:
    """(obs, action) -> Q-values of shape (..., num_critics), one head per critic.

    The critics are independent MLPs; stacking them lets losses take a min or a
    mean over the last axis.
    """

    def forward(obs: Array, action: Array) -> Array:
        x = jnp.concatenate([obs, action], axis=-1)
        qs = [_mlp(hidden, 1, act, f"q{i}")(x) for i in range(num_critics)]
        return jnp.concatenate(qs, axis=-1)

    return hk.without_apply_rng(hk.transform(forward))


def twin_vector_critic(
    size: int, hidden: Sequence[int] = (256, 256), act: str = "relu", num_critics: int = 2
) -> hk.Transformed:
    """(obs, action) -> vectors of shape (..., num_critics, size), one MLP per critic: the
    successor features psi(s, a) of QDAC (Grillotti et al. 2024), twinned like Q critics."""

    def forward(obs: Array, action: Array) -> Array:
        x = jnp.concatenate([obs, action], axis=-1)
        return jnp.stack([_mlp(hidden, size, act, f"psi{i}")(x) for i in range(num_critics)], axis=-2)

    return hk.without_apply_rng(hk.transform(forward))


def scalar_head(hidden: Sequence[int] = (256, 256), act: str = "relu", name: str = "head") -> hk.Transformed:
    """obs -> a scalar per input (...,): e.g. the logit of QDAC's Lagrange multiplier lambda(s, z)."""

    def forward(obs: Array) -> Array:
        return _mlp(hidden, 1, act, name)(obs)[..., 0]

    return hk.without_apply_rng(hk.transform(forward))
