"""CMA-ME and CMA-MAE's emitter: many CMA-ES instances, one vmapped step, a ranker as a parameter.

Fontaine, Togelius, Nikolaidis & Hoover 2020, "Covariance Matrix Adaptation for
the Rapid Illumination of Behavior Space" (CMA-ME); Fontaine & Nikolaidis 2023,
"Covariance Matrix Adaptation MAP-Annealing" (CMA-MAE: the same emitter with the
`imp` ranker on a repertoire with an archive learning rate). pyribs'
`EvolutionStrategyEmitter` is the reference for the options.

One `CMAEmitter` holds `num_instances` independent CMA-ES searches (the papers
use 15 of 36 solutions each) as one state with a leading instance axis; `emit`
samples every instance and `update` ranks each instance's offspring with the
configured ranker (`qdrl.qd.emitters.rankers`), feeds the ranked solutions to
the one CMA-ES (`qdrl.qd.cma_es`) and restarts the instances that must:

- selection: `mu` recombines the best lambda/2; `filter` the offspring the
  archive accepted (a new cell, or better than the cell's elite / threshold);
- restart: `basic` (CMA-ES's own stop conditions only), `no_improvement` (also
  when no offspring was accepted), or an integer N (also after N generations
  since the last restart); the new mean is an elite drawn uniformly from the
  repertoire, the random direction (rankers `rd`, `2rd`) is drawn anew.

The eigendecompositions of all instances happen on one shared clock (every
`eigen_period` updates of the emitter) so that they stay a real `lax.cond`
under vmap; an instance restarted in between starts from C = I, whose
decomposition is exact.

`emit_instances` / `update_instances` expose the instance axis to the bandit
scheduler (`qdrl.qd.emitters.scheduler`), which updates only the instances it
chose.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Annotated, Literal, NamedTuple

import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree

from qdrl.config import OneOf, PositiveFloat, PositiveInt, Range, check_fields
from qdrl.qd.base import Evaluation, Repertoire
from qdrl.qd.cma_es import CMAES, CMAESState, EigenGapRule
from qdrl.qd.emitters.multi import tree_select
from qdrl.qd.emitters.rankers import (
    RANKERS,
    Outcome,
    random_direction,
    rank,
    uses_direction,
)
from qdrl.qd.emitters.scheduler import InstancesAsEmitter
from qdrl.types import Array, Genotype, PRNGKey

__all__ = [
    "KIND_RANKERS",
    "CMAEmitter",
    "CMAEmitterConfig",
    "CMAEmitterState",
    "must_restart",
    "num_parents",
    "tree_select",
]

CMAKind = Literal["cma_improvement", "cma_optimizing", "cma_random_direction"]
# The ranker of each kind (CMA-ME's improvement, optimizing and random-direction
# emitters; pyribs' `EvolutionStrategyEmitter` with these rankers); `ranker` overrides it.
KIND_RANKERS: dict[str, str] = {
    "cma_improvement": "2imp",
    "cma_optimizing": "obj",
    "cma_random_direction": "2rd",
}


def ranker_names() -> list[str]:
    """The rankers an emitter may name (`qdrl.qd.emitters.rankers.RANKERS`)."""
    return sorted(RANKERS)


RankerName = Annotated[str, OneOf(ranker_names)]
SelectionRule = Literal["filter", "mu"]
# "no_improvement" (also restart when no offspring was accepted), "basic" (CMA-ES's
# own stop conditions only), or N (also after N generations since the last restart).
RestartRule = Literal["no_improvement", "basic"] | PositiveInt
Lambda = Annotated[int, Range(low=2)]  # solutions per CMA-ES generation
UpdateRule = Literal["pyribs", "tutorial"]


@dataclasses.dataclass(frozen=True)
class CMAEmitterConfig:
    """The `[emitter]` section of CMA-ME / CMA-MAE (`kind` = "cma_improvement",
    "cma_optimizing" or "cma_random_direction"); defaults: pyribs' CMA-ME (`2imp`,
    filter, no_improvement).

    CMA-MAE (Fontaine & Nikolaidis 2023) is the improvement emitter with
    `ranker="imp", selection_rule="mu", restart_rule="basic"` on a repertoire
    with a learning rate. `ranker` defaults to the kind's (`KIND_RANKERS`).
    """

    kind: CMAKind = "cma_improvement"
    num_instances: PositiveInt = 15  # independent CMA-ES searches stepped together
    batch_size: Lambda = 36  # solutions per instance per iteration (lambda)
    sigma0: PositiveFloat = 0.5  # initial step size of every (re)start
    ranker: RankerName | None = None  # imp, 2imp, obj, 2obj, rd, 2rd; None: the kind's
    selection_rule: SelectionRule = "filter"  # "filter": accepted offspring recombine; "mu": the best half
    restart_rule: RestartRule = "no_improvement"
    separable: bool = False  # sep-CMA-ES: diagonal covariance, for thousands of parameters
    # Generations between eigendecompositions, or the rule 0.5 lambda / (n (c_1 + c_mu)) counted
    # in "generations" (as QDax counts it) or in "evaluations" (pyribs' code: lambda times as often).
    eigen_gap: PositiveInt | EigenGapRule = "generations"
    update_rule: UpdateRule = "pyribs"  # CMA-ES equations: pyribs' (the reference) or Hansen's tutorial

    def __post_init__(self) -> None:
        if self.ranker is None:
            object.__setattr__(self, "ranker", KIND_RANKERS.get(self.kind, "2imp"))

    def check(self, section: str = "emitter") -> None:
        """Raises `ConfigError("section.key: expected ..., got ...")` for a bad value."""
        check_fields(self, section)

    @property
    def offspring(self) -> int:
        """Offspring per iteration: num_instances x batch_size."""
        return self.num_instances * self.batch_size

    @property
    def instance_size(self) -> int:
        """Offspring of one instance per iteration (every arm of a pool emits as many)."""
        return self.batch_size


class CMAEmitterState(NamedTuple):
    """Every leaf but `clock` has a leading instance axis K."""

    es: CMAESState  # (K, ...) one CMA-ES per instance
    direction: Array  # (K, D) target direction of the random-direction rankers (zeros otherwise)
    restarts: Array  # (K,) int32 restarts so far
    restarted: Array  # (K,) bool: restarted at the last update (the scheduler reselects those)
    clock: Array  # () int32 emitter updates so far (the shared eigendecomposition clock)


def num_parents(selection_rule: str, status: Array, batch_size: int) -> Array:
    """How many ranked offspring recombine: the accepted ones ("filter") or lambda/2 ("mu")."""
    if selection_rule == "filter":
        return jnp.sum(status > 0).astype(jnp.int32)
    return jnp.asarray(batch_size // 2, jnp.int32)


def must_restart(restart_rule: str | int, stopped: Array, status: Array, generation: Array) -> Array:
    """CMA-ES stopped, or the emitter's rule fires (no offspring accepted / N generations)."""
    if restart_rule == "no_improvement":
        return stopped | ~jnp.any(status > 0)
    if restart_rule == "basic":
        return stopped
    return stopped | (generation >= int(restart_rule))


