"""Policy networks as genotypes: one jitted rollout evaluates a whole batch of policies.

Genotypes are batched haiku parameter trees of a deterministic policy; policy i
acts in environment i of a batch, through the one rollout loop of qdrl
(`qdrl.rollout.run_episodes`). Fitness is the episode return (steps after the
episode ended are masked), the descriptor is computed from the trajectory of
state descriptors (its last value or its mean over the episode), and the
transitions are handed back in `extras["transitions"]` (with `extras["mask"]`)
for actor-critic emitters to store in a replay buffer, with the episodes'
descriptors in `extras["descriptors"]` (the same as `Evaluation.descriptors`, but
an extra: `MultiEmitter` hands extras whole to every sub-emitter, so an emitter
that labels every stored transition with its episode's descriptor, DCRL-ME's,
sees all of them and not only its own slice).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, Literal

import haiku as hk
import jax
import jax.numpy as jnp

from qdrl import nets
from qdrl.envs.base import Env
from qdrl.qd.base import Evaluation, ScoringFn
from qdrl.rollout import run_episodes
from qdrl.tasks.base import Task
from qdrl.types import Genotype, Params, PRNGKey

EpisodeDescriptor = Literal["final", "mean"]


def policy_network(action_size: int, hidden: Sequence[int] = (64, 64), act: str = "tanh") -> hk.Transformed:
    """The QD-RL literature's policy: a 64x64 tanh MLP, tanh output, lecun-uniform init (QDax)."""
    return nets.deterministic_policy(action_size, hidden, act, init="lecun_uniform")


def init_policies(
    network: hk.Transformed, observation_size: int, key: PRNGKey, n: int
) -> Params:
    """`n` independently initialised policies, stacked on a leading axis."""
    obs = jnp.zeros((observation_size,), jnp.float32)
    return jax.vmap(lambda k: network.init(k, obs))(jax.random.split(key, n))


def num_parameters(params: Params) -> int:
    """Scalars in one (unbatched) parameter tree."""
    return int(sum(x.size for x in jax.tree.leaves(params)))


def policy_scoring_fn(
    env: Env,
    network: hk.Transformed,
    descriptor: EpisodeDescriptor = "mean",
    num_steps: int | None = None,
    descriptor_fn: Callable[[jax.Array], jax.Array] | None = None,
    fixed_start: bool = True,
) -> ScoringFn:
    """A scoring function of batched policy parameters on `env`.

    Args:
      env: the environment; its state descriptor is aggregated per episode.
      network: the policy (`apply(params, obs) -> action`).
      descriptor: "final" (state descriptor after the episode's last step, e.g. the
        torso x-y) or "mean" (averaged over the episode, e.g. feet-contact rates).
      num_steps: episode length (default: the env's).
      descriptor_fn: optional map of the aggregated descriptor (e.g. a clip).
      fixed_start: every policy starts from the same initial state (QDax's
        deterministic evaluation, the QD-RL benchmarks' convention), so a policy's
        fitness and descriptor do not depend on the evaluation key; False gives
        each episode its own random initial state.
    """
    if descriptor not in ("final", "mean"):
        raise ValueError(f"descriptor: expected 'final' or 'mean', got {descriptor!r}")

    def scoring_fn(genotypes: Genotype, key: PRNGKey) -> Evaluation:
        n = jax.tree.leaves(genotypes)[0].shape[0]

        def policy(obs: jax.Array, _: PRNGKey) -> jax.Array:
            return jax.vmap(network.apply)(genotypes, obs)

        start = jax.random.PRNGKey(0) if fixed_start else None
        episodes = run_episodes(env, policy, key, n, num_steps, start_key=start)
        desc = episodes.final_desc if descriptor == "final" else episodes.mean_desc
        if descriptor_fn is not None:
            desc = descriptor_fn(desc)
        # A policy whose rollout blew up (NaN return) is rejected by the repertoire.
        return Evaluation(
            fitnesses=episodes.returns.astype(jnp.float32),
            descriptors=desc.astype(jnp.float32),
            extras={
                "transitions": episodes.transitions,
                "mask": episodes.mask,
                "descriptors": desc.astype(jnp.float32),
            },
            env_steps=jnp.sum(episodes.lengths).astype(jnp.int32),
        )

    return scoring_fn


def policy_task(
    name: str,
    env: Env,
    descriptor: EpisodeDescriptor,
    descriptor_low: Sequence[float],
    descriptor_high: Sequence[float],
    qd_offset: float,
    policy_hidden: Sequence[int] = (64, 64),
    max_fitness: float | None = None,
    clip_descriptors: bool = True,
) -> Task:
    """A `Task` whose genotypes are MLP policies acting in `env` for one episode each.

    Fitness is the episode return; the descriptor is the episode's state descriptor
    ("final" or "mean" over its steps), clipped to the bounds if `clip_descriptors`.
    Genotypes are unbounded parameter trees (`genotype_low/high` = -inf/inf).
    """
    low = jnp.asarray(descriptor_low, jnp.float32)
    high = jnp.asarray(descriptor_high, jnp.float32)
    if low.shape != (env.descriptor_size,) or high.shape != (env.descriptor_size,):
        raise ValueError(
            f"{name}: descriptor bounds of shape {low.shape} and {high.shape} for "
            f"a state descriptor of size {env.descriptor_size}"
        )
    network = policy_network(env.action_size, tuple(int(h) for h in policy_hidden))
    obs_size = env.observation_size
    # Zeros of the right shapes: an actual un-jitted init costs seconds on a CPU.
    shapes = jax.eval_shape(lambda k: init_policies(network, obs_size, k, 1), jax.random.PRNGKey(0))
    template: Params = jax.tree.map(lambda x: jnp.zeros(x.shape[1:], x.dtype), shapes)

    def init_fn(key: PRNGKey, n: int) -> Params:
        return init_policies(network, obs_size, key, n)

    def clip(desc: jax.Array) -> jax.Array:
        return jnp.clip(desc, low, high)

    def scoring_for(policy: Any) -> ScoringFn:
        return policy_scoring_fn(env, policy, descriptor, descriptor_fn=clip if clip_descriptors else None)

    return Task(
        name=name,
        scoring_fn=scoring_for(network),
        descriptor_low=tuple(float(v) for v in descriptor_low),
        descriptor_high=tuple(float(v) for v in descriptor_high),
        genotype_size=num_parameters(template),
        genotype_low=-math.inf,
        genotype_high=math.inf,
        qd_offset=qd_offset,
        max_fitness=max_fitness,
        init_fn=init_fn,
        genotype_template=template,
        env=env,
        policy_scoring=scoring_for,
        episode_descriptor=descriptor,
    )
