"""Jumanji adapter: a discrete-action jumanji environment behind qdrl's `Env` protocol.

Jumanji (InstaDeep, Bonnet et al. 2024, "Jumanji: a diverse suite of scalable
reinforcement learning environments in JAX") environments are functional
(`reset(key) -> (state, timestep)`, `step(state, action) -> (state, timestep)`),
so they sit behind `qdrl.envs.base.Env` unchanged, and the same rollout loop,
training loop and QD policy tasks run on them. The adapter fixes three things:

- Observation: a structured observation becomes one float32 vector through
  `observation_fn` (default `flatten_observation`: every leaf, raveled and
  concatenated; `snake_observation` for Snake).
- Action: qdrl policies output continuous actions in [-1, 1]^K. For a
  `DiscreteArray` action spec with K values, `action_size = K` and the action
  taken is the argmax of the policy output over the actions the observation's
  `action_mask` allows (`masked_argmax`), when the observation has a (K,) mask and
  `use_action_mask` is on. If no action is allowed, action 0 is taken (the
  environment ends the episode as it would for any invalid action).
- End of episode: `timestep.last()` is reported as a termination. Jumanji ends
  episodes at its own time limit too (Snake with discount 0); so that qdrl's
  `episode_length` truncates first, an environment with a `time_limit`
  attribute must have `time_limit > episode_length` (checked).

The state descriptor is `descriptor_fn(state, timestep, action)` of the jumanji
state, timestep and the discrete action just taken (-1 after a reset); by
default an empty vector. For Snake, `snake_head_position`.

With `start_seed` set, every episode starts from the one state that jumanji's
reset gives for `PRNGKey(start_seed)` (the reset key is ignored): an evaluation of
a deterministic policy is then a deterministic function of its parameters, as
when QDax evaluates brax policies from one fixed initial state. Jumanji's later
randomness (Snake's new fruits) comes from a key inside its state, so it is
fixed too. Leave it None for RL training.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import jumanji
from jumanji import specs

from qdrl.envs.base import Env
from qdrl.types import Array, PRNGKey

ObservationFn = Callable[[Any], Array]
# (jumanji state, jumanji timestep, discrete action taken, -1 after reset) -> (D,)
DescriptorFn = Callable[[Any, Any, Array], Array]


class JumanjiInner(NamedTuple):
    """The backend state: jumanji's own state and the mask of the actions allowed next."""

    state: Any
    action_mask: Array | None  # (K,) bool, or None when the env has no usable mask


def flatten_observation(observation: Any) -> Array:
    """Every leaf of a (structured) observation as float32, raveled and concatenated."""
    leaves = [jnp.ravel(jnp.asarray(x, jnp.float32)) for x in jax.tree.leaves(observation)]
    return jnp.concatenate(leaves) if leaves else jnp.zeros((0,), jnp.float32)


def snake_observation(observation: Any) -> Array:
    """Snake's grid (rows x cols x 5 feature maps: body, head, tail, fruit, body order)
    flattened, then its 4-action mask as 0/1: a (rows * cols * 5 + 4,) vector in [0, 1].

    The step count is left out: the policy acts the same at every step of an episode.
    """
    grid = jnp.ravel(jnp.asarray(observation.grid, jnp.float32))
    return jnp.concatenate([grid, jnp.asarray(observation.action_mask, jnp.float32)])


def snake_head_position(num_rows: int, num_cols: int) -> DescriptorFn:
    """Descriptor of Snake: the head's (row, col) scaled to [0, 1]^2.

    Row 0 is the top of the grid. After a fatal move the head may sit just off the
    grid; it is clipped back to the edge.
    """

    def descriptor(state: Any, timestep: Any, action: Array) -> Array:
        del timestep, action
        head = jnp.stack([state.head_position.row, state.head_position.col]).astype(jnp.float32)
        scale = jnp.asarray([max(num_rows - 1, 1), max(num_cols - 1, 1)], jnp.float32)
        return jnp.clip(head / scale, 0.0, 1.0)

    return descriptor


def action_frequencies(num_actions: int) -> DescriptorFn:
    """Descriptor of any discrete env: the one-hot of the action taken (zeros after reset).

    Its mean over an episode (`descriptor="mean"` in policy tasks) is the share of
    each action, in [0, 1]^K.
    """

    def descriptor(state: Any, timestep: Any, action: Array) -> Array:
        del state, timestep
        return jax.nn.one_hot(action, num_actions, dtype=jnp.float32)

    return descriptor


def _no_descriptor(state: Any, timestep: Any, action: Array) -> Array:
    del state, timestep, action
    return jnp.zeros((0,), jnp.float32)


