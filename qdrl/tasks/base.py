"""`Task`: a scoring function bundled with its search and descriptor bounds."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from qdrl.qd.base import Evaluation, ScoringFn
from qdrl.qd.dqd import DESCRIPTOR_GRADIENTS, FITNESS_GRADIENT
from qdrl.types import Array, Descriptor, Fitness, PRNGKey


class PolicyNetwork(NamedTuple):
    """The network whose parameters are a policy task's genotypes, and its input and output sizes."""

    network: Any  # haiku `Transformed`: apply(params, obs) -> action in [-1, 1]
    obs_size: int
    action_size: int


@dataclasses.dataclass(frozen=True)
class Task:
    """A QD benchmark: batched scoring function, bounds, and what the QD score needs.

    `qd_offset` is subtracted from every stored fitness before summing the QD
    score; each task sets it to (a bound below) its lowest fitness inside the
    search bounds so that every elite counts non-negatively. `max_fitness`, when
    known, normalises scores: `(f - qd_offset) / (max_fitness - qd_offset)`.
    `init_fn`, when given, replaces the default initial population (uniform in
    `[genotype_low, genotype_high]^genotype_size`), e.g. for QD-suite tasks that
    all start from one point, or policy tasks whose genotypes are parameter trees.
    `genotype_template` is one genotype (no batch axis) when genotypes are not flat
    vectors; `genotype_size` then counts its scalars.
    Policy tasks also give their environment (`env`), `policy_scoring(network)`:
    the task's scoring function for genotypes of another policy (anything with
    `apply(genotype, obs) -> action`), e.g. whole RL agents in ME-PBT (None: the
    task's own policy; keywords `fixed_start` and `record` as in
    `qdrl.tasks.policy.policy_scoring_fn`, e.g. for random-start re-evaluations), and
    `episode_descriptor`: how an episode's descriptor is read from its state
    descriptors ("final" or "mean"), so that RL runs fill the same archive.
    `gradient_scoring_fn`, for differentiable tasks, is `scoring_fn` whose
    evaluations also carry the fitness gradient and descriptor Jacobian
    (`qdrl.qd.dqd`); runs that do not ask for it differentiate nothing.
    `descriptor_names` label the descriptor dimensions on plots (e.g. "back foot
    contact"); by default "descriptor 0", "descriptor 1", ...
    """

    name: str
    scoring_fn: ScoringFn
    descriptor_low: tuple[float, ...]
    descriptor_high: tuple[float, ...]
    genotype_size: int
    genotype_low: float
    genotype_high: float
    qd_offset: float
    max_fitness: float | None = None
    init_fn: Callable[[PRNGKey, int], Any] | None = None
    genotype_template: Any = None
    env: Any = None
    policy_scoring: Callable[..., ScoringFn] | None = None
    episode_descriptor: str | None = None
    gradient_scoring_fn: ScoringFn | None = None
    # Multi-objective tasks (`qdrl.tasks.mo`): fitnesses are (n, num_objectives), every
    # objective maximised, and hypervolumes are measured from `reference_point`.
    num_objectives: int = 1
    reference_point: tuple[float, ...] | None = None
    descriptor_names: tuple[str, ...] = ()
    # Policy tasks (`qdrl.tasks.policy`): the genotypes' network; None when genotypes are not policies.
    policy: PolicyNetwork | None = None
    # Tasks whose Pareto front is known (ZDT, DTLZ2): () -> (k, M) points of it in fitness
    # space, for plots; and its hypervolume from `reference_point` (None where not known).
    true_front: Callable[[], Any] | None = None
    true_hypervolume: float | None = None
    # Objectives the literature minimises, scored negated (ZDT, DTLZ2): plots draw minus the
    # fitnesses, in the objectives' own view.
    minimised: bool = False
    # A policy task whose own scoring draws a random start state per episode (noisy evaluations:
    # the Uncertain-QD benchmarks' random starts) instead of QDax's one fixed start.
    random_start: bool = False

    def __post_init__(self) -> None:
        if len(self.descriptor_low) != len(self.descriptor_high):
            raise ValueError(
                f"{self.name}: descriptor_low has {len(self.descriptor_low)} entries, "
                f"descriptor_high {len(self.descriptor_high)}"
            )
        if self.num_objectives > 1 and (
            self.reference_point is None or len(self.reference_point) != self.num_objectives
        ):
            raise ValueError(
                f"{self.name}: a task of {self.num_objectives} objectives needs a reference "
                f"point of {self.num_objectives} values, got {self.reference_point}"
            )
        if not self.descriptor_names:
            default = tuple(f"descriptor {i}" for i in range(len(self.descriptor_low)))
            object.__setattr__(self, "descriptor_names", default)
        if len(self.descriptor_names) != len(self.descriptor_low):
            raise ValueError(
                f"{self.name}: expected {len(self.descriptor_low)} descriptor names, got "
                f"{list(self.descriptor_names)}"
            )
        if not self.genotype_low < self.genotype_high:
            raise ValueError(
                f"{self.name}: genotype_low ({self.genotype_low}) must be below "
                f"genotype_high ({self.genotype_high})"
            )

    @property
    def is_policy_task(self) -> bool:
        """Whether genotypes are policies acting in `env` (so the task hands back transitions)."""
        return self.policy is not None

    @property
    def descriptor_size(self) -> int:
        """Number of descriptor dimensions D."""
        return len(self.descriptor_low)

    def scoring(self, policy: Any = None, fixed_start: bool = True, record: Any = None) -> ScoringFn:
        """The scoring of genotypes acting by `policy` (None: the task's own network): random
        start states (`fixed_start=False`, for re-evaluations) and recorded env states (`record`,
        for replays) need a policy task; other tasks have one scoring function."""
        own = policy is None and record is None and fixed_start != self.random_start
        if self.policy_scoring is None or own:
            return self.scoring_fn
        return self.policy_scoring(policy, fixed_start=fixed_start, record=record)

    def example_genotype(self) -> Any:
        """One genotype without batch axis (zeros), e.g. to build an empty repertoire."""
        if self.genotype_template is not None:
            return jax.tree.map(jnp.zeros_like, self.genotype_template)
        return jnp.zeros((self.genotype_size,), jnp.float32)

    def init_genotypes(self, key: PRNGKey, n: int) -> Any:
        """`n` initial genotypes: (n, genotype_size) float32, or a pytree with a leading n axis."""
        if self.init_fn is not None:
            return self.init_fn(key, n)
        return jax.random.uniform(
            key,
            (n, self.genotype_size),
            minval=self.genotype_low,
            maxval=self.genotype_high,
        )


