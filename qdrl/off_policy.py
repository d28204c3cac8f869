"""The one off-policy training loop: collect, store, update — as a jitted scan.

SAC, TD3, and later DIAYN, DADS, SMERL and PBT train through `make_trainer`.
One iteration acts in `num_envs` environments, inserts those transitions into
the replay buffer and runs `grad_steps_per_iter` agent updates on uniformly
sampled batches. Before `learning_starts` environment steps, actions are uniform
random and no update runs. `Trainer.run_chunk` scans many iterations; Python
only runs between chunks. Where transitions are stored is a parameter
(`Storage`): the ring replay buffer by default, or a buffer that also knows each
transition's episode return (`EPISODE_RETURNS`, for SMERL).

On several devices (`placement`, `qdrl.placement`) the environments are split
over the devices (`STATE_AXES`), the agent and the replay buffer are replicated,
and each gradient step is data-parallel: its batch is split over the devices and
the gradients are averaged across them (the loss's mean over the batch, which
XLA partitions into per-device sums and one all-reduce).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from qdrl import buffers
from qdrl.agents.base import Agent, AgentState
from qdrl.config import NonNegativeInt, PositiveInt, check_fields
from qdrl.envs.base import Env, EnvState, reset_batch
from qdrl.placement import Placement
from qdrl.rollout import Episodes, RecordFn, env_step, run_episodes
from qdrl.types import Array, PRNGKey, Transition


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Settings of the off-policy loop (the agent's own settings are in its config)."""

    total_env_steps: PositiveInt = 1_000_000  # environment steps of the whole run
    num_envs: PositiveInt = 16  # environments stepped in parallel for collection
    batch_size: PositiveInt = 256  # transitions per gradient step
    buffer_size: PositiveInt = 1_000_000  # replay capacity, in transitions
    learning_starts: NonNegativeInt = 10_000  # env steps of uniform random actions before any update
    grad_steps_per_iter: PositiveInt = 16  # updates per iteration (num_envs env steps)
    eval_every: PositiveInt = 10_000  # env steps between log points (evaluation, metrics row)
    num_eval_envs: PositiveInt = 16  # episodes per evaluation, deterministic policy

    def check(self) -> None:
        check_fields(self, "train")
        if self.eval_every % self.num_envs:
            raise ValueError(
                f"train.eval_every: expected a multiple of train.num_envs={self.num_envs}, "
                f"got {self.eval_every}"
            )
        if self.batch_size > self.buffer_size:
            raise ValueError(
                f"train.batch_size: expected at most train.buffer_size={self.buffer_size}, "
                f"got {self.batch_size}"
            )

    @property
    def iters_per_chunk(self) -> int:
        return self.eval_every // self.num_envs

    @property
    def num_chunks(self) -> int:
        return -(-self.total_env_steps // self.eval_every)


class Storage(NamedTuple):
    """Where the loop stores transitions and how it samples the batches `agent.update` gets.

    init(example_transition, capacity, num_envs) -> buffer   (a pytree with `.size`)
    insert(buffer, transitions, env_state_after_step) -> buffer
    sample(buffer, key, n) -> batch of n items, the `transitions` argument of `agent.update`
    """

    init: Callable[[Transition, int, int], Any]
    insert: Callable[[Any, Transition, EnvState], Any]
    sample: Callable[[Any, PRNGKey, int], Any]


# The ring replay buffer: batches are `Transition`s.
REPLAY = Storage(
    init=lambda example, capacity, num_envs: buffers.init(example, capacity),
    insert=lambda buffer, transitions, env_state: buffers.insert(buffer, transitions),
    sample=buffers.sample,
)

# The trajectory buffer: batches are `(Transition, episode_return)` (SMERL). After
# `auto_reset`, `last_return` holds the return of the episode a step just ended.
EPISODE_RETURNS = Storage(
    init=buffers.trajectory_init,
    insert=lambda buffer, transitions, env_state: buffers.trajectory_insert(
        buffer,
        transitions,
        jnp.maximum(transitions.terminated, transitions.truncated),
        env_state.last_return,
    ),
    sample=buffers.trajectory_sample,
)


class TrainState(NamedTuple):
    """Everything a run carries between iterations; checkpointing saves exactly this."""

    agent: AgentState
    buffer: Any  # the `Storage`'s buffer: a `buffers.ReplayBuffer` by default
    env: EnvState
    key: PRNGKey
    env_steps: Array  # int32, environment steps taken
    grad_steps: Array  # int32, agent updates taken


# Which axis of each part of a `TrainState` is split over the devices (None: replicated).
STATE_AXES = TrainState(agent=None, buffer=None, env=0, key=None, env_steps=None, grad_steps=None)  # type: ignore[arg-type]


class Trainer(NamedTuple):
    """The jittable functions of one off-policy run."""

    init: Callable[[PRNGKey], TrainState]
    run_chunk: Callable[[TrainState], tuple[TrainState, dict[str, Array]]]
    evaluate: Callable[[AgentState, PRNGKey], dict[str, Array]]
    # The episodes `evaluate` plays from the same key (`record` as in `run_episodes`): a loaded
    # run replays them (`qdrl.load_run(...).rollout()`).
    episodes: Callable[..., Episodes]


def transition_example(env: Env) -> Transition:
    """A zero transition of `env`'s shapes (what a buffer of its transitions is built from)."""
    obs = jnp.zeros((env.observation_size,), jnp.float32)
    desc = jnp.zeros((env.descriptor_size,), jnp.float32)
    scalar = jnp.zeros((), jnp.float32)
    action = jnp.zeros((env.action_size,), jnp.float32)
    return Transition(obs, action, scalar, obs, scalar, scalar, desc, desc)


def make_trainer(
    env: Env, agent: Agent, config: TrainConfig, storage: Storage = REPLAY,
    placement: Placement | None = None,
) -> Trainer:
    """Build the init / chunk / evaluate functions of an off-policy run of `agent` on `env`.

    `storage` says where transitions go and what batches `agent.update` receives;
    `placement` spreads the environments and each gradient step's batch over its
    devices (see the module docstring; `num_envs` and `batch_size` must divide by
    their number).
    """
    config.check()
    place = placement or Placement()
    action_size = env.action_size

    def init(key: PRNGKey) -> TrainState:
        agent_key, env_key, key = jax.random.split(key, 3)
        return place.place(TrainState(
            agent=agent.init(agent_key),
            buffer=storage.init(transition_example(env), config.buffer_size, config.num_envs),
            env=reset_batch(env, env_key, config.num_envs),
            key=key,
            env_steps=jnp.zeros((), jnp.int32),
            grad_steps=jnp.zeros((), jnp.int32),
        ), STATE_AXES)

    def updates(agent_state: AgentState, buffer: Any, key: PRNGKey) -> Any:
        # All batches of the iteration come from one gather, then one update each.
        sample_key, update_key = jax.random.split(key)
        n = config.grad_steps_per_iter
        flat = storage.sample(buffer, sample_key, n * config.batch_size)
        batches = jax.tree.map(lambda x: x.reshape((n, config.batch_size, *x.shape[1:])), flat)

        def one(s: AgentState, xs: tuple[Any, PRNGKey]) -> tuple[AgentState, Any]:
            # The step's batch split over the devices, the agent replicated: XLA computes
            # per-device partial gradients and all-reduces them (data-parallel).
            s, m = agent.update(place.replicated(s), place.batched(xs[0]), xs[1])
            return place.replicated(s), m

        s, metrics = jax.lax.scan(one, agent_state, (batches, jax.random.split(update_key, n)))
        # nan marks a metric an update did not produce (a model trained every k-th update).
        return s, jax.tree.map(jnp.nanmean, metrics)

    def iteration(ts: TrainState, _: None) -> tuple[TrainState, dict[str, Array]]:
        key, act_key, update_key = jax.random.split(ts.key, 3)
        warmup = ts.env_steps < config.learning_starts

        def policy(obs: Array, k: PRNGKey) -> Array:
            random_key, agent_key = jax.random.split(k)
            uniform = jax.random.uniform(random_key, (obs.shape[0], action_size), minval=-1.0, maxval=1.0)
            return jnp.where(warmup, uniform, agent.act(ts.agent, obs, agent_key))

        env_state, transition = env_step(env, ts.env, policy, act_key)
        env_state = place.batched(env_state)
        buffer = place.replicated(storage.insert(ts.buffer, transition, env_state))
        env_steps = ts.env_steps + config.num_envs
        can_train = (env_steps >= config.learning_starts) & (buffer.size >= config.batch_size)

        metric_shapes = jax.eval_shape(updates, ts.agent, buffer, update_key)[1]

        def skip(s: AgentState, b: Any, k: PRNGKey) -> Any:
            return s, jax.tree.map(lambda x: jnp.full(x.shape, jnp.nan, x.dtype), metric_shapes)

        agent_state, metrics = jax.lax.cond(can_train, updates, skip, ts.agent, buffer, update_key)
        agent_state = place.replicated(agent_state)
        metrics = dict(metrics)
        metrics["train_return"] = jnp.nanmean(env_state.last_return)
        new = TrainState(
            agent=agent_state,
            buffer=buffer,
            env=env_state,
            key=key,
            env_steps=env_steps,
            grad_steps=ts.grad_steps + jnp.where(can_train, config.grad_steps_per_iter, 0),
        )
        return new, metrics

    def run_chunk(ts: TrainState) -> tuple[TrainState, dict[str, Array]]:
        ts, metrics = jax.lax.scan(iteration, ts, None, length=config.iters_per_chunk)
        # nan marks iterations without updates; average over the others.
        return ts, jax.tree.map(lambda m: jnp.nanmean(m, axis=0), metrics)

    def eval_episodes(agent_state: AgentState, key: PRNGKey, record: RecordFn | None = None) -> Episodes:
        params = agent.policy_params(agent_state)
        return run_episodes(
            env, lambda obs, _: agent.policy(params, obs), key, config.num_eval_envs, record=record
        )

    def evaluate(agent_state: AgentState, key: PRNGKey) -> dict[str, Array]:
        episodes = eval_episodes(agent_state, key)
        return {
            "eval_return": jnp.mean(episodes.returns),
            "eval_return_std": jnp.std(episodes.returns),
            "eval_length": jnp.mean(episodes.lengths.astype(jnp.float32)),
            "eval_returns": episodes.returns,
            "eval_final_desc": episodes.final_desc,
            "eval_mean_desc": episodes.mean_desc,
        }

    return Trainer(init=init, run_chunk=run_chunk, evaluate=evaluate, episodes=eval_episodes)