@dataclasses.dataclass(eq=False)
class CMAEmitter(InstancesAsEmitter):
    """`num_instances` CMA-ES searches in genotype space; batch_size = num_instances * lambda.

    Args:
      config: the options (see `CMAEmitterConfig`).
      genotype_example: one genotype (any pytree; flattened for CMA-ES).
      genotype_low, genotype_high: optional bounds; samples are clipped to them.
      descriptor_low, descriptor_high: the archive's descriptor box, for the
        random-direction rankers (default: the grid repertoire's own bounds).
    """

    config: CMAEmitterConfig
    genotype_example: Genotype
    genotype_low: float | None = None
    genotype_high: float | None = None
    descriptor_low: Sequence[float] | None = None
    descriptor_high: Sequence[float] | None = None
    batch_size: int = dataclasses.field(init=False)
    es: CMAES = dataclasses.field(init=False)
    unravel: Callable[[Array], Genotype] = dataclasses.field(init=False)
    ranker: str = dataclasses.field(init=False)

    def __post_init__(self) -> None:
        self.config.check()
        flat, self.unravel = ravel_pytree(self.genotype_example)
        c = self.config
        self.ranker = c.ranker or KIND_RANKERS[c.kind]
        self.es = CMAES(
            int(flat.shape[0]), c.batch_size, float(c.sigma0), c.separable, c.eigen_gap, c.update_rule
        )
        self.batch_size = c.offspring

    @property
    def num_instances(self) -> int:
        """K, the instances (arms of a bandit scheduler)."""
        return self.config.num_instances

    @property
    def instance_batch_size(self) -> int:
        """lambda, the offspring of one instance per iteration."""
        return self.config.batch_size

    def _flat(self, genotypes: Genotype, batch_dims: int) -> Array:
        ravel = lambda g: ravel_pytree(g)[0]  # noqa: E731
        for _ in range(batch_dims):
            ravel = jax.vmap(ravel)
        return ravel(genotypes)

    def _bounds(self, repertoire: Repertoire) -> tuple[Array, Array]:
        low = self.descriptor_low if self.descriptor_low is not None else getattr(repertoire, "low", None)
        high = self.descriptor_high if self.descriptor_high is not None else getattr(repertoire, "high", None)
        if low is None or high is None:
            raise ValueError(
                f"emitter.ranker: {self.ranker!r} needs the descriptor bounds: give "
                "descriptor_low and descriptor_high, or use a grid repertoire"
            )
        return jnp.asarray(low, jnp.float32), jnp.asarray(high, jnp.float32)

    def _fresh(self, repertoire: Repertoire, key: PRNGKey) -> tuple[CMAESState, Array]:
        """K new searches, each around an elite drawn uniformly, with new directions."""
        k = self.num_instances
        elite_key, direction_key = jax.random.split(key)
        means = self._flat(repertoire.sample(elite_key, k), 1)
        states = jax.vmap(self.es.init)(means)
        dim = int(repertoire.descriptors.shape[-1])
        if uses_direction(self.ranker):
            low, high = self._bounds(repertoire)
            keys = jax.random.split(direction_key, k)
            directions = jax.vmap(lambda kk: random_direction(kk, low, high))(keys)
        else:
            directions = jnp.zeros((k, dim), jnp.float32)
        return states, directions

    def init(
        self, key: PRNGKey, repertoire: Repertoire, evaluation: Evaluation, genotypes: Genotype
    ) -> CMAEmitterState:
        """Every instance starts around an elite of the initial repertoire (e.g. pyribs' x0)."""
        del evaluation, genotypes
        states, directions = self._fresh(repertoire, key)
        k = self.num_instances
        return CMAEmitterState(
            es=states,
            direction=directions,
            restarts=jnp.zeros((k,), jnp.int32),
            restarted=jnp.zeros((k,), bool),
            clock=jnp.zeros((), jnp.int32),
        )

    def emit_instances(self, state: CMAEmitterState, repertoire: Repertoire, key: PRNGKey) -> Genotype:
        """Every instance's lambda samples: leaves (K, lambda, ...)."""
        del repertoire
        keys = jax.random.split(key, self.num_instances)
        x = jax.vmap(self.es.sample)(state.es, keys)
        if self.genotype_low is not None or self.genotype_high is not None:
            x = jnp.clip(x, self.genotype_low, self.genotype_high)
        return jax.vmap(jax.vmap(self.unravel))(x)

    def update_instances(
        self,
        state: CMAEmitterState,
        repertoire: Repertoire,
        genotypes: Genotype,
        out: Outcome,
        active: Array,
        key: PRNGKey,
    ) -> CMAEmitterState:
        """Rank, step and maybe restart the `active` (K,) instances; the others keep their state.

        `genotypes` leaves are (K, lambda, ...) and `out` fields (K, lambda, ...) (see
        `rankers.outcome`, computed on the whole batch).
        """
        c = self.config
        flat = self._flat(genotypes, 2)
        decompose = (state.clock + 1) % self.es.eigen_period == 0

        def tell(es_state: CMAESState, x: Array, o: Outcome, direction: Array) -> tuple[CMAESState, Array]:
            order, values = rank(self.ranker, o, direction)
            k = num_parents(c.selection_rule, o.status, c.batch_size)
            new = self.es.update(es_state, x[order], k, decompose)
            stop = self.es.stop(new, values)
            return new, must_restart(c.restart_rule, stop, o.status, new.generation)

        stepped, restart = jax.vmap(tell)(state.es, flat, out, state.direction)
        restart = restart & active
        fresh, directions = self._fresh(repertoire, key)
        es_state = tree_select(restart, fresh, tree_select(active, stepped, state.es))
        return CMAEmitterState(
            es=es_state,
            direction=jnp.where(restart[:, None], directions, state.direction),
            restarts=state.restarts + restart.astype(jnp.int32),
            restarted=restart,
            clock=state.clock + 1,
        )

    def restarted(self, state: CMAEmitterState) -> Array:
        """(K,) bool: the instances that restarted at the last update."""
        return state.restarted
