"""Task families of multi-task optimisation: a genotype's fitness depends on the task it is scored on.

Mouret & Maguire 2020, "Quality Diversity for Multi-task Optimization" (GECCO). A
family holds `num_tasks` tasks whose parameters are the centroids of a CVT of the
task-parameter box: `cvt_cells(task_seed, num_tasks, cvt_samples, low, high,
kmeans_iters)`, the very cells of a CVT repertoire with `num_centroids = num_tasks`
and `cvt_seed = task_seed` (Multi-task MAP-Elites, `qdrl.algorithms.multi_task`, keeps
one elite per task in such a repertoire). A genotype is `{"x": (d,) float32, "task":
() int32}`: the solution and the index of the task it is to be scored on, so that the
emitter that picks the task and the scoring function that reads it keep the QD loop's
contract (`emit -> scoring_fn -> repertoire.add`). The descriptor of an evaluation is
its task's parameters: the offspring competes only for that task's cell.

Families: `multi_task_arm` (the paper's parameterised planar arm) and
`multi_task_halfcheetah` (brax's HalfCheetah under scaled gravity and actuator strength).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from qdrl.config import NonNegativeInt, PositiveInt
from qdrl.envs.brax import Backend, BraxEnv
from qdrl.qd.base import Evaluation, ScoringFn
from qdrl.qd.repertoires.cvt import cvt_cells
from qdrl.rollout import fixed_start_state, run_episodes
from qdrl.tasks.base import Task, TaskEntry
from qdrl.tasks.brax_qd import DEFAULT_BACKEND, REWARD_OFFSETS
from qdrl.tasks.policy import init_policies, num_parameters, policy_network
from qdrl.types import Array, PRNGKey

__all__ = [
    "GENES",
    "MULTI_TASK_TASKS",
    "TASK",
    "MultiTaskFamily",
    "multi_task_arm",
    "multi_task_arm_fitness",
    "multi_task_halfcheetah",
]

GENES = "x"  # the genotype's solution leaf
TASK = "task"  # the genotype's task-index leaf (int32)


@dataclasses.dataclass(frozen=True)
class MultiTaskFamily:
    """How a family's tasks are laid out: the CVT of its task-parameter box (the `[task]` keys
    of the same names), which the recipe gives its repertoire so that cell i is task i."""

    num_tasks: int
    task_seed: int
    cvt_samples: int
    kmeans_iters: int
    low: tuple[float, ...]
    high: tuple[float, ...]

    def parameters(self) -> np.ndarray:
        """(num_tasks, P) task parameters, computed once per process (k-means, on the host)."""
        with jax.ensure_compile_time_eval():
            return cvt_cells(self.task_seed, self.num_tasks, self.cvt_samples, self.low, self.high, self.kmeans_iters)


def multi_task_arm_fitness(genotype: Array, parameters: Array) -> Array:
    """Fitness () of one arm configuration `genotype` (d,) on the task `parameters` = (alpha, L).

    The arm of Mouret & Maguire 2020 (the authors' pymap_elites `multitask_arm`): d
    joints, links of length L / d (total length L), joint i at angle
    a_i = 2 pi (alpha / d) (g_i - 0.5) (alpha in [0, 1] scales every joint's range,
    at most pi / d each way); with phi_k = sum_{i<=k} a_i the end effector is
    p = (L / d) sum_k (cos phi_k, sin phi_k), and the fitness is -|p - (0.5, 0.5)|.
    Genes are clipped to [0, 1].
    """
    g = jnp.clip(genotype, 0.0, 1.0)
    d = g.shape[-1]
    alpha, length = parameters[0], parameters[1]
    phi = jnp.cumsum(2.0 * jnp.pi * (alpha / d) * (g - 0.5))
    tip = (length / d) * jnp.stack([jnp.sum(jnp.cos(phi)), jnp.sum(jnp.sin(phi))])
    return -jnp.linalg.norm(tip - 0.5)


def multi_task_scoring_fn(
    fitness: Callable[[Array, Array], Array], family: MultiTaskFamily, genotype_size: int
) -> ScoringFn:
    """The scoring of genotypes `{"x": (n, genotype_size), "task": (n,)}`: fitness of x on its task,
    descriptor the task's parameters. A task index outside [0, num_tasks) is clipped into it."""
    batched = jax.vmap(fitness)

    def scoring_fn(genotypes: dict[str, Array], key: PRNGKey) -> Evaluation:
        del key  # deterministic
        if not isinstance(genotypes, dict) or set(genotypes) != {GENES, TASK}:
            raise ValueError(
                f"genotypes: expected a dict {{'{GENES}': (n, {genotype_size}), '{TASK}': (n,) int32}}, "
                f"got {jax.tree.map(jnp.shape, genotypes)}"
            )
        x = jnp.asarray(genotypes[GENES], jnp.float32)
        if x.ndim != 2 or x.shape[1] != genotype_size:
            raise ValueError(f"genotypes['{GENES}']: expected shape (n, {genotype_size}), got {x.shape}")
        task = jnp.clip(jnp.asarray(genotypes[TASK]).astype(jnp.int32), 0, family.num_tasks - 1)
        if task.shape != x.shape[:1]:
            raise ValueError(f"genotypes['{TASK}']: expected shape ({x.shape[0]},), got {task.shape}")
        parameters = jnp.asarray(family.parameters(), jnp.float32)[task]
        return Evaluation(
            fitnesses=batched(x, parameters).astype(jnp.float32),
            descriptors=parameters,
            extras={},
            env_steps=jnp.zeros((), jnp.int32),
        )

    return scoring_fn


def _multi_task_init(num_dofs: int, num_tasks: int) -> Callable[[PRNGKey, int], dict[str, Array]]:
    """n random solutions, uniform in [0, 1]^d, each on a task drawn uniformly (the paper's start)."""

    def init(key: PRNGKey, n: int) -> dict[str, Array]:
        x_key, task_key = jax.random.split(key)
        return {
            GENES: jax.random.uniform(x_key, (n, num_dofs), jnp.float32),
            TASK: jax.random.randint(task_key, (n,), 0, num_tasks, jnp.int32),
        }

    return init


def multi_task_arm(
    num_dofs: PositiveInt = 10,
    num_tasks: PositiveInt = 1000,
    task_seed: NonNegativeInt = 0,
    cvt_samples: PositiveInt = 10_000,
    kmeans_iters: PositiveInt = 50,
) -> Task:
    """The parameterised planar arm of Mouret & Maguire 2020: `num_tasks` arms of varied joint range
    and length (the 2-D task parameters (alpha, L) in [0, 1]^2, a CVT's centroids), each to reach
    (0.5, 0.5) (`multi_task_arm_fitness`). The paper's setting is 10 joints and 5000 tasks from
    30,000 samples (agents/mt_me_arm.toml); the defaults make 1000, whose k-means takes seconds.

    qd_offset = -(1 + sqrt(1/2)): an end effector within reach L <= 1 of the origin is at most
    that far from the target, so every fitness lies in [qd_offset, 0].
    """
    if cvt_samples < num_tasks:
        raise ValueError(f"task.cvt_samples: expected at least task.num_tasks={num_tasks}, got {cvt_samples}")
    family = multi_task_family(num_tasks, task_seed, cvt_samples, kmeans_iters)
    return Task(
        name="multi_task_arm",
        scoring_fn=multi_task_scoring_fn(multi_task_arm_fitness, family, num_dofs),
        descriptor_low=family.low,
        descriptor_high=family.high,
        descriptor_names=("joint range alpha", "arm length L"),
        genotype_size=num_dofs + 1,
        genotype_low=0.0,
        genotype_high=1.0,
        qd_offset=-(1.0 + math.sqrt(0.5)),
        max_fitness=0.0,
        init_fn=_multi_task_init(num_dofs, num_tasks),
        genotype_template={GENES: jnp.zeros((num_dofs,), jnp.float32), TASK: jnp.zeros((), jnp.int32)},
    )


@functools.cache
def multi_task_family(
    num_tasks: int, task_seed: int, cvt_samples: int, kmeans_iters: int, dims: int = 2
) -> MultiTaskFamily:
    """The layout of `num_tasks` tasks over the task-parameter box [0, 1]^dims."""
    return MultiTaskFamily(num_tasks, task_seed, cvt_samples, kmeans_iters, (0.0,) * dims, (1.0,) * dims)


def _check_genotypes(genotypes: Any, n_leaves: int) -> tuple[Any, Array]:
    """(solutions, task indices) of a batch of `{"x": ..., "task": (n,)}` genotypes; raises on another form."""
    if not isinstance(genotypes, dict) or set(genotypes) != {GENES, TASK}:
        raise ValueError(
            f"genotypes: expected a dict {{'{GENES}': ..., '{TASK}': (n,) int32}}, got {jax.tree.map(jnp.shape, genotypes)}"
        )
    x = genotypes[GENES]
    if len(jax.tree.leaves(x)) != n_leaves:
        raise ValueError(f"genotypes['{GENES}']: expected {n_leaves} leaves, got {len(jax.tree.leaves(x))}")
    return x, jnp.asarray(genotypes[TASK]).astype(jnp.int32)


def multi_task_halfcheetah(
    episode_length: PositiveInt = 100,
    num_tasks: PositiveInt = 200,
    task_seed: NonNegativeInt = 0,
    cvt_samples: PositiveInt = 5000,
    kmeans_iters: PositiveInt = 50,
    backend: Backend = DEFAULT_BACKEND,
    policy_hidden: tuple[PositiveInt, ...] = (32, 32),
) -> Task:
    """HalfCheetah under `num_tasks` dynamics: task (p_0, p_1) in [0, 1]^2 scales gravity by
    0.5 + p_0 and every actuator's strength by 0.5 + p_1 (`BraxEnv.perturbed`); fitness = brax's
    halfcheetah return over a short episode from one fixed start state.

    A multi-task family (the scoring reads each genotype's task, the descriptor is the task's
    parameters) on brax; genotypes are `{"x": policy parameters, "task": int32}`, the policy an
    MLP of `policy_hidden` (tanh). Heavier (gravity) and weaker (actuators) cheetahs are other
    tasks of one robot: a gait found for one seeds its neighbours'. qd_offset as halfcheetah_uni's.
    """
    if cvt_samples < num_tasks:
        raise ValueError(f"task.cvt_samples: expected at least task.num_tasks={num_tasks}, got {cvt_samples}")
    family = multi_task_family(num_tasks, task_seed, cvt_samples, kmeans_iters)
    env = BraxEnv("halfcheetah", backend, episode_length, state_descriptor="x")
    network = policy_network(env.action_size, tuple(int(h) for h in policy_hidden), "tanh")
    template = jax.tree.map(lambda a: a[0], init_policies(network, env.observation_size, jax.random.PRNGKey(0), 1))
    n_leaves = len(jax.tree.leaves(template))
    # The one start state (a reset leaves the scales alone), computed when the first evaluation
    # is traced, from a key made now: concrete, as `fixed_start_state` needs it.
    start_key = jax.random.PRNGKey(0)
    starts: list[Any] = []

    def episode(policy: Any, parameters: Array, key: PRNGKey) -> tuple[Array, Array]:
        lane = env.perturbed(0.5 + parameters[0], 0.5 + parameters[1])  # traced scales: one program
        episodes = run_episodes(lane, lambda obs, _: network.apply(policy, obs), key, 1, start_state=starts[0])
        return episodes.returns[0], episodes.lengths[0]

    def scoring_fn(genotypes: dict[str, Any], key: PRNGKey) -> Evaluation:
        x, task = _check_genotypes(genotypes, n_leaves)
        if not starts:
            starts.append(fixed_start_state(env, start_key))
        parameters = jnp.asarray(family.parameters(), jnp.float32)[jnp.clip(task, 0, num_tasks - 1)]
        returns, lengths = jax.vmap(episode, in_axes=(0, 0, None))(x, parameters, key)
        return Evaluation(
            fitnesses=returns.astype(jnp.float32),
            descriptors=parameters,
            extras={},
            env_steps=jnp.sum(lengths).astype(jnp.int32),
        )

    def init(key: PRNGKey, n: int) -> dict[str, Any]:
        policy_key, task_key = jax.random.split(key)
        return {
            GENES: init_policies(network, env.observation_size, policy_key, n),
            TASK: jax.random.randint(task_key, (n,), 0, num_tasks, jnp.int32),
        }

    return Task(
        name="multi_task_halfcheetah",
        scoring_fn=scoring_fn,
        descriptor_low=family.low,
        descriptor_high=family.high,
        descriptor_names=("gravity scale - 0.5", "actuator strength - 0.5"),
        genotype_size=num_parameters(template) + 1,
        genotype_low=-math.inf,
        genotype_high=math.inf,
        qd_offset=-REWARD_OFFSETS["halfcheetah_uni"] * episode_length,
        init_fn=init,
        genotype_template={GENES: template, TASK: jnp.zeros((), jnp.int32)},
    )


# The families of the task table (`qdrl.tasks.TASKS`); the mt_me recipe accepts these names.
MULTI_TASK_TASKS: dict[str, TaskEntry] = {
    "multi_task_arm": TaskEntry(multi_task_arm),
    "multi_task_halfcheetah": TaskEntry(multi_task_halfcheetah, policy=True),
}
