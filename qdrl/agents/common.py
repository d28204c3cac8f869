"""Pieces every agent shares: an Adam step with the learning rate as an array, checks, field types."""

from __future__ import annotations

from typing import Annotated, Any

import jax.numpy as jnp
import optax

from qdrl import nets
from qdrl.config import OneOf, PositiveInt
from qdrl.types import Array


def adam_step(
    params: Any, opt_state: optax.OptState, grads: Any, lr: Array | float
) -> tuple[Any, optax.OptState]:
    """One Adam step whose learning rate is an array, so it may differ per population member.

    `opt_state` is `optax.scale_by_adam().init(params)` or the result of an earlier step.
    """
    updates, opt_state = optax.scale_by_adam().update(grads, opt_state)
    return optax.apply_updates(params, optax.tree.scale(-lr, updates)), opt_state


def critics_l2_loss(q: Array, target_q: Array) -> Array:
    """The critics' regression loss: `rlax.l2_loss` (0.5 (q - target)^2) of each of the
    critics' (batch, critics) values against the (batch,) target, summed over the critics
    and averaged over the batch."""
    import rlax  # ~0.5 s with distrax and tfp: paid by the first critic loss, not on import

    return jnp.mean(jnp.sum(rlax.l2_loss(q, target_q[..., None]), axis=-1))


def check_size(name: str, value: object) -> None:
    """Raise ValueError unless `value` is a positive int (an observation or action size)."""
    if not (isinstance(value, int) and not isinstance(value, bool) and value > 0):
        raise ValueError(f"{name}: expected a positive int, got {value!r}")


def activation_names() -> list[str]:
    """The activations a network config may name (`qdrl.nets.ACTIVATIONS`)."""

    return sorted(nets.ACTIVATIONS)


# Config field types shared by the agents and skill models: hidden layer widths, an activation.
Hidden = tuple[PositiveInt, ...]
Activation = Annotated[str, OneOf(activation_names)]
