"""Brax adapter: any registered brax environment, on a backend chosen by name.

The raw brax environment (`brax.envs.get_environment`) has no time limit and no
automatic reset; qdrl's `Env` base adds both, keeping termination apart from
truncation. The state descriptor is a function of the brax state; by default the
torso's x-y position, which final-position tasks and skill discovery use.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

from qdrl.envs.base import Env
from qdrl.types import Array, PRNGKey

BACKENDS = ("spring", "positional", "generalized", "mjx")

DescriptorFn = Callable[[Any], Array]


def torso_xy(pipeline_state: Any) -> Array:
    """x-y position of the first body (the torso in every brax locomotion robot)."""
    return pipeline_state.x.pos[0, :2]


STATE_DESCRIPTORS: dict[str, DescriptorFn] = {"xy": torso_xy}


def brax_env_names() -> list[str]:
    """Names in brax's environment registry."""
    from brax import envs

    return sorted(envs._envs)


def _strong(tree: Any) -> Any:
    """Cast floating leaves to strong float32 so reset and step states have one type.

    brax's reset returns strong float32 for `done` and some metrics while step returns
    weak types; without this, `jit(step)` compiles twice and `lax.cond` over the
    two states fails.
    """

    def cast(x: Any) -> Any:
        if isinstance(x, jax.Array | float) and jnp.issubdtype(jnp.result_type(x), jnp.floating):
            return jnp.asarray(x, jnp.float32)
        return x

    return jax.tree.map(cast, tree)


class BraxEnv(Env):
    """A brax environment behind qdrl's single-instance protocol."""

    def __init__(
        self,
        name: str,
        backend: str = "spring",
        episode_length: int = 1000,
        state_descriptor: str | DescriptorFn = "xy",
        **env_kwargs: Any,
    ) -> None:
        if backend not in BACKENDS:
            raise ValueError(f"unknown brax backend {backend!r}; expected one of {BACKENDS}")
        names = brax_env_names()
        if name not in names:
            raise ValueError(f"unknown brax environment {name!r}; expected one of {names}")
        if episode_length <= 0:
            raise ValueError(f"episode_length must be a positive integer, got {episode_length}")
        if isinstance(state_descriptor, str):
            if state_descriptor not in STATE_DESCRIPTORS:
                raise ValueError(
                    f"unknown state descriptor {state_descriptor!r}; "
                    f"expected one of {sorted(STATE_DESCRIPTORS)}"
                )
            state_descriptor = STATE_DESCRIPTORS[state_descriptor]
        from brax import envs

        self.name = name
        self.backend = backend
        self.episode_length = episode_length
        self.brax_env = envs.get_environment(name, backend=backend, **env_kwargs)
        self.action_size = int(self.brax_env.action_size)
        self._descriptor = state_descriptor

    def _reset(self, key: PRNGKey) -> tuple[Any, Array, Array]:
        state = _strong(self.brax_env.reset(key))
        return state, state.obs, self._descriptor(state.pipeline_state)

    def _step(self, inner: Any, action: Array) -> tuple[Any, Array, Array, Array, Array]:
        state = _strong(self.brax_env.step(inner, action))
        desc = self._descriptor(state.pipeline_state)
        return state, state.obs, state.reward, state.done, desc
