"""Array and pytree type aliases shared across qdrl. Imports no brax or jumanji."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple, TypeAlias

import jax

Array: TypeAlias = jax.Array
PRNGKey: TypeAlias = jax.Array
Params: TypeAlias = Any  # a haiku parameter tree (nested mapping of arrays)
PyTree: TypeAlias = Any
Metrics: TypeAlias = Mapping[str, Array]
Genotype: TypeAlias = Any  # any pytree whose leaves carry a leading batch axis
Fitness: TypeAlias = jax.Array
Descriptor: TypeAlias = jax.Array


class Transition(NamedTuple):
    """One environment step, as stored in replay buffers.

    `terminated` is 1.0 when the episode ended in a terminal state (no bootstrap);
    `truncated` is 1.0 when it was cut by the time limit (bootstrap through it).
    `desc` / `next_desc` are the state descriptors before and after the step
    (e.g. torso x-y), used by skill discovery and QD-RL emitters.
    """

    obs: Array
    action: Array
    reward: Array
    next_obs: Array
    terminated: Array
    truncated: Array
    desc: Array
    next_desc: Array

    @property
    def discount_mask(self) -> Array:
        """1.0 where the target bootstraps from `next_obs`, 0.0 at true terminations."""
        return 1.0 - self.terminated
