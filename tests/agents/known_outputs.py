"""Networks set to known outputs, for losses checked by hand (imported by the agents' tests)."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp


def zeroed(params: Any, bias: float = 0.0) -> Any:
    """Every weight and bias 0 (a network that outputs 0), each MLP's last layer's bias `bias`:
    haiku parameters named "<mlp>/~/linear_<i>", the highest i of each mlp being its output."""
    out = jax.tree.map(jnp.zeros_like, params)
    last: dict[str, str] = {}
    for name in sorted(out):
        last[name.split("/~/")[0]] = name
    for name in last.values():
        out[name] = {**out[name], "b": out[name]["b"] + bias}
    return out