@dataclasses.dataclass(frozen=True)
class TaskEntry:
    """One task of the registry (`qdrl.tasks.TASKS`): its builder, and what a spec can know of
    the task before building it (building a policy task builds its environment).

    `entry(**params)` builds the task; `entry.build` is the builder itself (its signature
    and annotations declare the `[task]` keys).
    """

    build: Callable[..., Task]
    # Genotypes are policies acting in an environment: unbounded parameter trees.
    policy: bool = False
    # The number of objectives, or how a resolved `[task]` table sets it (DTLZ2's num_objectives).
    objectives: int | Callable[[Mapping[str, Any]], int] = 1

    def __call__(self, **params: Any) -> Task:
        return self.build(**params)

    def num_objectives(self, table: Mapping[str, Any]) -> int:
        """The number of objectives of the task of a resolved `[task]` table, without building it."""
        return self.objectives if isinstance(self.objectives, int) else int(self.objectives(table))


def batched_scoring_fn(
    evaluate: Callable[[Array], tuple[Fitness, Descriptor]],
    genotype_size: int,
    gradients: bool = False,
) -> ScoringFn:
    """Turns a deterministic one-genotype `x -> (fitness (), descriptor (D,))` into a `ScoringFn`.

    With `gradients`, the evaluation's extras also hold `jax.grad` of the fitness
    (`qdrl.qd.dqd.FITNESS_GRADIENT`, (n, genotype_size)) and `jax.jacrev` of the
    descriptor (`DESCRIPTOR_GRADIENTS`, (n, D, genotype_size)) of `evaluate` itself, for the
    differentiable-QD emitters (OMG-MEGA, CMA-MEGA). Without, nothing is
    differentiated.
    """
    batched = jax.vmap(evaluate)
    fitness_grad = jax.vmap(jax.grad(lambda x: evaluate(x)[0]))
    descriptor_jac = jax.vmap(jax.jacrev(lambda x: evaluate(x)[1]))

    def scoring_fn(genotypes: Array, key: PRNGKey) -> Evaluation:
        del key  # deterministic
        genotypes = check_genotypes(genotypes, genotype_size)
        fitnesses, descriptors = batched(genotypes)
        extras: dict[str, Any] = {}
        if gradients:
            extras[FITNESS_GRADIENT] = fitness_grad(genotypes).astype(jnp.float32)
            extras[DESCRIPTOR_GRADIENTS] = descriptor_jac(genotypes).astype(jnp.float32)
        return Evaluation(
            fitnesses=fitnesses.astype(jnp.float32),
            descriptors=descriptors.astype(jnp.float32),
            extras=extras,
            env_steps=jnp.zeros((), jnp.int32),
        )

    return scoring_fn


def check_genotypes(genotypes: Array, genotype_size: int) -> Array:
    """`genotypes` as a floating (n, genotype_size) array; raises a ValueError on another shape."""
    genotypes = jnp.asarray(genotypes)
    if genotypes.ndim != 2 or genotypes.shape[1] != genotype_size:
        raise ValueError(f"genotypes: expected shape (n, {genotype_size}), got {genotypes.shape}")
    if not jnp.issubdtype(genotypes.dtype, jnp.floating):
        genotypes = genotypes.astype(jnp.float32)
    return genotypes