def masked_argmax(action: Array, mask: Array | None) -> Array:
    """The index of the largest entry of `action` (K,) among those `mask` allows (int32).

    With `mask` None every action is allowed; with no action allowed, index 0.
    """
    if mask is not None:
        action = jnp.where(mask, action, -jnp.inf)
    return jnp.argmax(action).astype(jnp.int32)


class JumanjiEnv(Env):
    """A jumanji environment with a discrete action spec, as a qdrl `Env` (see the module doc)."""

    def __init__(
        self,
        env: str | Any,
        episode_length: int = 1000,
        observation_fn: ObservationFn = flatten_observation,
        descriptor_fn: DescriptorFn | None = None,
        use_action_mask: bool = True,
        start_seed: int | None = None,
        **env_kwargs: Any,
    ) -> None:
        """Wrap `env`: a jumanji environment, or a registered id (e.g. "Snake-v1") made
        with `jumanji.make(env, **env_kwargs)`.
        """

        if episode_length <= 0:
            raise ValueError(f"episode_length must be a positive integer, got {episode_length}")
        if isinstance(env, str):
            known = sorted(jumanji.registered_environments())
            if env not in known:
                raise ValueError(f"unknown jumanji environment {env!r}; expected one of {known}")
            self.name = env
            env = jumanji.make(env, **env_kwargs)
        elif env_kwargs:
            raise ValueError(
                f"env_kwargs {sorted(env_kwargs)} are only used with an environment id"
            )
        else:
            self.name = type(env).__name__
        spec = env.action_spec
        if not isinstance(spec, specs.DiscreteArray):
            raise ValueError(
                f"{self.name}: only DiscreteArray action specs are supported, got {type(spec).__name__}"
            )
        time_limit = getattr(env, "time_limit", None)
        if isinstance(time_limit, int) and time_limit <= episode_length:
            raise ValueError(
                f"{self.name}: jumanji's time_limit ({time_limit}) must exceed episode_length "
                f"({episode_length}) so that qdrl truncates the episode before jumanji ends it; "
                f"pass time_limit={episode_length + 1} or more"
            )
        self.jumanji_env: Any = env
        self.episode_length = episode_length
        self.action_size = int(spec.num_values)
        self.observation_fn = observation_fn
        self.descriptor_fn = _no_descriptor if descriptor_fn is None else descriptor_fn
        self.use_action_mask = use_action_mask
        self.start_seed = start_seed

    def _action_mask(self, observation: Any) -> Array | None:
        mask = getattr(observation, "action_mask", None)
        if not self.use_action_mask or mask is None or jnp.shape(mask) != (self.action_size,):
            return None
        return jnp.asarray(mask, bool)

    def _reset(self, key: PRNGKey) -> tuple[Any, Array, Array]:
        if self.start_seed is not None:
            key = jax.random.PRNGKey(self.start_seed)
        state, timestep = self.jumanji_env.reset(key)
        inner = JumanjiInner(state, self._action_mask(timestep.observation))
        no_action = jnp.asarray(-1, jnp.int32)
        desc = self.descriptor_fn(state, timestep, no_action)
        return inner, self.observation_fn(timestep.observation), desc

    def _step(self, inner: Any, action: Array) -> tuple[Any, Array, Array, Array, Array]:
        discrete = masked_argmax(action, inner.action_mask)
        state, timestep = self.jumanji_env.step(inner.state, discrete)
        next_inner = JumanjiInner(state, self._action_mask(timestep.observation))
        desc = self.descriptor_fn(state, timestep, discrete)
        return (
            next_inner,
            self.observation_fn(timestep.observation),
            jnp.asarray(timestep.reward, jnp.float32),
            timestep.last().astype(jnp.float32),
            desc,
        )


def snake_env(
    episode_length: int = 100,
    num_rows: int = 12,
    num_cols: int = 12,
    use_action_mask: bool = True,
    start_seed: int | None = None,
) -> JumanjiEnv:
    """Jumanji's Snake-v1 (reward 1 per fruit) with `snake_observation` and the head
    position (`snake_head_position`) as state descriptor; `start_seed` as in `JumanjiEnv`.

    Jumanji's time limit is set to `max(4000, episode_length + 1)` (4000 is its
    default) so that qdrl's `episode_length` always truncates first.
    """
    return JumanjiEnv(
        "Snake-v1",
        episode_length=episode_length,
        observation_fn=snake_observation,
        descriptor_fn=snake_head_position(num_rows, num_cols),
        use_action_mask=use_action_mask,
        start_seed=start_seed,
        num_rows=num_rows,
        num_cols=num_cols,
        time_limit=max(4000, episode_length + 1),
    )
