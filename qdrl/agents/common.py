"""Pieces every agent shares: an Adam step with the learning rate as an array, and checks."""

from __future__ import annotations

import math
from typing import Any

import optax

from qdrl.types import Array


def adam_step(
    params: Any, opt_state: optax.OptState, grads: Any, lr: Array | float
) -> tuple[Any, optax.OptState]:
    """One Adam step whose learning rate is an array, so it may differ per population member.

    `opt_state` is `optax.scale_by_adam().init(params)` or the result of an earlier step.
    """
    updates, opt_state = optax.scale_by_adam().update(grads, opt_state)
    return optax.apply_updates(params, optax.tree.scale(-lr, updates)), opt_state


def require(ok: bool, field: str, expected: str, value: object) -> None:
    """Raise `ValueError("agent.<field>: expected <expected>, got <value>")` unless `ok`."""
    if not ok:
        raise ValueError(f"agent.{field}: expected {expected}, got {value!r}")


def is_real(value: object) -> bool:
    """True for a finite int or float (bools excluded)."""
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def check_size(name: str, value: object) -> None:
    """Raise ValueError unless `value` is a positive int (an observation or action size)."""
    if not (isinstance(value, int) and not isinstance(value, bool) and value > 0):
        raise ValueError(f"{name}: expected a positive int, got {value!r}")


def check_network(hidden: object, activation: object) -> None:
    """Raise `ValueError("agent.hidden: ...")` / `("agent.activation: ...")` on a bad network shape."""
    from qdrl import nets

    require(
        isinstance(hidden, tuple)
        and all(isinstance(w, int) and not isinstance(w, bool) and w > 0 for w in hidden),
        "hidden",
        "a tuple of positive ints",
        hidden,
    )
    require(
        activation in nets.ACTIVATIONS,
        "activation",
        f"one of {sorted(nets.ACTIVATIONS)}",
        activation,
    )
