"""A pure-JAX point mass in a 2-D box: fast to compile, for tests, demos and point-maze.

The agent sets its velocity (action in [-1, 1]^2, scaled by `max_speed`) and moves
inside [-1, 1]^2 (positions are clipped at the walls). The reward is the negative
distance to `goal`, so a policy that heads for the goal and stays there scores
near 0 and a still one scores about -distance × episode_length. The state
descriptor is the x-y position. Episodes never terminate, only truncate.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from qdrl.envs.base import Env
from qdrl.types import Array, PRNGKey


class PointEnv(Env):
    """Point mass moving towards a goal; observation = (position, goal)."""

    def __init__(
        self,
        episode_length: int = 100,
        goal: tuple[float, float] = (0.5, 0.5),
        max_speed: float = 0.1,
        start_noise: float = 0.1,
    ) -> None:
        if episode_length <= 0:
            raise ValueError(f"episode_length must be a positive integer, got {episode_length}")
        self.name = "point"
        self.episode_length = episode_length
        self.action_size = 2
        self.goal = jnp.asarray(goal, jnp.float32)
        self.max_speed = max_speed
        self.start_noise = start_noise

    def _obs(self, pos: Array) -> Array:
        return jnp.concatenate([pos, self.goal])

    def _reset(self, key: PRNGKey) -> tuple[Any, Array, Array]:
        pos = self.start_noise * jax.random.uniform(key, (2,), minval=-1.0, maxval=1.0)
        return pos, self._obs(pos), pos

    def _step(self, inner: Any, action: Array) -> tuple[Any, Array, Array, Array, Array]:
        pos = jnp.clip(inner + self.max_speed * action, -1.0, 1.0)
        reward = -jnp.linalg.norm(pos - self.goal)
        return pos, self._obs(pos), reward, jnp.zeros(()), pos
