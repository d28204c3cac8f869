"""The one small task protocol every environment in qdrl meets, and its batched helpers.

An environment is single-instance and functional: `reset(key) -> EnvState` and
`step(state, action) -> EnvState`, both pure and jittable. Batching is `jax.vmap`
on the caller's side (`reset_batch`, `step_batch`), so the same environment serves
a batch of training envs, a batch of QD policies, or a population of agents.

Episode bookkeeping lives here, written once for every backend: the step counter,
truncation at `episode_length` (kept apart from termination so that learners
bootstrap through time limits), the running episode return and the return and
length of the last finished episode. Backends only provide `_reset` and `_step`.
"""

from __future__ import annotations

import abc
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from qdrl.types import Array, PRNGKey


class EnvState(NamedTuple):
    """State of one environment instance (leaves gain a leading axis when batched)."""

    obs: Array  # (obs_size,) float32
    reward: Array  # () reward of the last step
    terminated: Array  # () 1.0 if the last step reached a terminal state
    truncated: Array  # () 1.0 if the last step hit the time limit (and did not terminate)
    desc: Array  # (descriptor_size,) state descriptor, e.g. torso x-y
    step: Array  # () int32 steps taken in the current episode
    episode_return: Array  # () return accumulated in the current episode
    last_return: Array  # () return of the last finished episode (nan before any)
    last_length: Array  # () length of the last finished episode (0 before any)
    key: PRNGKey  # used for the next automatic reset
    inner: Any  # the backend's own state (brax State, jumanji State, ...)

    @property
    def done(self) -> Array:
        """1.0 where the episode ended, by termination or by truncation."""
        return jnp.maximum(self.terminated, self.truncated)


class Env(abc.ABC):
    """Base of all qdrl environments: bookkeeping on top of a backend's reset/step."""

    name: str
    action_size: int
    episode_length: int

    @abc.abstractmethod
    def _reset(self, key: PRNGKey) -> tuple[Any, Array, Array]:
        """Backend reset: (inner_state, obs, desc)."""

    @abc.abstractmethod
    def _step(self, inner: Any, action: Array) -> tuple[Any, Array, Array, Array, Array]:
        """Backend step: (inner_state, obs, reward, terminated, desc)."""

    def reset(self, key: PRNGKey) -> EnvState:
        """A fresh episode. `key` seeds both this reset and the later automatic ones."""
        reset_key, carry_key = jax.random.split(key)
        inner, obs, desc = self._reset(reset_key)
        zero = jnp.zeros((), jnp.float32)
        return EnvState(
            obs=jnp.asarray(obs, jnp.float32),
            reward=zero,
            terminated=zero,
            truncated=zero,
            desc=jnp.asarray(desc, jnp.float32),
            step=jnp.zeros((), jnp.int32),
            episode_return=zero,
            last_return=jnp.full((), jnp.nan, jnp.float32),
            last_length=jnp.zeros((), jnp.int32),
            key=carry_key,
            inner=inner,
        )

    def step(self, state: EnvState, action: Array) -> EnvState:
        """One step. Does not reset: see `auto_reset`. Actions are clipped to [-1, 1]."""
        action = jnp.clip(action, -1.0, 1.0)
        inner, obs, reward, terminated, desc = self._step(state.inner, action)
        reward = jnp.asarray(reward, jnp.float32)
        terminated = jnp.asarray(terminated, jnp.float32)
        step = state.step + 1
        truncated = jnp.where(
            (step >= self.episode_length) & (terminated == 0.0), 1.0, 0.0
        ).astype(jnp.float32)
        done = jnp.maximum(terminated, truncated) > 0
        episode_return = state.episode_return + reward
        return EnvState(
            obs=jnp.asarray(obs, jnp.float32),
            reward=reward,
            terminated=terminated,
            truncated=truncated,
            desc=jnp.asarray(desc, jnp.float32),
            step=step,
            episode_return=episode_return,
            last_return=jnp.where(done, episode_return, state.last_return),
            last_length=jnp.where(done, step, state.last_length),
            key=state.key,
            inner=inner,
        )

    # -- sizes, computed by abstract evaluation (no compilation, no real reset) --

    def traced_reset(self, key: PRNGKey | None = None) -> jax.stages.Traced:
        """`reset`, traced once per key type (a raw `PRNGKey` by default) and kept: its
        output shapes give the sizes below, and `.lower().compile()` a program that resets
        from any key of that type (`qdrl.rollout.fixed_start_state`). Tracing a brax
        reset takes most of a second; a task traces it once."""
        spec = jax.eval_shape(lambda: jax.random.PRNGKey(0)) if key is None else jax.ShapeDtypeStruct(
            jnp.shape(key), key.dtype
        )
        cache: dict[tuple[Any, ...], jax.stages.Traced] = self.__dict__.setdefault("_traced_resets", {})
        entry = (spec.shape, str(spec.dtype))
        if entry not in cache:
            cache[entry] = jax.jit(self.reset).trace(spec)
        return cache[entry]

    def _shapes(self) -> EnvState:
        shapes: EnvState = self.traced_reset().out_info
        return shapes

    @property
    def observation_size(self) -> int:
        return int(self._shapes().obs.shape[-1])

    @property
    def descriptor_size(self) -> int:
        return int(self._shapes().desc.shape[-1])

    @property
    def descriptor_names(self) -> tuple[str, ...]:
        """Names of the state descriptor's dimensions, for plots: "x", "y" for a 2-D one by
        default; environments whose descriptor is something else name it."""
        names = getattr(self, "_descriptor_names", None)
        if names is not None:
            return tuple(names)
        n = self.descriptor_size
        return ("x", "y") if n == 2 else tuple(f"descriptor {i}" for i in range(n))


def reset_batch(env: Env, key: PRNGKey, num_envs: int) -> EnvState:
    """`num_envs` independent fresh episodes, batched on the leading axis."""
    return jax.vmap(env.reset)(jax.random.split(key, num_envs))


def step_batch(env: Env, state: EnvState, action: Array) -> EnvState:
    """Step a batch of environments with a batch of actions."""
    return jax.vmap(env.step)(state, action)


def auto_reset(env: Env, state: EnvState) -> EnvState:
    """Reset the finished environments of a batch, keeping their episode metrics.

    The reset is computed only on steps where some environment is done
    (`lax.cond`), so fixed-length episodes pay for it once per episode, not per step.
    Each reset uses a fresh key split from the environment's own key.
    """

    def reset_done(s: EnvState) -> EnvState:
        keys = jax.vmap(jax.random.split)(s.key)
        fresh = jax.vmap(env.reset)(keys[:, 0])
        done = s.done > 0

        def pick(new: Array, old: Array) -> Array:
            mask = done.reshape(done.shape + (1,) * (old.ndim - done.ndim))
            return jnp.where(mask, new, old)

        merged: EnvState = jax.tree.map(pick, fresh, s)
        return merged._replace(
            key=jnp.where(done[:, None], keys[:, 1], s.key),
            last_return=s.last_return,
            last_length=s.last_length,
        )

    return jax.lax.cond(jnp.any(state.done > 0), reset_done, lambda s: s, state)
