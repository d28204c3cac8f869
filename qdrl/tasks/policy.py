"""Policy networks as genotypes: one jitted rollout evaluates a whole batch of policies.

Genotypes are batched haiku parameter trees of a deterministic policy; policy i
acts in environment i of a batch, through the one rollout loop of qdrl
(`qdrl.rollout.run_episodes`).

Batches are evaluated in blocks of a fixed width (`eval_batch`): the batch is
padded to a multiple of it and the blocks are rolled out one after the other
(`lax.map`). XLA compiles a batched physics step differently for different batch
sizes (on the CPU, halfcheetah's spring pipeline gives results that differ in the
last bits for batches of 1, 2-4, 8-65, 128-130 and 256), and the contact dynamics
of the robots are chaotic: a relative change of 1e-7 in a policy's parameters
moves its 100-step return by several units. Without a fixed width, the same
policy scored alone or in another batch gets another fitness and descriptor; with
it, each policy sees exactly the same computation wherever it sits in whichever
batch (tests/tasks/test_policy_eval.py). Fitness is the episode return (steps after the
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
from typing import Annotated, Any, Literal

import haiku as hk
import jax
import jax.numpy as jnp

from qdrl import nets
from qdrl.config import OneOf
from qdrl.envs.base import Env
from qdrl.qd.base import Evaluation, ScoringFn
from qdrl.rollout import Episodes, RecordFn, fixed_start_state, run_episodes
from qdrl.tasks.base import PolicyNetwork, Task
from qdrl.types import Genotype, Params, PRNGKey

EpisodeDescriptor = Literal["final", "mean"]

# Episodes rolled out together when a task is built without the run's batch size.
DEFAULT_EVAL_BATCH = 64

# A policy's hidden activation, as a task parameter (`policy_activation`): tanh in qdrl's QD-RL
# specs, relu in QDax's MLP default (the skill-discovery benchmark's policies).
Activation = Annotated[str, OneOf(lambda: sorted(nets.ACTIVATIONS))]


def policy_network(action_size: int, hidden: Sequence[int] = (64, 64), act: str = "tanh") -> hk.Transformed:
    """The QD-RL literature's policy: a 64x64 MLP (hidden activation `act`), tanh output, lecun-uniform init (QDax)."""
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
    eval_batch: int | None = DEFAULT_EVAL_BATCH,
    record: RecordFn | None = None,
    objectives: RecordFn | None = None,
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
      eval_batch: episodes rolled out together (see the module docstring): a batch
        of n policies is padded to a multiple of it and evaluated block by block,
        so a policy's fitness and descriptor do not depend on the batch it is in.
        Set it to the run's batch size (the runners do) to pay no padding; None
        rolls out any batch at once, with batch-dependent numerics.
      record: also hand back `extras["recorded"]`, (T, n, ...): what this function of
        the batched env state keeps after each step (`qdrl.rollout.unroll_recorded`),
        e.g. brax's link poses to render an episode. The episodes are unchanged.
      objectives: for multi-objective tasks, the per-step rewards of M objectives,
        (n, M), read from the batched env state after each step (e.g. brax's
        forward-reward and control-cost metrics); the fitness is then their
        episode sums (n, M) over the episode's valid steps instead of the return.
        It rides on the same rollout as `record`.
    """
    if descriptor not in ("final", "mean"):
        raise ValueError(f"descriptor: expected 'final' or 'mean', got {descriptor!r}")
    if eval_batch is not None and eval_batch < 1:
        raise ValueError(f"eval_batch: expected a positive integer or None, got {eval_batch}")
    # The one start state of every evaluation (QDax's deterministic scoring), computed when
    # the first evaluation is traced: evaluation programs broadcast it instead of resetting
    # (see `fixed_start_state`).
    start_key = jax.random.PRNGKey(0) if fixed_start else None
    start_states: list[Any] = []

    def start_state() -> Any:
        if start_key is None:
            return None
        if not start_states:
            start_states.append(fixed_start_state(env, start_key))
        return start_states[0]
    recorder: RecordFn | None = record
    if objectives is not None:
        user_record, objective_fn = record, objectives

        def recorder(state: Any) -> Any:
            return (objective_fn(state), None if user_record is None else user_record(state))

    def rollout(genotypes: Genotype, key: PRNGKey) -> Episodes:
        n = jax.tree.leaves(genotypes)[0].shape[0]

        def policy(obs: jax.Array, _: PRNGKey) -> jax.Array:
            return jax.vmap(network.apply)(genotypes, obs)

        return run_episodes(env, policy, key, n, num_steps, record=recorder, start_state=start_state())

    # One jitted rollout per task: jax traces it once per block shape and reuses the trace
    # wherever the task is evaluated again with that shape (a run's initial population and
    # its step), so a costly trace such as brax's step is paid once. The compiled
    # programs are unchanged: XLA inlines the call.
    rollout = jax.jit(rollout)

    def scoring_fn(genotypes: Genotype, key: PRNGKey) -> Evaluation:
        n = jax.tree.leaves(genotypes)[0].shape[0]
        if eval_batch is None:
            episodes = rollout(genotypes, key)
        else:
            episodes = _in_blocks(rollout, genotypes, key, n, eval_batch)
        desc = episodes.final_desc if descriptor == "final" else episodes.mean_desc
        if descriptor_fn is not None:
            desc = descriptor_fn(desc)
        extras = {
            "transitions": episodes.transitions,
            "mask": episodes.mask,
            "descriptors": desc.astype(jnp.float32),
        }
        fitnesses = episodes.returns
        recorded = episodes.recorded
        if objectives is not None:
            per_step, recorded = recorded  # (T, n, M), the user's record
            fitnesses = jnp.sum(per_step * episodes.mask[..., None], axis=0)
        if record is not None:
            extras["recorded"] = recorded
        # A policy whose rollout blew up (NaN return) is rejected by the repertoire.
        return Evaluation(
            fitnesses=fitnesses.astype(jnp.float32),
            descriptors=desc.astype(jnp.float32),
            extras=extras,
            env_steps=jnp.sum(episodes.lengths).astype(jnp.int32),
        )

    return scoring_fn


def _in_blocks(
    rollout: Callable[[Genotype, PRNGKey], Episodes],
    genotypes: Genotype,
    key: PRNGKey,
    n: int,
    width: int,
) -> Episodes:
    """`rollout` of n policies as ceil(n / width) blocks of `width`, one after the other.

    The last block is padded with copies of the first policy, whose episodes are
    dropped. Every block is the same computation, so a policy's episode does not
    depend on n or on its place in the batch.
    """
    num_blocks = -(-n // width)
    pad = num_blocks * width - n

    def blocks(x: jax.Array) -> jax.Array:
        if pad:
            x = jnp.concatenate([x, jnp.broadcast_to(x[:1], (pad, *x.shape[1:]))])
        return x.reshape(num_blocks, width, *x.shape[1:])

    keys = jax.random.split(key, num_blocks)
    out = jax.lax.map(lambda b: rollout(*b), (jax.tree.map(blocks, genotypes), keys))

    def batch_major(x: jax.Array) -> jax.Array:  # (blocks, width, ...) -> (n, ...)
        return x.reshape(num_blocks * width, *x.shape[2:])[:n]

    def time_major(x: jax.Array) -> jax.Array:  # (blocks, T, width, ...) -> (T, n, ...)
        x = jnp.moveaxis(x, 0, 1)
        return x.reshape(x.shape[0], num_blocks * width, *x.shape[3:])[:, :n]

    return Episodes(
        returns=batch_major(out.returns),
        lengths=batch_major(out.lengths),
        final_desc=batch_major(out.final_desc),
        mean_desc=batch_major(out.mean_desc),
        transitions=jax.tree.map(time_major, out.transitions),
        mask=time_major(out.mask),
        recorded=jax.tree.map(time_major, out.recorded),
    )


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
    eval_batch: int | None = DEFAULT_EVAL_BATCH,
    objectives: RecordFn | None = None,
    reference_point: Sequence[float] | None = None,
    descriptor_names: Sequence[str] = (),
    policy_activation: str = "tanh",
    random_start: bool = False,
) -> Task:
    """A `Task` whose genotypes are MLP policies acting in `env` for one episode each.

    Fitness is the episode return; the descriptor is the episode's state descriptor
    ("final" or "mean" over its steps), clipped to the bounds if `clip_descriptors`.
    Genotypes are unbounded parameter trees (`genotype_low/high` = -inf/inf).
    Episodes are rolled out in blocks of `eval_batch` (see `policy_scoring_fn`).
    With `objectives` (per-step rewards (n, M) of the env state, see
    `policy_scoring_fn`) the fitness is their episode sums and the task has M
    objectives, measured from `reference_point`. With `random_start`, each episode of the
    task's scoring starts from its own random state (noisy evaluations), not the fixed one.
    """
    if objectives is not None and reference_point is None:
        raise ValueError(f"{name}: a task with objectives needs a reference_point")
    low = jnp.asarray(descriptor_low, jnp.float32)
    high = jnp.asarray(descriptor_high, jnp.float32)
    if low.shape != (env.descriptor_size,) or high.shape != (env.descriptor_size,):
        raise ValueError(
            f"{name}: descriptor bounds of shape {low.shape} and {high.shape} for "
            f"a state descriptor of size {env.descriptor_size}"
        )
    network = policy_network(env.action_size, tuple(int(h) for h in policy_hidden), policy_activation)
    obs_size = env.observation_size
    # Zeros of the right shapes: an actual un-jitted init costs seconds on a CPU.
    shapes = jax.eval_shape(lambda k: init_policies(network, obs_size, k, 1), jax.random.PRNGKey(0))
    template: Params = jax.tree.map(lambda x: jnp.zeros(x.shape[1:], x.dtype), shapes)

    def init_fn(key: PRNGKey, n: int) -> Params:
        return init_policies(network, obs_size, key, n)

    def clip(desc: jax.Array) -> jax.Array:
        return jnp.clip(desc, low, high)

    def scoring_for(
        policy: Any = None, fixed_start: bool = True, record: RecordFn | None = None
    ) -> ScoringFn:
        return policy_scoring_fn(
            env, network if policy is None else policy, descriptor,
            descriptor_fn=clip if clip_descriptors else None, fixed_start=fixed_start,
            eval_batch=eval_batch, record=record, objectives=objectives,
        )

    return Task(
        name=name,
        scoring_fn=scoring_for(network, fixed_start=not random_start),
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
        num_objectives=1 if objectives is None else len(reference_point or ()),
        reference_point=None if reference_point is None else tuple(float(v) for v in reference_point),
        descriptor_names=tuple(descriptor_names),
        policy=PolicyNetwork(network, obs_size, env.action_size),
        random_start=random_start,
    )
